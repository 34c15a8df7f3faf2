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
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)


@contextlib.contextmanager
def client(port: int) -> Iterator[zenoh.Session]:
    with zenoh.open(zenoh_config("client", connect=[f"tcp/127.0.0.1:{port}"])) as session:
        yield session


def percentile(values, q: float) -> float:
    import numpy as np

    return float(np.percentile(np.asarray(values), q))


def wait(seconds: float) -> None:
    time.sleep(seconds)
