"""A clock for tests that moves on by a fixed step at each reading: code that polls a clock (a
guard's watch, a spin to a deadline, a tool's part timers) sees time pass without any wall-clock
wait, and a test can say exactly how much passed."""

from __future__ import annotations


class SteppingClock:
    """Each reading ``step_s`` after the last one; the first is ``start_s + step_s``."""

    def __init__(self, step_s: float, start_s: float = 0.0) -> None:
        self.step_s = step_s
        self.now_s = start_s  # the last reading

    def __call__(self) -> float:
        self.now_s += self.step_s
        return self.now_s
