"""Exceptions. Every error a user can cause is an :class:`InputError` (exit code 2 on the CLI)."""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input: a file, row, column, key or parameter is named in the message."""


class ConvergenceError(RuntimeError):
    """An iterative solver did not converge; the message names the poses concerned."""


class Terminated(SystemExit):
    """SIGTERM or SIGHUP: unwind like Ctrl-C (staged outputs discarded), exit 128 + signal."""


#: The interruption this process received (set by :func:`on_interrupt` and
#: :func:`on_terminate`), kept because an extension module may swallow the exception the
#: signal raised inside it and raise its own instead (pybind11's array conversion turns a
#: Ctrl-C during a matplotlib draw into "ValueError: Invalid bounding box").
_received: BaseException | None = None


def forget_signals() -> None:
    """Forget the interruption received so far (a new command starts in this process)."""
    global _received
    _received = None


def on_interrupt(signum, frame) -> None:
    """Signal handler of SIGINT: raise :class:`KeyboardInterrupt` as Python's own handler does,
    and remember it for :func:`interruption`.

    Parameters
    ----------
    signum : int
        The signal's number.
    frame : frame or None
        The interrupted frame (unused).

    Raises
    ------
    KeyboardInterrupt
        Always.
    """
    global _received
    _received = KeyboardInterrupt()
    raise KeyboardInterrupt


def on_terminate(signum, frame) -> None:
    """Signal handler of SIGTERM and SIGHUP: raise :class:`Terminated` (exit 128 + signal),
    and remember it for :func:`interruption`.

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
    global _received
    _received = Terminated(128 + signum)
    raise Terminated(128 + signum)


def interruption(exc: BaseException | None) -> BaseException | None:
    """The Ctrl-C (:class:`KeyboardInterrupt`) or :class:`Terminated` that caused ``exc``, if
    any. A signal that arrives inside an extension module can surface as another exception:
    an ``ImportError`` ("initialization failed") whose cause or context is the signal's
    exception, or - where the module swallowed it - one with no trace of it; so a signal
    received through :func:`on_interrupt` or :func:`on_terminate` (since
    :func:`forget_signals`) is the cause of whatever failure follows it.

    Parameters
    ----------
    exc : BaseException or None
        The exception caught.

    Returns
    -------
    BaseException or None
        The interruption in ``exc``'s chain (``exc`` itself included), else the signal
        received, else None.
    """
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (KeyboardInterrupt, Terminated)):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return _received
