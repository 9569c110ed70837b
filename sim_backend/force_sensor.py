"""A simulated 6-axis force/torque sensor answering SYNC with two TPDOs.

It measures the wrench the environment applies, plus a constant bias and Gaussian noise,
quantises it to the PDO's fixed point, saturates at its range (and flags it in the status
byte), and counts its samples in a rolling 8-bit counter so the controller can detect
stale data.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drivers.pdo_codec import (
    FORCE_N_PER_COUNT,
    SENSOR_FORCE_SATURATED,
    TORQUE_NM_PER_COUNT,
    encode_sensor_frame,
)


@dataclass(frozen=True)
class SensorParams:
    noise_std_n: float
    bias_n: tuple[float, float, float]
    range_n: float
    seed: int


@dataclass
class SimulatedForceSensor:
    params: SensorParams
    counter: int = 0
    status_flags: int = 0  # extra status bits forced by fault injection
    rng: np.random.Generator = field(init=False)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.params.seed)

    def sample(self, force_n: np.ndarray, torque_nm: np.ndarray) -> tuple[bytes, bytes]:
        p = self.params
        measured = np.asarray(force_n, dtype=float) + np.asarray(p.bias_n) + self.rng.normal(0.0, p.noise_std_n, 3)
        status = self.status_flags
        if np.any(np.abs(measured) > p.range_n):
            status |= SENSOR_FORCE_SATURATED
            measured = np.clip(measured, -p.range_n, p.range_n)
        self.counter = (self.counter + 1) & 0xFF
        f = encode_sensor_frame(tuple(measured.tolist()), FORCE_N_PER_COUNT, status, self.counter)  # type: ignore[arg-type]
        t = encode_sensor_frame(tuple(np.asarray(torque_nm, float).tolist()), TORQUE_NM_PER_COUNT, status,
                                self.counter)  # type: ignore[arg-type]
        return f, t
