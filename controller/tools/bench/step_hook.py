"""A law whose step runs through a hook: how the benches time or watch the step on a simulated rig.

A wrapper, not an assignment to ``law.step``: a compiled law's methods are read-only. Everything
else is the law's own (``__getattr__``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

# around(step, state, inputs, t): runs ``step(state, inputs, t)`` and returns what it returns
StepAround = Callable[[Callable[[Any, Any, float], Any], Any, Any, float], Any]


class StepHookedLaw:
    """``law`` with ``around`` called in place of each ``step``."""

    def __init__(self, law: Any, around: StepAround) -> None:
        self._law, self._around = law, around

    def step(self, state: Any, inputs: Any, t: float) -> Any:
        return self._around(self._law.step, state, inputs, t)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._law, name)
