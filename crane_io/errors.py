"""Errors a user can act on, and the one way the command lines report them.

Every bad-input error in the project derives from `CraneError`; its message is one sentence a lab
user understands. The command lines catch it (crane_io.cli_support.cli_errors), print the sentence and
exit non-zero, never a traceback. This module imports no command-line library.

A message names a setting the user can change by its parameter name in backquotes (`duration`,
`leader_port`), never by a command-line flag: from Python the sentence reads as the name of the
argument to change; the command lines show their own flag in its place (`--duration`,
crane_io.cli_support.cli_errors), and a backquoted name that is no option of the command stays as it is.
"""

from __future__ import annotations


class CraneError(Exception):
    """A problem with the user's input, hardware or files, described in one sentence."""

    exit_code = 2


class ConfigError(CraneError):
    """A configuration file or option that cannot be used."""


class SessionFileError(CraneError):
    """A file that is not a readable crane-session (missing, foreign, truncated, NaNs, too short)."""


class SessionDamagedError(SessionFileError):
    """A session file whose stored data fail their checksum or cannot be decoded (names the dataset)."""


class SessionCloseError(SessionFileError):
    """The end of a recording (its end-of-run attributes or the file's close) could not be written;
    the rows already written are kept and the sentence says how to get an ordinary file."""


class NotRecoverableError(SessionFileError):
    """`crane-collect recover` refuses a file: not a crane-session, not crashed, or still being written."""


class HardwareError(CraneError):
    """A servo, port or bus problem (missing port, wrong model, servo silent, hardware-error bit)."""

    exit_code = 3
