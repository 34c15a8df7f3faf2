"""Service processes of ``jara-arm up``: start, watch, restart with backoff, stop in order.

Nothing here touches Zenoh. Every method is meant to be called from the
launcher's main loop (one thread); the only other threads read the children's
output into a bounded tail, kept to say why a child crashed.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Mapping, Sequence

log = logging.getLogger("jara_arm.launcher")

INITIAL_BACKOFF = 0.5  #: delay before the first restart after a crash [s]
MAX_BACKOFF = 10.0  #: the delay doubles up to this [s]
STABLE_AFTER = 30.0  #: a child that ran this long before dying restarts after INITIAL_BACKOFF again [s]
STOP_GRACE = 5.0  #: time a child has to exit after SIGTERM before its process group is killed [s]
TAIL_LINES = 50  #: output lines kept per child
_CRASH_SIGNALS = {signal.SIGSEGV, signal.SIGABRT, signal.SIGBUS, signal.SIGFPE, signal.SIGILL}


def describe_exit(returncode: int) -> str:
    """``exited with code 1`` or ``died with SIGKILL``."""
    if returncode >= 0:
        return f"exited with code {returncode}"
    try:
        return f"died with {signal.Signals(-returncode).name}"
    except ValueError:
        return f"died with signal {-returncode}"


def _is_error(returncode: int) -> bool:
    """Did the child fail on its own (so its last lines say why), not just get killed?"""
    if returncode >= 0:
        return returncode != 0
    with contextlib.suppress(ValueError):
        return signal.Signals(-returncode) in _CRASH_SIGNALS
    return False


class Child:
    """One service process of one arm; started again whenever it dies."""

    def __init__(self, label: str, argv: Sequence[str], env: Mapping[str, str] | None = None,
                 echo: Callable[[str], None] | None = None) -> None:
        self.label = label  #: e.g. ``servo (arm0)``
        self.argv = list(argv)
        self.echo = echo  #: called with each line the process prints (besides keeping its tail)
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.popen: subprocess.Popen[str] | None = None
        self.tail: collections.deque[str] = collections.deque(maxlen=TAIL_LINES)
        self.backoff = INITIAL_BACKOFF
        self.started_at = 0.0  #: monotonic time of the last start [s]
        self.restart_at: float | None = None  #: monotonic time of the pending restart [s]
        self._reader: threading.Thread | None = None

    @property
    def pid(self) -> int | None:
        return self.popen.pid if self.popen else None

    @property
    def running(self) -> bool:
        return self.popen is not None and self.popen.poll() is None

    def start(self) -> None:
        """Start the process; a failure to start counts as a crash (retried with backoff)."""
        self.restart_at = None
        self.started_at = time.monotonic()
        self.tail = collections.deque(maxlen=TAIL_LINES)  # the tail of this run only
        try:
            # A session of its own: Ctrl-C in a terminal reaches only the launcher,
            # which stops the children in order; fork+exec, never a bare fork.
            self.popen = subprocess.Popen(
                self.argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT, text=True, errors="replace", env=self.env,
                start_new_session=True, close_fds=True)
        except OSError as exc:
            self.popen = None
            log.error("cannot start %s: %s", self.label, exc)
            self._schedule_restart(time.monotonic())
            return
        log.info("started %s: pid %d", self.label, self.popen.pid)
        log.debug("%s command: %s", self.label, " ".join(self.argv))
        self._reader = threading.Thread(target=self._read, args=(self.popen, self.tail, self.echo),
                                        name=f"output {self.label}", daemon=True)
        self._reader.start()

    @staticmethod
    def _read(popen: subprocess.Popen[str], tail: collections.deque[str],
              echo: Callable[[str], None] | None) -> None:
        assert popen.stdout is not None
        with popen.stdout:
            for line in popen.stdout:
                tail.append(line.rstrip("\n"))
                if echo is not None:
                    echo(line.rstrip("\n"))

    def poll(self, now: float) -> None:
        """Notice a death (and say why) or start the pending restart when it is due."""
        if self.restart_at is not None:
            if now >= self.restart_at:
                self.start()
            return
        if self.popen is None or (rc := self.popen.poll()) is None:
            return
        self._kill_group()  # whatever the dead child left in its group
        if self._reader:
            self._reader.join(1.0)  # the last lines, for the report below
        self._schedule_restart(now)
        msg = f"{self.label} {describe_exit(rc)}; restarting in {self.restart_delay:.1f} s"
        if _is_error(rc) and self.tail:
            lines = "\n".join(f"  {self.label} | {line}" for line in self.tail)
            log.error("%s; its last output:\n%s", msg, lines)
        else:
            log.error("%s", msg)

    @property
    def restart_delay(self) -> float:
        return max(0.0, (self.restart_at or 0.0) - time.monotonic())

    def _schedule_restart(self, now: float) -> None:
        if now - self.started_at >= STABLE_AFTER:
            self.backoff = INITIAL_BACKOFF  # it had been running fine: not a crash loop
        self.restart_at = now + self.backoff
        self.backoff = min(self.backoff * 2.0, MAX_BACKOFF)

    def terminate(self) -> None:
        """SIGTERM the child itself (it then stops its own loop and session)."""
        self.restart_at = None
        if self.running:
            assert self.popen is not None
            with contextlib.suppress(ProcessLookupError):
                self.popen.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        """SIGKILL the child's whole process group, and reap it."""
        self.restart_at = None
        self._kill_group()
        if self.popen is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.popen.wait(2.0)

    def _kill_group(self) -> None:
        if self.popen is not None:
            # The group id is the child's pid (start_new_session); it cannot be
            # reused while any member of the group lives.
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.popen.pid, signal.SIGKILL)


class Supervisor:
    """The children of every arm, grouped in layers (one per service, in start order)."""

    def __init__(self, layers: Sequence[Sequence[Child]]) -> None:
        self.layers = [list(layer) for layer in layers]
        self.stopping = False

    @property
    def children(self) -> list[Child]:
        return [c for layer in self.layers for c in layer]

    def start(self, first_layer: int = 0) -> None:
        """Start the children of every layer from ``first_layer`` on."""
        for layer in self.layers[first_layer:]:
            for child in layer:
                child.start()

    def poll(self) -> None:
        """Call about every 0.1 s: restarts what died, unless stopping."""
        if self.stopping:
            return
        now = time.monotonic()
        for child in self.children:
            child.poll(now)

    def stop(self, grace: float = STOP_GRACE, idle: Callable[[], None] | None = None,
             hurry: threading.Event | None = None) -> None:
        """Stop the layers in reverse start order: SIGTERM, up to ``grace`` s, then SIGKILL.

        ``idle`` runs while waiting (the launcher keeps printing the services'
        logs); ``hurry`` set (a second Ctrl-C) cuts the wait short.
        """
        self.stopping = True
        for layer in reversed(self.layers):
            running = [c for c in layer if c.running]
            for child in layer:
                child.terminate()  # also cancels a pending restart
            deadline = time.monotonic() + grace
            while (any(c.running for c in running) and time.monotonic() < deadline
                   and not (hurry and hurry.is_set())):
                if idle:
                    idle()
                time.sleep(0.05)
            for child in running:
                if child.running:
                    log.warning("%s still running%s; killing it", child.label,
                                " (second signal)" if hurry and hurry.is_set()
                                else f" {grace:.0f} s after SIGTERM")
                elif child.popen is not None:
                    log.info("%s stopped (%s)", child.label, describe_exit(child.popen.returncode))
                child.kill()

