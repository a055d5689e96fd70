"""How progress is shown. On a terminal: tqdm bars on stderr, when the user asked for them (no
--no-progress, not --json). Redirected to a log file or a pipe (CI, nohup, `2> log`) a bar is only noise,
so there a long command writes plain lines instead, at a bounded rate (`ProgressLines`), so that a log
still tells what is done and how long it took."""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from typing import TextIO

_clock = time.monotonic  # the tests replace it


def _isatty(stream) -> bool:
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty()) if callable(isatty) else False
    except (ValueError, OSError):  # a closed stream
        return False


def show_progress(requested: bool = True, stream: TextIO | None = None) -> bool:
    """True when progress bars should be drawn: `requested` and `stream` (default sys.stderr) is a TTY."""
    if not requested:
        return False
    return _isatty(sys.stderr if stream is None else stream)


class ProgressLines:
    """Plain progress lines for a log: `prefix` + text + the seconds since the start, one per line.

    A call writes only if at least `interval` seconds have passed since the last line (the start
    counts as one), unless `force` is set, which the callers use for the few lines that matter (what
    is about to run, the end of a phase). So a run of any length writes its forced lines plus at most
    one line every `interval` seconds."""

    def __init__(self, prefix: str = "", stream=None, interval: float = 10.0, clock=None):
        self.prefix = prefix
        self.stream = stream
        self.interval = float(interval)
        self.clock = clock or _clock
        self.t0 = self._last = self.clock()

    def elapsed(self) -> float:
        return self.clock() - self.t0

    def due(self) -> bool:
        """Would an unforced line be written now?"""
        return self.clock() - self._last >= self.interval

    def __call__(self, text: str, force: bool = False) -> bool:
        """Write `text` if due (or forced); True when it was written."""
        if not (force or self.due()):
            return False
        self._last = self.clock()
        stream = sys.stderr if self.stream is None else self.stream
        stream.write(f"{self.prefix}{text}, {self.elapsed():.0f} s\n")
        stream.flush()
        return True


def progress_lines(requested: bool = True, stream: TextIO | None = None, prefix: str = "",
                   interval: float = 10.0) -> ProgressLines | None:
    """The plain-line counterpart of `show_progress`: a ProgressLines on `stream` (default sys.stderr)
    when progress was `requested` and the stream is NOT a terminal (there the bars are drawn), else None."""
    if not requested or _isatty(sys.stderr if stream is None else stream):
        return None
    return ProgressLines(prefix, stream, interval)
