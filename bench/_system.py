"""Bench helpers: the launcher's full system on a private loopback port."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import zenoh

from jara_arm.services.runtime.zenoh_args import zenoh_config


def end(proc: subprocess.Popen, sig: signal.Signals = signal.SIGTERM, grace: float = 20.0, group: bool = True) -> None:
    """``proc`` ended: ``sig``, then SIGKILL after ``grace`` [s]. Where it leads a process group (the launcher, the
    tools and Chromium run in sessions of their own), SIGKILL goes to the whole group, and ``sig`` too if ``group``
    (else only to ``proc``: the launcher stops its services itself)."""
    def signal_it(s: signal.Signals, whole: bool) -> None:
        with contextlib.suppress(ProcessLookupError):
            if whole and os.getpgid(proc.pid) == proc.pid:
                os.killpg(proc.pid, s)
            else:
                proc.send_signal(s)

    if proc.poll() is None:
        signal_it(sig, group)
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            signal_it(signal.SIGKILL, True)
            proc.wait()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def launched_system(robot: str = "iiwa", arm: str = "arm0", timeout: float = 60.0,
                    arms: list[tuple[str, str]] | None = None, extra: list[str] | None = None,
                    lines: list[str] | None = None, secure: str | None = None) -> Iterator[int]:
    """``jara-arm up`` on a free port; yields the port once the ready line is printed.

    ``arms``: several (arm, robot) instead of one; ``extra``: more launcher options;
    ``lines``: a list that receives the launcher's output (for a report); ``secure``: a cell
    directory (``jara-arm certs init``) to run it in, listening on TLS.
    """
    port = free_port()
    scheme = "tls" if secure else "tcp"
    extra = [*(extra or []), *(["--secure", secure] if secure else [])]
    arm_args = [a for arm_id, rob in (arms or [(arm, robot)]) for a in ("--arm", f"{arm_id}:{rob}")]
    proc = subprocess.Popen(
        [sys.executable, "-m", "jara_arm.launcher", "up", *arm_args,
         "--listen", f"{scheme}/127.0.0.1:{port}", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines = [] if lines is None else lines
    ready = threading.Event()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if "ready" in line:
                ready.set()

    threading.Thread(target=read, daemon=True).start()
    try:
        if not ready.wait(timeout):
            raise RuntimeError("the system did not get ready:\n" + "".join(lines))
        yield port
    finally:
        end(proc, signal.SIGINT, 15.0, group=False)


@contextlib.contextmanager
def client(port: int) -> Iterator[zenoh.Session]:
    with zenoh.open(zenoh_config("client", connect=[f"tcp/127.0.0.1:{port}"])) as session:
        yield session


def percentile(values, q: float) -> float:
    import numpy as np

    return float(np.percentile(np.asarray(values), q))


def wait(seconds: float) -> None:
    time.sleep(seconds)
