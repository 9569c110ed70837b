"""The loop's exchange wrapped by a bench tool: its own where the wrapper does not say otherwise.

A wrapper, not an assignment to the exchange's methods: the cyclic exchange runs compiled, and its
methods cannot be replaced on the object. The loop asks its exchange what else it can do with
``isinstance`` against runtime-checkable Protocols (``CycleDeadlines``, ``SdoControlwords`` in
controller/shell/loop.py). Python 3.11 answers those with ``hasattr``, which ``__getattr__``
forwarding satisfies; from 3.12 they read the attributes with ``inspect.getattr_static``, which never
calls ``__getattr__``, and a forwarding wrapper would have lost the kernel SYNC's deadlines and the
quick stop's SDO controlwords. So those methods are set on the wrapper itself, exactly when the
exchange has them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

# the exchange's methods that the loop checks for (controller/shell/loop.py's runtime Protocols)
OPTIONAL_METHODS = ("cycle_deadline", "send_controlword_by_sdo")


# what a wrapper calls in place of the exchange's optional method: given its name and the method
OptionalWrap = Callable[[str, Callable[..., Any]], Callable[..., Any]]


class WrappedExchange:
    """``inner`` with the methods a subclass overrides; the rest is ``inner``'s (module text).
    ``wrap`` gives what the wrapper calls in place of each optional method ``inner`` has (None:
    the method itself)."""

    def __init__(self, inner: Any, wrap: OptionalWrap | None = None) -> None:
        self.inner = inner
        for name in OPTIONAL_METHODS:
            method = getattr(inner, name, None)
            if method is not None:
                setattr(self, name, method if wrap is None else wrap(name, method))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)
