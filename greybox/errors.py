"""Errors greybox raises for user mistakes and for solver failures.

A :class:`GreyboxInputError` is a user mistake (a bad file, a bad option): the CLI prints
its message alone and exits with status 2, never a traceback. A :class:`SolverError`
is a numerical failure that is reported, not hidden.
"""
from __future__ import annotations


class GreyboxError(Exception):
    """Base class of greybox's own errors.

    Example::

        from greybox import GreyboxError, load_log
        try:
            log = load_log("flight.csv")
        except GreyboxError as e:           # a bad input or a failed solver
            print(e)
    """


class GreyboxInputError(GreyboxError, ValueError):
    """Bad input from the user: the message names the file, row, column or parameter.

    Example::

        from greybox import GreyboxInputError, load_log
        try:
            log = load_log("flight.csv")
        except GreyboxInputError as e:      # also a ValueError
            print(e)    # flight.csv: row 17, column 'w2': missing value (time and inputs ...)
    """


class SolverError(GreyboxError, RuntimeError):
    """A numerical solver failed; the message carries the solver's own reason.

    Example::

        try:
            x_trim, u_trim = hover_trim(model, p)
        except SolverError as e:            # e.g. no hover trim: IPOPT's status
            print(e)
    """


class ConvergenceWarning(UserWarning):
    """A fit stopped before a certified optimum; its result says why (``FitResult.status``,
    ``FitResult.certificate``). Warned, not raised: the result is still returned.

    Example::

        import warnings
        from greybox import ConvergenceWarning, fit
        with warnings.catch_warnings():
            warnings.simplefilter("error", ConvergenceWarning)   # an uncertified fit raises
            res = fit(model, log)
    """


class AirframeWarning(UserWarning):
    """An airframe accepted with a doubt (e.g. inertias that break ``J1 + J2 >= J3`` within
    measurement error).

    Example::

        import warnings
        from greybox import AirframeWarning, load_airframe
        with warnings.catch_warnings():
            warnings.simplefilter("error", AirframeWarning)      # accept no doubtful airframe
            af = load_airframe("greybox/data/airframes/paper.toml")
    """


class CacheWarning(UserWarning):
    """The compile cache could not be used as is (not writable, a broken library rebuilt);
    the work goes on, perhaps slower.

    Example::

        import warnings
        from greybox import CacheWarning
        warnings.filterwarnings("ignore", category=CacheWarning)   # e.g. on a read-only home
    """


class Terminated(BaseException):
    """SIGTERM, raised like Ctrl-C's ``KeyboardInterrupt`` so the same clean-up runs (compilers
    killed, temporary files removed, no output written)."""


_SIGNALS_RECEIVED: list[int] = []   # process-wide, like the signal handlers themselves


def raise_terminated(signum, frame) -> None:
    """A SIGTERM handler: turn the signal into :class:`Terminated` (and remember it)."""
    _SIGNALS_RECEIVED.append(signum)
    raise Terminated()


def raise_interrupted(signum, frame) -> None:
    """A SIGINT handler: ``KeyboardInterrupt``, as Python's own, but remembered: an interrupt
    raised inside a C extension's callback can surface as another exception (CasADi turns
    it into ``SystemError``), and the CLI must still report it as an interrupt."""
    _SIGNALS_RECEIVED.append(signum)
    raise KeyboardInterrupt()


def forget_signals() -> None:
    """Forget the signals received so far (at the start of a command run in-process)."""
    _SIGNALS_RECEIVED.clear()


def signal_received() -> int | None:
    """The last SIGINT/SIGTERM received through the handlers above, or None."""
    return _SIGNALS_RECEIVED[-1] if _SIGNALS_RECEIVED else None


def interrupt_status(exc: BaseException) -> int | None:
    """The CLI's exit status for an interrupt — 130 (Ctrl-C, SIGINT) or 143 (SIGTERM) — after
    printing its one line, or None when ``exc`` is not one. Also an exception a C extension
    made out of an interrupt (CasADi raises ``SystemError`` from a callback it ran into).

    The signal the handlers above recorded decides which: an extension can turn the
    :class:`Terminated` our SIGTERM handler raised into a ``KeyboardInterrupt`` (CasADi's
    interrupt check, while a compiler ran, does), and a SIGTERM is still a SIGTERM."""
    import signal
    import sys
    sig = signal_received()
    if sig is None:
        if isinstance(exc, KeyboardInterrupt):
            sig = signal.SIGINT
        elif isinstance(exc, Terminated):
            sig = signal.SIGTERM
        else:
            return None
    print("greybox: interrupted" if sig == signal.SIGINT else "greybox: terminated", file=sys.stderr)
    return 130 if sig == signal.SIGINT else 143
