"""Errors greybox raises for user mistakes and for solver failures.

A :class:`GreyboxInputError` is a user mistake (a bad file, a bad option): the CLI prints
its message alone and exits with status 2, never a traceback. A :class:`SolverError`
is a numerical failure that is reported, not hidden.
"""
from __future__ import annotations


class GreyboxError(Exception):
    """Base class of greybox's own errors."""


class GreyboxInputError(GreyboxError, ValueError):
    """Bad input from the user: the message names the file, row, column or parameter."""


class SolverError(GreyboxError, RuntimeError):
    """A numerical solver failed; the message carries the solver's own reason."""


class ConvergenceWarning(UserWarning):
    """A fit stopped before converging; its result says why (``FitResult.status``)."""


class AirframeWarning(UserWarning):
    """An airframe accepted with a doubt (e.g. inertias that break ``J1 + J2 >= J3`` within
    measurement error)."""


class CacheWarning(UserWarning):
    """The compile cache could not be used as is (not writable, a broken library rebuilt);
    the work goes on, perhaps slower."""


class Terminated(BaseException):
    """SIGTERM, raised like Ctrl-C's ``KeyboardInterrupt`` so the same clean-up runs (compilers
    killed, temporary files removed, no output written)."""


def raise_terminated(signum, frame) -> None:
    """A SIGTERM handler: turn the signal into :class:`Terminated`."""
    raise Terminated()
