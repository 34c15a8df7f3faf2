"""A run of a low-level client's position commands the servo drops, said once with why.

The SyncFIFO (``Servo/posCmd``) has no reply: a client whose stream the servo
does not take would only see its arm stand still. The servo says so in its log
once when a run of drops starts (why: the servo off, an alarm, a motion
running) and once when its reason ends (how many it dropped), never once per
command: a 1 kHz stream would flood the log.
"""

from __future__ import annotations

import logging
from typing import Any


class DropRun:
    """The current run of dropped commands: its reason and length."""

    def __init__(self, log: logging.LoggerAdapter[Any], key: str) -> None:
        self._log = log
        self._key = key
        self.why: str | None = None  #: the reason of the run going on; None: no run
        self.count = 0  #: commands dropped in it

    def drop(self, why: str) -> None:
        """One command dropped for ``why``."""
        if why != self.why:
            self.holds(why)
            self.why = why
            self._log.warning("dropping the position commands of %s: %s", self._key, why)
        self.count += 1

    def holds(self, why: str | None) -> None:
        """Every cycle, the reason commands are dropped now (None: they are taken): a run of another reason
        is over, said with its length."""
        if self.why is not None and why != self.why:
            self._log.info("dropped %d position command(s) of %s (%s)", self.count, self._key, self.why)
            self.why, self.count = None, 0
