"""Exceptions. Every error a user can cause is an :class:`InputError` (exit code 2 on the CLI)."""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input: a file, row, column, key or parameter is named in the message."""


class ConvergenceError(RuntimeError):
    """An iterative solver did not converge; the message names the poses concerned."""


class Terminated(SystemExit):
    """SIGTERM or SIGHUP: unwind like Ctrl-C (staged outputs discarded), exit 128 + signal."""


def on_terminate(signum, frame) -> None:
    """Signal handler of SIGTERM and SIGHUP: raise :class:`Terminated` (exit 128 + signal).

    Parameters
    ----------
    signum : int
        The signal's number.
    frame : frame or None
        The interrupted frame (unused).

    Raises
    ------
    Terminated
        Always, with code ``128 + signum``.
    """
    raise Terminated(128 + signum)


def interruption(exc: BaseException | None) -> BaseException | None:
    """The Ctrl-C (:class:`KeyboardInterrupt`) or :class:`Terminated` that caused ``exc``, if
    any: a signal that arrives while an extension module initialises surfaces as an
    ``ImportError`` ("initialization failed") whose cause or context is the signal's
    exception.

    Parameters
    ----------
    exc : BaseException or None
        The exception caught.

    Returns
    -------
    BaseException or None
        The interruption in ``exc``'s chain (``exc`` itself included), else None.
    """
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (KeyboardInterrupt, Terminated)):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None
