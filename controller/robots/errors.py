"""Exceptions shared by the robot models."""

from controller.errors import RefusedError


class NoSolutionError(RefusedError):
    """A kinematic problem has no solution on the configured branch; the message says why."""
