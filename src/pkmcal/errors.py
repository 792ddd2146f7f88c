"""Exceptions. Every error a user can cause is an :class:`InputError` (exit code 2 on the CLI)."""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input: a file, row, column, key or parameter is named in the message."""


class ConvergenceError(RuntimeError):
    """An iterative solver did not converge; the message names the poses concerned."""
