"""3-vectors and 3x3 matrices on plain floats, for code that runs every cycle or sub-step.

For 3x3 problems numpy's per-call overhead is most of the cost (``np.linalg.inv`` of a 3x3
takes longer than the cofactor formula in Python). Matrices are tuples of rows. The tests
compare every function with numpy.
"""

from __future__ import annotations

import math

import numpy as np

Vector3 = tuple[float, float, float]
Matrix3 = tuple[Vector3, Vector3, Vector3]


def norm3(v: Vector3) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def sub3(a: Vector3, b: Vector3) -> Vector3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def matvec(m: Matrix3, v: Vector3) -> Vector3:
    return (
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    )


def as_rows(m: np.ndarray) -> Matrix3:
    # 3x3 is the caller's promise (a 3x3 array), not checked here: tuple() is tuple[..., ...] to mypy.
    return tuple(tuple(float(x) for x in row) for row in m)  # type: ignore[return-value]


def transpose3(m: Matrix3) -> Matrix3:
    return ((m[0][0], m[1][0], m[2][0]), (m[0][1], m[1][1], m[2][1]), (m[0][2], m[1][2], m[2][2]))


def dot3(r: Vector3, c: Vector3) -> float:
    return r[0] * c[0] + r[1] * c[1] + r[2] * c[2]


def matmul3(a: Matrix3, b: Matrix3) -> Matrix3:
    c0, c1, c2 = transpose3(b)
    return (
        (dot3(a[0], c0), dot3(a[0], c1), dot3(a[0], c2)),
        (dot3(a[1], c0), dot3(a[1], c1), dot3(a[1], c2)),
        (dot3(a[2], c0), dot3(a[2], c1), dot3(a[2], c2)),
    )


def scaled3(m: Matrix3, k: float) -> Matrix3:
    (a, b, c), (d, e, f), (g, h, i) = m
    return ((k * a, k * b, k * c), (k * d, k * e, k * f), (k * g, k * h, k * i))


def inverse3(m: Matrix3) -> Matrix3:
    """The inverse by cofactors; raises ``np.linalg.LinAlgError`` for a singular matrix."""
    (a, b, c), (d, e, f), (g, h, i) = m
    co_a, co_b, co_c = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * co_a + b * co_b + c * co_c
    r = 1.0 / det if det != 0.0 else math.inf
    if not math.isfinite(r):
        # The determinant, a product of three entries, under- or overflowed (entries below
        # about 1e-103 or above 1e102; found by tests/unit/test_linalg3.py): invert the matrix
        # scaled to a largest entry of 1, then scale back. Never taken by the robots' Jacobians.
        scale = max(abs(x) for row in m for x in row)
        if scale == 0.0 or scale == 1.0 or not math.isfinite(scale):
            raise np.linalg.LinAlgError("singular 3x3 matrix")
        return scaled3(inverse3(scaled3(m, 1.0 / scale)), 1.0 / scale)
    return (
        (co_a * r, (c * h - b * i) * r, (b * f - c * e) * r),
        (co_b * r, (a * i - c * g) * r, (c * d - a * f) * r),
        (co_c * r, (b * g - a * h) * r, (a * e - b * d) * r),
    )


def solve3(m: Matrix3, v: Vector3) -> Vector3:
    """x with m x = v (``inverse3``: the same error for a singular m)."""
    return matvec(inverse3(m), v)


def symmetric_eigenvalues3(m: Matrix3) -> Vector3:
    """Eigenvalues of a symmetric 3x3 matrix, ascending (the trigonometric closed form).

    Smith, "Eigenvalues of a symmetric 3x3 matrix", Comm. ACM 4(4), 1961: with
    q = tr(m)/3 and B = (m - q I)/p, p^2 = tr((m - q I)^2)/6, the eigenvalues are
    q + 2 p cos(phi + 2 pi k / 3), cos(3 phi) = det(B)/2. Accurate to about 1e-8 of the
    largest eigenvalue (``tests/test_linalg3.py`` holds it to 1e-7): where two eigenvalues
    nearly coincide, acos near +-1 keeps only half the digits. Enough for a condition number
    checked against its limit (``robot.cheope.margins.max_condition_number``, 10).
    """
    a00, a01, a02 = m[0]
    a11, a12 = m[1][1], m[1][2]
    a22 = m[2][2]
    off = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    if off == 0.0:
        lo, mid, hi = sorted((a00, a11, a22))
        return lo, mid, hi
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off) / 6.0)
    det = (
        b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    ) / p**3
    phi = math.acos(max(-1.0, min(1.0, det / 2.0))) / 3.0
    largest = q + 2.0 * p * math.cos(phi)
    smallest = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    lo, mid, hi = sorted((smallest, 3.0 * q - largest - smallest, largest))
    return lo, mid, hi
