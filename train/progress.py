"""When to draw progress bars: they go to stderr, so only when the user asked for them (no
--no-progress, not --json) AND stderr is a terminal. Redirected to a log file or a pipe (CI, nohup,
`2> log`) a tqdm bar is only noise, so the commands stay quiet there."""

from __future__ import annotations

import sys


def show_progress(requested: bool = True, stream=None) -> bool:
    """True when progress bars should be drawn: `requested` and `stream` (default sys.stderr) is a TTY."""
    if not requested:
        return False
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty()) if callable(isatty) else False
    except (ValueError, OSError):  # a closed stream
        return False
