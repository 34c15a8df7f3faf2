"""A progress line on stderr for long commands (record, replay): in place on a terminal, one line each
time otherwise (a log file keeps them all)."""

from __future__ import annotations

from typing import TextIO

_CLEAR = "\r\x1b[K"  #: back to the start of the line and erase it


def human_size(size: int) -> str:
    """``size`` [bytes] as ``12.3 MB``."""
    value = float(size)
    for unit in ("B", "kB", "MB", "GB"):
        if value < 1000 or unit == "GB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1000
    raise AssertionError("not reached")


class Progress:
    """Writes progress to ``out``; ``tty``: rewrite one line in place."""

    def __init__(self, out: TextIO, tty: bool) -> None:
        self.out, self.tty = out, tty
        self._shown = False  # a progress line stands unfinished on the terminal

    def show(self, line: str) -> None:
        """The current progress, replacing the previous one on a terminal."""
        if self.tty:
            self.out.write(f"{_CLEAR}{line}")
            self._shown = True
        else:
            self.out.write(f"{line}\n")
        self.out.flush()

    def say(self, line: str) -> None:
        """A line that stays (a start, an end, a warning)."""
        if self._shown:
            self.out.write(_CLEAR)
            self._shown = False
        self.out.write(f"{line}\n")
        self.out.flush()

    done = say
