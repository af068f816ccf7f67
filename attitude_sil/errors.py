"""The one error family of attitude_sil.

Every error a user can cause (a bad scenario, tuning spec or parameter file, a
corrupt bag, a graph that does not connect, a node that refuses a parameter)
derives from :class:`AttitudeSilError`. It subclasses ``ValueError``, as the
errors of python-control and numpy do for bad input, so existing ``except
ValueError`` code keeps working. The ``attitude-sil`` command turns any of
them into one line on stderr and exit code 2; a traceback always means a bug.

This module imports nothing from the package, so every layer can use it.
"""

from __future__ import annotations

__all__ = [
    "AttitudeSilError",
    "ScenarioError",
    "SpecError",
    "BagError",
    "BagWriteError",
    "RunError",
    "ParamClientError",
    "SchedulerLostError",
    "NonFiniteWarning",
]


class AttitudeSilError(ValueError):
    """Base of every user-facing error; the message is one line naming the problem."""


class ScenarioError(AttitudeSilError):
    """A scenario file or parameter value that cannot be used."""


class SpecError(AttitudeSilError):
    """A tuning spec that cannot be used; names the file and the key."""


class BagError(AttitudeSilError):
    """A bag cannot be read; names the file and the problem."""


class BagWriteError(AttitudeSilError, RuntimeError):
    """A bag cannot be written (disk full, permissions, ...); names the file."""


class RunError(AttitudeSilError, RuntimeError):
    """An episode could not run or did not finish (discovery, timeout, refused reset)."""


class ParamClientError(AttitudeSilError, RuntimeError):
    """A node is not there, has no such parameter, or refused a value."""


class SchedulerLostError(AttitudeSilError, RuntimeError):
    """The Dask scheduler a batch evaluation ran on went away mid-run; names its address and how it was lost.

    Attributes
    ----------
    address : str
        The scheduler's address, as the client was given it.
    """

    def __init__(self, message: str, address: str) -> None:
        super().__init__(message)
        self.address = address

    def __reduce__(self):
        # rebuilt from both arguments (the default would pass the message alone)
        return type(self), (str(self), self.address)


class NonFiniteWarning(UserWarning):
    """Episodes of a batch run went non-finite (a law commanded NaN or inf, or the state diverged); names the
    episodes and the laws they ran."""
