"""Homing of a simulated drive with an incremental encoder (CiA 402 homing mode 6).

An incremental encoder counts from wherever the carriage was at power-up: the drive's reported
position is the carriage's true position plus an offset nobody knows (``encoder_offset``,
configured in the simulator only). Homing finds a known place and sets the reported position
there to the home offset 0x607C, which removes the unknown offset:

- 35 and 37, "current position": the place where the carriage stands is home (CiA 402-2
  methods 35, obsolete, and 37);
- 17 and 18, limit switch without index pulse: move towards the negative (17) or positive (18)
  limit switch at the switch search speed (0x6099 sub 1), and when it closes, back away at the
  zero search speed (0x6099 sub 2) until it opens again; that edge is home; accelerations at
  0x609A. Reaching the end stop first is a homing error.

Positions and speeds here are in the drive's unit (m, or rad), in its true coordinates.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

CURRENT_POSITION_METHODS = (35, 37)
NEGATIVE_LIMIT_SWITCH = 17
POSITIVE_LIMIT_SWITCH = 18
SUPPORTED_METHODS = (NEGATIVE_LIMIT_SWITCH, POSITIVE_LIMIT_SWITCH, *CURRENT_POSITION_METHODS)


class HomingPhase(enum.Enum):
    IDLE = "idle"  # not started since the mode was entered
    SEARCH_SWITCH = "search switch"
    SEARCH_EDGE = "search edge"
    ATTAINED = "attained"
    ERROR = "error"


@dataclass(frozen=True)
class HomingSettings:
    """The homing objects as written by the master (0x6098, 0x607C, 0x6099, 0x609A)."""

    method: int = 0
    home_offset: float = 0.0  # the reported position at home [unit]
    switch_speed: float = 0.0  # [unit/s]
    zero_speed: float = 0.0
    acceleration: float = 0.0  # [unit/s^2]


@dataclass
class HomingRun:
    """One homing run from a start to attained or error: the carriage's motion and the result."""

    settings: HomingSettings
    negative_switch: float  # the switches' positions, true coordinates [unit]
    positive_switch: float
    stroke_min: float
    stroke_max: float
    phase: HomingPhase = HomingPhase.IDLE
    home_position: float = math.nan  # true coordinates of home, once attained

    def start(self, position: float) -> None:
        m = self.settings.method
        if m in CURRENT_POSITION_METHODS:
            self.home_position, self.phase = position, HomingPhase.ATTAINED
        elif (
            m in (NEGATIVE_LIMIT_SWITCH, POSITIVE_LIMIT_SWITCH)
            and self.settings.switch_speed > 0
            and self.settings.zero_speed > 0
            and self.settings.acceleration > 0
        ):
            self.phase = HomingPhase.SEARCH_SWITCH
        else:
            self.phase = HomingPhase.ERROR  # a method this drive does not have, or no speeds

    def _switch_closed(self, x: float) -> bool:
        if self.settings.method == NEGATIVE_LIMIT_SWITCH:
            return x <= self.negative_switch
        return x >= self.positive_switch

    def step(self, x: float, v: float, h: float) -> tuple[float, float]:
        """Move the carriage over ``h`` seconds; returns the new position and velocity."""
        s = self.settings
        toward = -1.0 if s.method == NEGATIVE_LIMIT_SWITCH else 1.0
        if self.phase == HomingPhase.SEARCH_SWITCH:
            v_cmd = toward * s.switch_speed
            if self._switch_closed(x):
                self.phase = HomingPhase.SEARCH_EDGE
        elif self.phase == HomingPhase.SEARCH_EDGE:
            v_cmd = -toward * s.zero_speed
            if not self._switch_closed(x):
                self.home_position, self.phase = x, HomingPhase.ATTAINED
                v_cmd = 0.0
        else:
            v_cmd = 0.0
        dv = v_cmd - v
        limit = s.acceleration * h
        v += max(-limit, min(limit, dv))
        x += v * h
        if not self.stroke_min <= x <= self.stroke_max:
            x, v = min(max(x, self.stroke_min), self.stroke_max), 0.0
            if self.phase in (HomingPhase.SEARCH_SWITCH, HomingPhase.SEARCH_EDGE):
                self.phase = HomingPhase.ERROR  # the end stop, and no switch on the way
        return x, v

    @property
    def moving(self) -> bool:
        return self.phase in (HomingPhase.SEARCH_SWITCH, HomingPhase.SEARCH_EDGE)
