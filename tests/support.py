"""Test helpers: free loopback ports, service processes, a typed client over Zenoh, waits on events,
geometry. The live harness built on them (the system launched, the client-side arm) is ``harness.py``.

Every test talks to real processes over real Zenoh sessions on 127.0.0.1 with
multicast scouting off, on ports of its own, so that tests can run side by side.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from jara_arm.client import Arm
from jara_arm.client.arm import wait_alive as client_wait_alive
from jara_arm.launcher import cli
from jara_arm.launcher.completion import bash_script
from jara_arm.robots import RobotModel
from jara_arm.schema import codec
from jara_arm.schema import wire_types as w
from jara_arm.schema.codec import Encoding, Reply
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.operations import Interface
from jara_arm.schema.planner import MotionRequest, MotionSettings
from jara_arm.schema.types import CarPosWithElbow, CartesianSpeed, LimitValue
from jara_arm.services.planner.request import PlanRequest
from jara_arm.services.runtime.realtime import realtime_thread
from jara_arm.services.runtime.zenoh_args import zenoh_config


def pose(p: Any, R: np.ndarray | None = None) -> np.ndarray:
    """The 4x4 transform at position ``p`` [m] with rotation ``R`` (default: none)."""
    T = np.eye(4)
    T[:3, 3] = p
    if R is not None:
        T[:3, :3] = R
    return T


def rot_z(a: float) -> np.ndarray:
    """The rotation by ``a`` [rad] about z."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance [m] of points (N, 3) to the segment a-b."""
    d = b - a
    u = np.clip((p - a) @ d / (d @ d), 0.0, 1.0)
    return np.linalg.norm(p - (a + u[:, None] * d), axis=1)


def car(T: np.ndarray, elbow: float = 0.0) -> dict:
    """A ``CarPosWithElbow`` argument in wire form: pose ``T`` [m], ``elbow`` [rad]."""
    return w.CAR_POS_WITH_ELBOW.encode(CarPosWithElbow(T[:3].copy(), elbow, 0))


def bash_complete(words: list[str]) -> list[str]:
    """What bash offers for the last of ``words`` with jara-arm's completion script sourced."""
    script = bash_script(cli.command_parsers())
    line = " ".join(f"'{w}'" for w in words)
    run = subprocess.run(["bash", "-c", (f'{script}\nCOMP_WORDS=({line}); COMP_CWORD={len(words) - 1}; '
                                         '_jara_arm; printf "%s\\n" "${COMPREPLY[@]}"')],
                         capture_output=True, text=True, timeout=10, check=True)
    return [w for w in run.stdout.splitlines() if w]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


def client_config(port: int) -> zenoh.Config:
    return zenoh_config("client", connect=[endpoint(port)])


