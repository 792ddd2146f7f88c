"""Exceptions. Every error a user can cause is an :class:`InputError` (exit code 2 on the CLI)."""

from __future__ import annotations

import os
import signal
import sys


class InputError(ValueError):
    """Bad user input: a file, row, column, key or parameter is named in the message."""


class ConvergenceError(RuntimeError):
    """An iterative solver did not converge; the message names the poses concerned."""


class Terminated(SystemExit):
    """SIGTERM or SIGHUP: unwind like Ctrl-C (staged outputs discarded), exit 128 + signal."""


#: The interruption this process received (set by :func:`on_signal`), kept because an
#: extension module may swallow the exception the signal raised inside it and raise its own
#: instead (pybind11's array conversion turns a Ctrl-C during a matplotlib draw into
#: "ValueError: Invalid bounding box").
_received: BaseException | None = None


def forget_signals() -> None:
    """Forget the interruption received so far (a new command starts in this process)."""
    global _received
    _received = None


def on_signal(signum, frame) -> None:
    """Signal handler of SIGINT, SIGTERM and SIGHUP: raise :class:`KeyboardInterrupt` for
    SIGINT (as Python's own handler does), :class:`Terminated` (exit 128 + signal) for the
    others, and remember it for :func:`interruption`.

    Parameters
    ----------
    signum : int
        The signal's number.
    frame : frame or None
        The interrupted frame (unused).

    Raises
    ------
    KeyboardInterrupt or Terminated
        Always.
    """
    global _received
    exc = KeyboardInterrupt() if signum == signal.SIGINT else Terminated(128 + signum)
    _received = exc
    raise exc


def on_unraisable(unraisable) -> None:
    """``sys.unraisablehook`` under pkmcal's handlers. An exception Python cannot raise (in a
    weakref callback, a ``__del__``, a garbage-collector callback) is dropped, and by default
    printed as "Exception ignored in ..." with a traceback. A signal's exception dropped so
    is already remembered by :func:`on_signal`: the run stops at its next progress step
    (:func:`stop_if_signalled`) and commits nothing; it is not printed. Any other is printed
    only with ``PKMCAL_DEBUG=1`` (a command's error output is one line).

    Parameters
    ----------
    unraisable : object
        What Python passes to ``sys.unraisablehook`` (``exc_value`` is used).
    """
    if not isinstance(unraisable.exc_value, (KeyboardInterrupt, Terminated)) and \
            os.environ.get("PKMCAL_DEBUG"):
        sys.__unraisablehook__(unraisable)


def stop_if_signalled() -> None:
    """Raise the interruption remembered since :func:`forget_signals`, if any: a signal whose
    exception something swallowed still stops the run (called at progress steps and before a
    commit).

    Raises
    ------
    KeyboardInterrupt or Terminated
        A signal came.
    """
    if _received is not None:
        raise _received


def handle_signals() -> dict:
    """Install :func:`on_signal` for SIGINT, SIGTERM and SIGHUP (where the platform has them)
    and :func:`on_unraisable`; main thread only.

    Returns
    -------
    dict
        What was replaced (handlers by signal, and the hook), for :func:`restore_signals`.
    """
    previous = {getattr(signal, name): signal.signal(getattr(signal, name), on_signal)
                for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)}
    previous["unraisablehook"] = sys.unraisablehook
    sys.unraisablehook = on_unraisable
    return previous


def restore_signals(previous: dict) -> None:
    """Put back what :func:`handle_signals` replaced.

    Parameters
    ----------
    previous : dict
        What :func:`handle_signals` returned.
    """
    previous = dict(previous)
    sys.unraisablehook = previous.pop("unraisablehook", sys.unraisablehook)
    for signum, handler in previous.items():
        signal.signal(signum, signal.SIG_DFL if handler is None else handler)


def interruption_exit(cause: BaseException) -> tuple[str, int]:
    """How a run that ``cause`` (a Ctrl-C or a :class:`Terminated`) interrupted ends: its one
    line (after ``error: ``) and exit code.

    Parameters
    ----------
    cause : KeyboardInterrupt or Terminated
        The interruption (:func:`interruption`).

    Returns
    -------
    tuple of (str, int)
        ``("interrupted", 130)`` or ``("terminated (signal n)", 128 + n)``.
    """
    if isinstance(cause, Terminated):
        return f"terminated (signal {int(cause.code) - 128})", int(cause.code)
    return "interrupted", 130


def interruption(exc: BaseException | None) -> BaseException | None:
    """The Ctrl-C (:class:`KeyboardInterrupt`) or :class:`Terminated` that caused ``exc``, if
    any. A signal that arrives inside an extension module can surface as another exception:
    an ``ImportError`` ("initialization failed") whose cause or context is the signal's
    exception, or - where the module swallowed it - one with no trace of it; so a signal
    received through :func:`on_signal` (since :func:`forget_signals`) is the cause of
    whatever failure follows it.

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
