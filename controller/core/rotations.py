"""Rotations: SO(3) by its exponential map (Rodrigues) and elementary rotations, vectorised in numpy.

Seed 004 writes the 3-nSPU's kinematics with them; the simulated pose tracker uses them too."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def hat(w: Array) -> Array:
    """Skew matrix [w] with [w] x = w x x; vectorised over leading dimensions."""
    w = np.asarray(w)
    out = np.zeros((*w.shape[:-1], 3, 3), dtype=w.dtype)
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def vee(m: Array) -> Array:
    """Inverse of `hat` (uses the skew part)."""
    m = np.asarray(m)
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], axis=-1
    )


def so3_exp(w: Array) -> Array:
    """Rotation exp([w]) by Rodrigues' formula (series near 0); vectorised, complex-step safe."""
    w = np.asarray(w)
    th2 = np.sum(w * w, axis=-1)
    small = np.real(th2) < 1e-12
    th2_safe = np.where(small, 1.0, th2)
    th = np.sqrt(th2_safe)
    a = np.where(small, 1.0 - th2 / 6.0 + th2 * th2 / 120.0, np.sin(th) / th)
    b = np.where(small, 0.5 - th2 / 24.0 + th2 * th2 / 720.0, (1.0 - np.cos(th)) / th2_safe)
    k = hat(w)
    eye = np.broadcast_to(np.eye(3), k.shape)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def so3_log(r: Array) -> Array:
    """Rotation vector w with exp([w]) = R, |w| <= pi (seed 004, text after eq. (9)).

    log R = alpha / (2 sin alpha) (R - R^T) with cos alpha = (tr R - 1)/2; near alpha = pi the
    axis is taken from the symmetric part (R + I)/2 = a a^T instead.  Real input only.
    """
    r = np.asarray(r, dtype=float)
    flat = r.reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 3))
    for k, m in enumerate(flat):
        c = np.clip(0.5 * (np.trace(m) - 1.0), -1.0, 1.0)
        alpha = float(np.arccos(c))
        v = vee(m)
        if alpha < 1e-6:
            out[k] = v * (1.0 + alpha * alpha / 6.0)
        elif alpha < np.pi - 1e-4:
            out[k] = v * (alpha / np.sin(alpha))
        else:
            sym = 0.5 * (m + np.eye(3))
            i = int(np.argmax(np.diag(sym)))
            axis = sym[:, i] / np.sqrt(sym[i, i])
            axis = axis / np.linalg.norm(axis)
            if np.dot(axis, v) < 0.0:
                axis = -axis
            out[k] = alpha * axis
    return out.reshape((*r.shape[:-2], 3))


def rot_x(a: Array | float) -> Array:
    """Elementary rotation about x."""
    a = np.asarray(a)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(a: Array | float) -> Array:
    """Elementary rotation about y."""
    a = np.asarray(a)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_z(a: Array | float) -> Array:
    """Elementary rotation about z."""
    a = np.asarray(a)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def rpy(roll: float, pitch: float, yaw: float) -> Array:
    """Roll-pitch-yaw rotation Rz(yaw) Ry(pitch) Rx(roll) (seed 004 section 4, RPY(.,.,.))."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)
