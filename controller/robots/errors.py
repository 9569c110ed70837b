"""Exceptions shared by the robot models."""


class NoSolutionError(ValueError):
    """A kinematic problem has no solution on the configured branch; the message says why."""
