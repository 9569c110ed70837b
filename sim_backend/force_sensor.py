"""A simulated 6-axis force/torque sensor answering SYNC with two TPDOs.

It sees the wrench the environment applies through a first-order anti-aliasing filter
(``bandwidth_hz``), samples it at its own rate (``sample_rate_hz``), adds a constant bias
and Gaussian noise per sample, quantises to the PDO's fixed point, saturates at its range
(and flags it in the status byte), and counts its transmitted samples in a rolling 8-bit
counter so the controller can detect stale data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from controller.core.cycle_data import SENSOR_FORCE_SATURATED, SENSOR_TORQUE_SATURATED
from drivers.pdo_codec import FORCE_N_PER_COUNT, SENSOR_TPDO, TORQUE_NM_PER_COUNT, saturating_i16


@dataclass(frozen=True)
class SensorParams:
    noise_std_n: float
    bias_n: tuple[float, float, float]
    range_n: float
    seed: int
    sample_rate_hz: float = 1000.0
    bandwidth_hz: float = 200.0


@dataclass
class SimulatedForceSensor:
    params: SensorParams
    counter: int = 0
    status_flags: int = 0  # extra status bits forced by fault injection
    freeze_counter: bool = False  # fault injection: the counter stops advancing
    hold_sample: bool = False  # fault injection: the sample stops changing, its counter advancing
    extra_force_n: tuple[float, float, float] = (0.0, 0.0, 0.0)  # fault injection: an unexpected force
    rng: np.random.Generator = field(init=False)
    _filtered_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    _torque: np.ndarray = field(default_factory=lambda: np.zeros(3))
    _sample: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the latest sample [N], bias and noise in
    _next_sample_s: float | None = None
    _alpha: float = 1.0
    _alpha_dt: float = -1.0
    object_values: dict[tuple[int, int], int] = field(default_factory=dict)  # latched at each SYNC

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.params.seed)
        bx, by, bz = self.params.bias_n
        self._sample = (float(bx), float(by), float(bz))

    def observe(self, t_s: float, dt: float, fx_n: float, fy_n: float, fz_n: float) -> None:
        """Filter the true force over ``dt`` and take a sample when one is due (plain floats: every sub-step)."""
        if dt != self._alpha_dt:  # the plant's sub-step is constant: compute the factor once
            self._alpha = 1.0 - math.exp(-2.0 * math.pi * self.params.bandwidth_hz * dt)
            self._alpha_dt = dt
        a = self._alpha
        f = self._filtered_xyz
        f0, f1, f2 = f[0] + a * (fx_n - f[0]), f[1] + a * (fy_n - f[1]), f[2] + a * (fz_n - f[2])
        self._filtered_xyz = (f0, f1, f2)
        if self._next_sample_s is None or t_s >= self._next_sample_s:
            p = self.params
            b = p.bias_n
            n = self.rng.normal(0.0, p.noise_std_n, 3).tolist()  # the same draws as ever: one call of 3
            if not self.hold_sample:  # held: a dead bridge or a hung converter; the draws go on
                # plain floats, as numpy adds them element by element: the same sums, a third of the time
                self._sample = (f0 + b[0] + n[0], f1 + b[1] + n[1], f2 + b[2] + n[2])
            self._next_sample_s = (self._next_sample_s or t_s) + 1.0 / p.sample_rate_hz

    def latch(self) -> dict[tuple[int, int], int]:
        """Answer a SYNC: the latest sample as the values of the objects a TPDO maps, in counts.

        Objects 0x2000sub1..3 (force, FORCE_N_PER_COUNT), 0x2001sub1..3 (torque), 0x2002 (status),
        0x2003 (counter) of drivers/eds/force_sensor.eds; the TPDOs pack them as mapped.
        """
        r = self.params.range_n
        s, e = self._sample, self.extra_force_n
        measured = [s[0] + e[0], s[1] + e[1], s[2] + e[2]]
        status = self.status_flags
        if abs(measured[0]) > r or abs(measured[1]) > r or abs(measured[2]) > r:
            status |= SENSOR_FORCE_SATURATED
            measured = [min(max(m, -r), r) for m in measured]
        if not self.freeze_counter:
            self.counter = (self.counter + 1) & 0xFF
        values = self.object_values
        for k, (f, t) in enumerate(zip(measured, self._torque.tolist()), start=1):
            cf, sf = saturating_i16(f, FORCE_N_PER_COUNT)
            ct, st = saturating_i16(t, TORQUE_NM_PER_COUNT)
            status |= (SENSOR_FORCE_SATURATED if sf else 0) | (SENSOR_TORQUE_SATURATED if st else 0)
            values[(0x2000, k)], values[(0x2001, k)] = cf, ct
        values[(0x2002, 0)] = status & 0xFF
        values[(0x2003, 0)] = self.counter
        return values

    def frames(self) -> tuple[bytes, bytes]:
        """The two TPDOs answering a SYNC in the EDS's default mapping: the latest sample."""
        v = self.latch()
        status, counter = v[(0x2002, 0)], v[(0x2003, 0)]
        f = SENSOR_TPDO.pack(v[(0x2000, 1)], v[(0x2000, 2)], v[(0x2000, 3)], status, counter)
        t = SENSOR_TPDO.pack(v[(0x2001, 1)], v[(0x2001, 2)], v[(0x2001, 3)], status, counter)
        return f, t

    def sample(self, force_n: np.ndarray, torque_nm: np.ndarray) -> tuple[bytes, bytes]:
        """Observe a constant wrench long enough for the filter to settle, then answer a SYNC."""
        fx, fy, fz = (float(v) for v in force_n)
        self._filtered_xyz = (fx, fy, fz)
        self._next_sample_s = None
        self._alpha_dt = -1.0
        self._torque = np.asarray(torque_nm, dtype=float)
        self.observe(0.0, 0.0, fx, fy, fz)
        return self.frames()
