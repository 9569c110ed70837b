"""One root for the errors this project raises on purpose, and three kinds a caller can act on.

The command line (controller/cli.py) turns each into one line and exit code 2: ``InputError``
and ``DeviceError`` as "error", ``RefusedError`` as "refused". The builtin base each subclass
also has (ValueError, RuntimeError, OSError, ConnectionError) keeps ``except ValueError`` code
working.
"""

from __future__ import annotations


class CheopeError(Exception):
    """Root of every error raised on purpose in controller/, drivers/, sim_backend/ and logs/."""


class InputError(CheopeError, ValueError):
    """Bad input from a user or a peer: a configuration value, an option, a bus or fault spec, a
    recording, a frame. The message names what was wrong and what is allowed."""


class RefusedError(CheopeError, ValueError):
    """A well-formed request that is unsafe or impossible: a path outside the workspace or too
    close to a singularity, a motion plan that does not converge, a pose with no assembly."""


class DeviceError(CheopeError):
    """A device, bus, process or permission problem: a node that does not answer its set-up, a
    simulator that does not start, a monitoring peer that cannot be reached, a recording that
    cannot be written."""


class NoSolutionError(RefusedError):
    """A kinematic problem has no solution on the configured branch; the message says why."""


class WorkspaceError(RefusedError):
    """A pose or path violates the workspace, the joint limits or the singularity margins."""
