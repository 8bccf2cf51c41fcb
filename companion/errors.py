"""Errors the user can fix (bad input, a file that is not what the command needs).

Library code raises a subclass of :class:`UserError` with one sentence saying what is wrong and,
where it helps, what to do; the command line (:func:`companion.cli.main.main`) prints that sentence
and exits with :attr:`UserError.exit_code`, without a traceback.
"""
from __future__ import annotations


class UserError(Exception):
    """Bad input or an unusable file, explained in one sentence (CLI: message, exit code 1)."""

    exit_code: int = 1
