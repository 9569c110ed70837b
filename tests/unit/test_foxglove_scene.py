"""The scene's geometry: the rotation that points a cylinder, a cube or an arrow along its direction."""

from __future__ import annotations

import numpy as np
from hypothesis import assume, given
from hypothesis import strategies as st

from logs.foxglove_scene import quaternion_from_to

_component = st.floats(min_value=-10.0, max_value=10.0, allow_nan=False)
_vector = st.tuples(_component, _component, _component)


def _rotate(q: tuple[float, float, float, float], v: np.ndarray) -> np.ndarray:
    x, y, z, w = q
    u = np.array([x, y, z])
    return 2.0 * u.dot(v) * u + (w * w - u.dot(u)) * v + 2.0 * w * np.cross(u, v)


@given(_vector, _vector)
def test_the_rotation_takes_the_first_direction_to_the_second(a, b):
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    assume(na > 1e-3 and nb > 1e-3)
    q = quaternion_from_to(a, b)
    assert abs(np.linalg.norm(q) - 1.0) < 1e-9
    assert np.allclose(_rotate(q, np.asarray(a) / na), np.asarray(b) / nb, atol=1e-7)


def test_opposite_directions_take_half_a_turn_and_a_zero_vector_none():
    for a in ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.3, -0.4, 0.5)):
        b = tuple(-x for x in a)
        q = quaternion_from_to(a, b)
        assert abs(q[3]) < 1e-12
        assert np.allclose(_rotate(q, np.asarray(a) / np.linalg.norm(a)), np.asarray(b) / np.linalg.norm(b))
    assert quaternion_from_to((0.0, 0.0, 0.0), (1.0, 0.0, 0.0)) == (0.0, 0.0, 0.0, 1.0)
