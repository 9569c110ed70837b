"""controller/core/linalg3.py against numpy."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from controller.core.linalg3 import (
    as_rows,
    inverse3,
    matmul3,
    matvec,
    norm3,
    scaled3,
    solve3,
    sub3,
    symmetric_eigenvalues3,
    transpose3,
)

finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
matrices = arrays(np.float64, (3, 3), elements=finite)
vectors = arrays(np.float64, (3,), elements=finite)


@settings(max_examples=300)
@given(matrices, matrices, vectors, finite)
def test_products_match_numpy(a, b, v, k):
    assert np.allclose(matvec(as_rows(a), tuple(v)), a @ v, rtol=1e-12, atol=1e-12)
    assert np.allclose(matmul3(as_rows(a), as_rows(b)), a @ b, rtol=1e-12, atol=1e-12)
    assert np.array_equal(transpose3(as_rows(a)), a.T)
    assert np.allclose(scaled3(as_rows(a), k), k * a)
    assert np.isclose(norm3(tuple(v)), np.linalg.norm(v), rtol=1e-12, atol=1e-12)
    assert np.array_equal(sub3(tuple(v), tuple(a[0])), v - a[0])


@settings(max_examples=300)
@given(matrices, vectors)
def test_inverse_and_solve_match_numpy_where_well_conditioned(a, v):
    if np.linalg.cond(a) > 1e6:
        return
    # Rounding errors of an inverse scale with its largest entry, not with each entry.
    inv = np.linalg.inv(a)
    assert np.allclose(inverse3(as_rows(a)), inv, rtol=1e-6, atol=1e-9 * max(1.0, np.abs(inv).max()))
    x = np.linalg.solve(a, v)
    assert np.allclose(
        solve3(as_rows(a), tuple(v)), x, rtol=1e-6, atol=1e-9 * max(1.0, np.abs(inv).max() * np.abs(v).max())
    )


def test_the_inverse_of_a_matrix_whose_determinant_underflows_matches_numpy():
    # Found by the property above: entries of 6.8e-145, a well-conditioned matrix whose
    # determinant underflows to 0.0.
    a = np.full((3, 3), 6.769652881360066e-145) - np.diag(
        [6.769652881360066e-145, 6.769652881360066e-145, 0.0]
    )
    assert np.allclose(inverse3(as_rows(a)), np.linalg.inv(a), rtol=1e-9, atol=0.0)


def test_inverse_of_a_singular_matrix_raises_as_numpy_does():
    with pytest.raises(np.linalg.LinAlgError):
        inverse3(((1.0, 2.0, 3.0), (2.0, 4.0, 6.0), (0.0, 1.0, 1.0)))


@settings(max_examples=500)
@given(matrices)
def test_symmetric_eigenvalues_match_eigvalsh(a):
    s = a @ a.T + np.diag([1e-3, 2e-3, 3e-3])  # a Gram matrix, as J^T J
    expected = np.linalg.eigvalsh(s)
    got = symmetric_eigenvalues3(as_rows(s))
    assert list(got) == sorted(got)
    # the closed form keeps about 1e-8 of the largest eigenvalue (the docstring says why)
    assert np.allclose(got, expected, rtol=0.0, atol=1e-7 * max(1e-3, expected[-1]))


@pytest.mark.parametrize(
    "a", [np.array([[8.5, 0, 0], [0, 0, 0], [8.5, 0, 0]]), np.array([[3.0, 0, 0], [0, 0, 0], [3.0, 0, 0]])]
)
def test_symmetric_eigenvalues_where_two_nearly_coincide(a):
    # hypothesis found these: a large eigenvalue beside two that differ by 1e-3 of a part
    s = a @ a.T + np.diag([1e-3, 2e-3, 3e-3])
    got = symmetric_eigenvalues3(as_rows(s))
    assert list(got) == sorted(got)
    assert np.allclose(got, np.linalg.eigvalsh(s), rtol=0.0, atol=1e-7 * np.linalg.eigvalsh(s)[-1])


def test_symmetric_eigenvalues_of_a_diagonal_and_a_repeated_case():
    assert symmetric_eigenvalues3(((3.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 2.0))) == (1.0, 2.0, 3.0)
    s = np.full((3, 3), 1.0) + np.eye(3)  # eigenvalues 1, 1, 4
    assert np.allclose(symmetric_eigenvalues3(as_rows(s)), (1.0, 1.0, 4.0))