@contextlib.contextmanager
def client_session(port: int, timeout: float = 20.0) -> Iterator[zenoh.Session]:
    """A client session to ``port``, retried until the listener is up."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            session = zenoh.open(client_config(port))
            break
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)
    with session:
        yield session


class Proc:
    """A child process whose stderr is collected (for failure messages)."""

    def __init__(self, argv: Sequence[str], env: Mapping[str, str] | None = None) -> None:
        self.argv = list(argv)
        self.popen = subprocess.Popen(
            self.argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}, start_new_session=True)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            self.lines.append(line.rstrip("\n"))

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def wait_for_line(self, needle: str, timeout: float = 30.0, start: int = 0) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in self.lines[start:]:
                if needle in line:
                    return line
            if self.popen.poll() is not None and not self._reader.is_alive():
                break
            time.sleep(0.05)
        raise AssertionError(f"no line with {needle!r} within {timeout} s; output:\n{self.output}")

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 10.0) -> int:
        if self.popen.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.popen.pid, sig)
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.popen.pid, signal.SIGKILL)
                self.popen.wait(5)
        self._reader.join(2)
        return self.popen.returncode


def service_argv(service: Service, port: int, arm: str = "arm0", robot: str = "iiwa",
                 *extra: str, client: bool = False) -> list[str]:
    """A service on loopback, multicast off: a peer listening on ``port``, or (``client``) a client of the
    router on ``port`` (the launcher's topology)."""
    module = service.value.replace("-", "_")
    where = ["--mode", "client", "--connect", endpoint(port)] if client else ["--listen", endpoint(port)]
    return [sys.executable, "-m", f"jara_arm.services.{module}", "--arm", arm, "--robot", robot, *where, *extra]


def wait_alive(session: zenoh.Session, arm: str, services: Sequence[Service],
               timeout: float = 30.0) -> None:
    """The client's ``wait_alive`` for ``arm`` (``NoAnswer`` naming the services not up)."""
    client_wait_alive(session, ArmKeys(arm), services, timeout)


class Client(Arm):
    """The public client (``jara_arm.client.Arm``) with the replies as they came, for tests that check a
    refusal's code and comment, and raw queries (arbitrary payloads, for bad-input tests)."""

    def common(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.call(Interface.COMMON, name, args)

    def middle(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.call(Interface.MIDDLE, name, args)

    def ext(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.call(Interface.EXT, name, args)

    def servo(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.call(Interface.COMMON, name, args, servo=True)

    def raw(self, key: str, payload: bytes, *, json: bool = False, timeout: float = 10.0) -> Any:
        """A query with an arbitrary payload (labelled JSON if ``json``); the reply map as decoded data,
        read by the reply's encoding label, which must be JSON for a request that is JSON."""
        enc = zenoh.Encoding.APPLICATION_JSON if json else None
        oks = [r.ok for r in self.session.get(key, payload=payload, encoding=enc, timeout=timeout)
               if r.ok is not None]
        assert len(oks) == 1, f"expected exactly one reply on {key}, got {len(oks)}"
        encoding = Encoding.of(oks[0].encoding)
        assert encoding is Encoding.of_request(payload, enc), f"{key} answered {encoding.name} to {payload!r}"
        return codec.loads(oks[0].payload.to_bytes(), encoding)


def wait_until(predicate, timeout: float = 10.0, interval: float = 0.02, what: str = "condition",
               explain=None):
    """Poll ``predicate`` until it returns a truthy value, which is returned.

    On timeout ``explain()`` (if given) adds what the system looked like.
    """
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            extra = f"\n{explain()}" if explain is not None else ""
            raise AssertionError(f"timed out after {timeout} s waiting for {what}{extra}")
        time.sleep(interval)


LAUNCHER = [sys.executable, "-m", "jara_arm.launcher"]


@contextlib.contextmanager
def busy_loops() -> Iterator[None]:
    """A normal-priority busy loop per core while inside: the vision, UI and logging a cell's PC also runs."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(os.cpu_count() or 1)]
    try:
        yield
    finally:
        for h in hogs:
            h.kill()
            h.wait()


def proc_alive(pid: int) -> bool:
    """Running (not gone, not a zombie)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def processes_with(needle: str) -> list[int]:
    """Live processes whose command line contains ``needle`` (e.g. the test's own port)."""
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit() and int(d.name) != os.getpid():
            with contextlib.suppress(OSError):
                if needle in (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace"):
                    if proc_alive(int(d.name)):
                        pids.append(int(d.name))
    return pids


def wait_recording(recorder: Proc, timeout: float = 30.0) -> None:
    """Until ``jara-arm record`` shows messages written: its subscription reached the services (the servo
    publishes Servo/posFeedback only while subscribed), so their call-trace publishers match it too."""
    written = re.compile(r", [1-9][0-9]* messages, ")
    wait_until(lambda: any(written.search(line) for line in recorder.lines), timeout,
               what=f"jara-arm record writing messages; its output: {recorder.lines[-5:]}")


def motion_settings(model: RobotModel, **changes: Any) -> MotionSettings:
    """The settings a motion is planned with, as the command service's defaults would have them (speed
    ratios 50 % joint, 100 % Cartesian; no offsets; wide Cartesian limits), with ``changes``."""
    s = MotionSettings(
        spdRatioJoint=50, spdRatioCartesian=100, maxSpeedJoint=model.rated_speed,
        maxSpeedCartesian=CartesianSpeed(0.25, 1.0), accelTimeJoint=model.min_accel_time,
        accelTimeCartesian=model.min_accel_time_cartesian, softLimitJoint=model.hard_limits,
        softLimitCartesian=(LimitValue(2.0, -2.0),) * 3, baseOffset=np.eye(4)[:3],
        controlPointOffset=np.eye(4)[:3], home=model.ready_pose)
    return dataclasses.replace(s, **changes)


def plan_request(op: str, args: Mapping[str, Any], settings: MotionSettings) -> PlanRequest:
    """The motion ``op`` with ``args`` in wire form (as ``Planner/plan`` carries them), decoded as the planner's
    plan worker decodes it for ``MotionPlanner`` and the planning process; raises PlanRefused as it does."""
    return PlanRequest.decode(MotionRequest(op, dict(args), settings))


#: SCHED_FIFO priority of the tests' low-level streams and timed waits: below the servo's clock (40) and the cell bus (35).
STREAM_PRIORITY = 30


@contextlib.contextmanager
def realtime_process_section(priority: int) -> Iterator[None]:
    """Every thread of this process under the normal scheduler at SCHED_FIFO ``priority`` meanwhile, where
    permitted; Zenoh's own threads included, which carry a stream out (a low-level client's stack must be
    real-time as a whole: its Python thread alone is not enough)."""
    raised = []
    for tid in (int(t) for t in os.listdir("/proc/self/task")):
        try:
            if os.sched_getscheduler(tid) == os.SCHED_OTHER:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
                raised.append(tid)
        except OSError:  # no permission, or the thread ended meanwhile
            continue
    try:
        yield
    finally:
        for tid in raised:
            with contextlib.suppress(OSError):
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))


@contextlib.contextmanager
def realtime_section(priority: int) -> Iterator[None]:
    """The calling thread at SCHED_FIFO ``priority`` meanwhile, where permitted (as it was, otherwise)."""
    raised = realtime_thread(priority, "a test's timed section")
    try:
        yield
    finally:
        if raised:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
