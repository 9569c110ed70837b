"""A simulated pose tracker on the 3-nSPU's platform: the true pose, with noise, at its own rate.

Real set-ups measure a non-holonomic platform from outside (an optical or laser tracker),
because its pose is not a function of the joint readings. This one samples the simulator's
own pose (``plant_kinematics.NspuOdometry.pose``: the mismatched geometry, the physical legs)
at ``sim.tracker.rate_hz``, adds independent Gaussian noise of ``position_noise_m`` to each
coordinate of the platform point P and ``angle_noise_rad`` to each component of the rotation
vector (R_measured = exp([noise]x) R), and answers as two TPDOs (drivers/pdo_codec.py,
``encode_tracker_frames``). A sample is taken at a SYNC when one is due, so the rate is
quantised to the loop's period.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.core.rotations import so3_exp, so3_log
from drivers.pdo_codec import encode_tracker_frames


@dataclass(frozen=True)
class TrackerParams:
    rate_hz: float
    position_noise_m: float
    angle_noise_rad: float
    seed: int

    def __post_init__(self) -> None:
        if not self.rate_hz > 0.0:
            raise ValueError(f"sim.tracker.rate_hz must be positive, got {self.rate_hz}")
        if self.position_noise_m < 0.0 or self.angle_noise_rad < 0.0:
            raise ValueError(
                f"sim.tracker noise must be >= 0, got {self.position_noise_m} m, {self.angle_noise_rad} rad"
            )


class SimulatedPoseTracker:
    def __init__(self, params: TrackerParams) -> None:
        self.params = params
        self._rng = np.random.default_rng(params.seed)
        self._next_s: float | None = None
        self.counter = 0

    def frames(
        self, now_s: float, position_m: np.ndarray, rotation: np.ndarray
    ) -> tuple[bytes, bytes] | None:
        """The two TPDOs of a sample of the pose (P [m], R) if one is due at ``now_s``, else None."""
        period = 1.0 / self.params.rate_hz
        if self._next_s is not None and now_s < self._next_s - 1e-9:
            return None
        # the next sample one period on from when this one was due (no drift from the SYNC grid)
        self._next_s = now_s + period if self._next_s is None else max(self._next_s + period, now_s)
        p = np.asarray(position_m, dtype=float) + self._rng.normal(0.0, self.params.position_noise_m, 3)
        r = so3_log(so3_exp(self._rng.normal(0.0, self.params.angle_noise_rad, 3)) @ np.asarray(rotation))
        self.counter = (self.counter + 1) % 256
        return encode_tracker_frames(
            (float(p[0]), float(p[1]), float(p[2])), (float(r[0]), float(r[1]), float(r[2])), 0, self.counter
        )
