"""Soak: N arms moving continuously for M minutes; every alarm in a soak is a false alarm.

    python bench/soak.py [--arms N] [--minutes M] [--hog] [--slow-client] [--frozen-client] [--reader]
                         [--view] [--recorder] [--motion ptp|lin] [--robot iiwa] [--timing same-host]

Starts ``jara-arm up`` with N arms, switches every servo on and drives each arm
back and forth between two joint poses (``movePTPJointAbs`` at 50 %, the next
motion queued while the current one runs, so the stream never pauses). With
``--hog``, one normal-priority busy loop per core runs for the whole soak (the
vision, UI and logging a real cell's PC also runs). ``--slow-client`` connects a client that
subscribes to ``JARA_ARM/**`` and spends 20 ms in each sample's callback; ``--frozen-client`` one
that subscribes to every arm's ``Servo/posFeedback`` and is stopped (SIGSTOP) for 10 s, let go for
5 s, again and again (``bench/bad_client.py``). ``--reader`` connects a client that takes every
arm's ``Servo/posFeedback`` and keeps up: what the bad clients ask for, without their badness.
``--view`` runs ``jara-arm view`` with the page open in headless Chromium (software WebGL, as on a PC
without a GPU); ``--recorder`` runs ``jara-arm record`` of every arm into a temporary MCAP file: the
tools a user watches a cell with, beside its motions.

``--motion lin``: each arm runs LINs instead (``moveLinearCartesianRel``, 0.1 m along x and back, each
from rest after the last ended: every one an early start), and the flange's speed along the arm's 1 kHz
``Servo/posFeedback``, by the servo's time stamps, is checked for dips (``count_dips``: each LIN one move,
none whose speed fell below half the speed reached and rose again, ``bench/motion.py``'s
``speed_dipped``). A LIN that did not arrive (``Motion.wait`` raised) counts as refused.

Reports per arm: servo cycles, cycles late by more than one period, overruns,
underruns (from the servo's own ``Servo/health``), motions completed, calls
refused, every alarm raised and every stall logged; then CPU per process over
the soak. Exits 1 if any alarm was raised or any call was refused.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import dataclasses
import json
import multiprocessing
import os
import re
import signal
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zenoh

sys.path.insert(0, str(Path(__file__).parent))
from _system import client, end, free_port, launched_system  # noqa: E402
import cpu  # noqa: E402
from motion import speed_dipped  # noqa: E402
from starts import STUTTER  # noqa: E402

from jara_arm.client import Arm, ArmError, NoAnswer, rel  # noqa: E402
from jara_arm.kinematics import Kinematics  # noqa: E402
from jara_arm.launcher.tools.watch import format_log  # noqa: E402
from jara_arm.robots import robot  # noqa: E402
from jara_arm.schema import codec, messages  # noqa: E402
from jara_arm.schema.codes import ReturnCode, StateBit  # noqa: E402
from jara_arm.schema.keys import ANY_ARM, ArmKeys, any_arm_alarm, any_arm_log, arm_of  # noqa: E402
from jara_arm.schema.operations import OP, Interface  # noqa: E402
from jara_arm.schema.wire_types import TIMED_JOINT_POS  # noqa: E402
from jara_arm.services.runtime.wire import decode_sample  # noqa: E402

SPEED = 50  # [%] of the rated joint speeds
SWING = 0.4  # [rad or m] J1 and J2 swing between the two poses (scaled for prismatic axes)
LIN_STEP = 0.1  # [m] --motion lin: each LIN's length, along x and back
RECORDER_EXIT = 600.0  # [s] for --recorder to write what it holds and exit, after the soak
MOVING = 0.05  # [-] of the top speed over the soak (every LIN the same length and speed): above it, an arm moves


@dataclasses.dataclass
class ArmTally:
    cycles: int = 0
    late: int = 0
    overruns: int = 0
    underruns: int = 0
    lateness_max: float = 0.0  # [s]
    windows: list[tuple[float, int, float]] = dataclasses.field(default_factory=list)  # (t [s], late, max [s])

    def add(self, h: messages.LoopHealth, t: float) -> None:
        """One ``Servo/health`` window, received ``t`` [s] after the start."""
        self.cycles += h.cycles
        self.late += h.lateCycles
        self.overruns += h.overruns
        self.underruns += h.underruns
        self.lateness_max = max(self.lateness_max, h.latenessMax)
        self.windows.append((t, h.lateCycles, h.latenessMax))
    motions: int = 0
    refused: list[str] = dataclasses.field(default_factory=list)
    feedback: list[tuple[bytes, zenoh.Encoding]] = dataclasses.field(default_factory=list)  # --motion lin: samples
    dips: int = 0
    dipped: list[str] = dataclasses.field(default_factory=list)  # --motion lin: each dipped LIN's speed


#: A watcher's stall line: "the <service> service was silent for <N> ms and is back".
_SILENCE = re.compile(r"was silent for (\d+) ms")


def steal_ticks() -> int:
    """The machine's CPU time taken by its hypervisor so far [USER_HZ ticks] (``/proc/stat``)."""
    with open("/proc/stat") as f:
        return int(f.readline().split()[8])


def record_steal(samples: list[tuple[float, int]], t0: float, stop: threading.Event) -> None:
    """Every second, (s since ``t0``, steal ticks): a stalled VM stalls every loop in it."""
    last = steal_ticks()
    while not stop.wait(1.0):
        now = steal_ticks()
        samples.append((time.monotonic() - t0, now - last))
        last = now


def hog() -> None:  # pragma: no cover - runs in its own process
    while True:
        pass


BAD_CLIENT = Path(__file__).parent / "bad_client.py"
FREEZE = (10.0, 5.0)  #: the frozen client's cycle: stopped, then running [s]


def start_bad_client(kind: str, port: int, *options: str) -> subprocess.Popen:
    """``bench/bad_client.py KIND [OPTIONS]`` connected to the launcher's client endpoint, once ready."""
    proc = subprocess.Popen([sys.executable, str(BAD_CLIENT), kind, "--connect", f"tcp/127.0.0.1:{port}",
                             *options], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    if "ready" not in proc.stdout.readline():
        raise RuntimeError(f"bad client {kind} did not start")
    # Its output is not needed any more, but a full pipe would stop it: read and forgotten.
    threading.Thread(target=collections.deque, args=(proc.stdout, 0), daemon=True).start()
    return proc


def freeze_cycles(proc: subprocess.Popen, stop: threading.Event) -> None:
    """Stop ``proc`` for FREEZE[0] s, let it run FREEZE[1] s, until ``stop``; leaves it running."""
    while not stop.is_set():
        proc.send_signal(signal.SIGSTOP)
        stop.wait(FREEZE[0])
        proc.send_signal(signal.SIGCONT)
        stop.wait(FREEZE[1])


def start_tool(argv: list[str], first: str, timeout: float = 60.0) -> tuple[subprocess.Popen, str]:
    """``jara-arm <argv>`` started, and its first output line that holds ``first`` (its other lines kept)."""
    proc = subprocess.Popen([sys.executable, "-m", "jara_arm.launcher", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    deadline = time.monotonic() + timeout
    said: list[str] = []

    def read() -> None:
        assert proc.stdout is not None
        for text in proc.stdout:
            if first in text and not said:
                said.append(text.strip())
        # then it reads on and forgets: a full pipe would stop the tool

    threading.Thread(target=read, daemon=True).start()
    while not said and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    if not said:
        end(proc)
        raise RuntimeError(f"jara-arm {argv[0]} did not print {first!r} within {timeout:.0f} s (exit {proc.poll()})")
    return proc, said[0]


def start_view(port: int, workdir: Path) -> list[subprocess.Popen]:
    """``jara-arm view`` of the system and its page open in headless Chromium (which must be installed)."""
    browser = next((p for n in ("chromium", "chromium-browser", "google-chrome") if (p := shutil.which(n))), None)
    if browser is None:
        raise SystemExit("--view: no Chromium on this machine (make browser installs it)")
    view, line = start_tool(["view", "--connect", f"tcp/127.0.0.1:{port}", "--port", str(free_port())],
                            "jara-arm view: ")
    url = line.split()[2]
    try:  # a session of its own: its renderer and GPU processes end with it (os.killpg)
        page = subprocess.Popen([browser, "--headless=new", "--no-sandbox", "--use-angle=swiftshader",
                                 "--enable-unsafe-swiftshader", "--no-first-run", f"--user-data-dir={workdir}/chromium",
                                 url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    except OSError:
        end(view)
        raise
    return [view, page]


def poses(model_name: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Two joint poses around the ready pose, inside the limits."""
    m = robot(model_name)
    a, b = list(m.ready_pose), list(m.ready_pose)
    for i in range(min(2, m.axis_num)):
        swing = SWING if not m.prismatic[i] else 0.1
        lim = m.hard_limits[i]
        centre = min(max(m.ready_pose[i], lim.lower + swing), lim.upper - swing)
        a[i], b[i] = centre - swing / 2, centre + swing / 2
    return tuple(a), tuple(b)


def drive_lins(arm: Arm, until: float, tally: ArmTally, stop: threading.Event) -> None:
    """LINs of ``LIN_STEP`` along x and back until ``until`` (monotonic), each from rest, each waited for;
    ``tally.motions`` counts those accepted, ``tally.refused`` those refused or that did not arrive."""
    sign = 1.0
    try:
        arm.servoON()
        arm.setSpeedCartesian(SPEED)
        while time.monotonic() < until and not stop.is_set():
            try:
                motion = arm.moveLinearCartesianRel(rel(dx=sign * LIN_STEP), wait=False)
            except ArmError as exc:
                tally.refused.append(f"{time.strftime('%H:%M:%S')} moveLinearCartesianRel: {exc}")
                stop.wait(1.0)
                continue
            tally.motions += 1  # accepted: it moves, whether or not it arrives
            sign = -sign
            try:
                motion.wait(30.0)
            except ArmError as exc:  # did not arrive: an alarm should say why (the soak counts both)
                tally.refused.append(f"{time.strftime('%H:%M:%S')} moveLinearCartesianRel did not arrive: {exc}")
                arm.wait_idle(60.0)
    except ArmError as exc:
        tally.refused.append(f"{time.strftime('%H:%M:%S')} {exc}")


def count_dips(model_name: str, tally: ArmTally) -> int:
    """How many LINs show a dip in the flange's speed, from the feedback's joints and the servo's times.

    The stream is cut into moves where the speed is above ``MOVING`` of the top: each LIN from rest is one
    move. A move whose speed dips counts, and so does every move beyond the LINs driven (a LIN that stopped
    and started again is two). The client's receive times are not used: a loaded reader gets the feedback
    late, the servo's time stamps are when it was so. Each dipped move's profile goes to ``tally.dipped``."""
    fk = Kinematics(robot(model_name))
    msgs = sorted((codec.decode_message(TIMED_JOINT_POS, payload, codec.Encoding.of(encoding))
                   for payload, encoding in tally.feedback),
                  key=lambda m: (m.tm.sec, m.tm.nsec))
    tm = np.array([m.tm.sec + 1e-9 * m.tm.nsec for m in msgs])
    keep = np.append(True, np.diff(tm) > 0)  # one sample per servo time
    tm = tm[keep]
    if len(tm) < 3:
        return 0
    p = np.array([fk.fk(np.asarray(m.pos, dtype=float)).translation for m, k in zip(msgs, keep) if k])
    v = np.linalg.norm(np.diff(p, axis=0), axis=1) / np.diff(tm)  # a missed sample: a longer step, same speed
    moving = np.concatenate(([False], v > MOVING * v.max(), [False])).astype(int)
    starts, ends = np.flatnonzero(np.diff(moving) == 1), np.flatnonzero(np.diff(moving) == -1)
    dips = max(0, len(starts) - tally.motions)
    for a, b in zip(starts, ends):
        if speed_dipped(v[a:b]):
            dips += 1
            top = a + int(np.argmax(v[a:b]))
            tally.dipped.append(f"move at servo time {tm[a]:.3f} s: {b - a} moving samples, top {1e3 * v[top]:.1f} "
                                f"mm/s at {top - a}; every 25th [mm/s]: "
                                + " ".join(f"{1e3 * x:.0f}" for x in v[a:b:25]))
    if len(starts) > tally.motions:
        tally.dipped.append(f"{len(starts)} moves in the feedback for {tally.motions} LINs")
    return dips


def drive(arm: Arm, model_name: str, until: float, tally: ArmTally, stop: threading.Event) -> None:
    """Keep ``arm`` moving until ``until`` (monotonic): the next motion is queued while one runs.

    The queue length comes from the arm's ``state`` publication (sent on every change).
    """
    targets = poses(model_name)
    states = arm.session.declare_subscriber(arm.keys.state, zenoh.handlers.RingChannel(1))
    queue_length = 0

    def refused(what: str) -> None:
        tally.refused.append(f"{time.strftime('%H:%M:%S')} {what}")

    try:
        for name, reply in (("servoON", arm.call(Interface.COMMON, OP.servoON)),
                            ("setSpeedJoint", arm.call(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": SPEED}))):
            if reply.id != ReturnCode.OK:
                refused(f"{name}: {reply.id} {reply.comment}")
        sent = 0
        while time.monotonic() < until and not stop.is_set():
            if (s := states.try_recv()) is not None:
                msg = codec.loads(s.payload.to_bytes(), codec.Encoding.of(s.encoding))
                queue_length = int(msg.get("queueLength", 0))
                if msg["state"] & StateBit.ALARM or not msg["state"] & StateBit.SERVO_ON:
                    refused(f"state 0x{msg['state']:02x}: alarm or servo off")
                    stop.wait(1.0)
                    continue
            if queue_length < 2:
                reply = arm.call(Interface.MIDDLE, OP.movePTPJointAbs, {"jointPoints": targets[sent % 2]})
                if reply.id != ReturnCode.OK:
                    refused(f"movePTPJointAbs: {reply.id} {reply.comment}")
                    stop.wait(1.0)
                    continue
                sent += 1
                queue_length += 1
            stop.wait(0.05)
        arm.wait_idle(60.0)
        tally.motions = sent
    except NoAnswer as exc:
        refused(str(exc))
    finally:
        states.undeclare()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", type=int, default=1)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--hog", action="store_true", help="a normal-priority busy loop on every core")
    ap.add_argument("--slow-client", action="store_true", help="a client at 20 ms per sample of JARA_ARM/**")
    ap.add_argument("--reader", action="store_true",
                    help="a client that takes every arm's 1 kHz Servo/posFeedback and keeps up")
    ap.add_argument("--frozen-client", action="store_true",
                    help="a client of Servo/posFeedback stopped 10 s of every 15")
    ap.add_argument("--view", action="store_true", help="jara-arm view with its page open in headless Chromium")
    ap.add_argument("--recorder", action="store_true", help="jara-arm record of every arm into a temporary file")
    ap.add_argument("--motion", choices=("ptp", "lin"), default="ptp",
                    help="ptp: PTPs queued back to back (default); lin: LINs from rest, checked for speed dips")
    ap.add_argument("--robot", default="iiwa")
    ap.add_argument("--timing", default="same-host")
    ap.add_argument("--json", metavar="FILE", help="also write the figures to FILE")
    args = ap.parse_args()
    arm_ids = [f"a{i}" for i in range(args.arms)]
    tallies = {a: ArmTally() for a in arm_ids}
    alarms: list[str] = []
    stalls: collections.Counter[str] = collections.Counter()  # silences logged by the arm's watchers
    longest: collections.Counter[str] = collections.Counter()  # [ms] the longest of them
    longest_line: dict[str, str] = {}  # its log line
    warnings: list[str] = []
    stutters: list[str] = []  # bench/starts.py's STUTTER lines, at any level
    hogs: list[multiprocessing.Process] = []
    ctx = multiprocessing.get_context("spawn")
    lines: list[str] = []
    tools: list[subprocess.Popen] = []
    recorder: subprocess.Popen | None = None
    recorded = ""
    workdir = Path(tempfile.mkdtemp(prefix="soak-"))
    t_start = time.monotonic()
    with launched_system(arms=[(a, args.robot) for a in arm_ids], extra=["--timing", args.timing],
                         lines=lines, timeout=120.0) as port, client(port) as session:
        ready_after = time.monotonic() - t_start
        roots = [p for p in cpu.launchers() if f":{port}" in " ".join(cpu._cmdline(p))]

        def on_alarm(s: zenoh.Sample) -> None:
            ev = decode_sample(messages.ALARM_EVENT, s)
            if ev.event == "raised":
                alarms.append(f"{time.strftime('%H:%M:%S')} {arm_of(str(s.key_expr))} "
                              f"0x{ev.alarm.code:02x} {ev.alarm.type.value}: {ev.alarm.description}")

        def on_health(s: zenoh.Sample) -> None:
            h = decode_sample(messages.LOOP_HEALTH, s)
            tallies[arm_of(str(s.key_expr))].add(h, time.monotonic() - t_start)

        def on_log(s: zenoh.Sample) -> None:
            line, level = format_log(str(s.key_expr), s.payload.to_bytes(), codec.Encoding.of(s.encoding))
            if any(what in line for what in STUTTER):  # at any level: a clock that waited says so at INFO
                stutters.append(line)
            if level >= 30:
                warnings.append(line)
                if (m := _SILENCE.search(line)) is not None:
                    arm = arm_of(str(s.key_expr))
                    stalls[arm] += 1
                    if int(m.group(1)) > longest[arm]:
                        longest[arm] = int(m.group(1))
                        longest_line[arm] = line

        # Callbacks only append to lists: no work, no blocking.
        subs = [session.declare_subscriber(any_arm_alarm(), on_alarm),
                session.declare_subscriber(any_arm_log(), on_log)]
        subs += [session.declare_subscriber(ArmKeys(a).servo_health, on_health) for a in arm_ids]
        if args.motion == "lin":
            def on_feedback(tally: ArmTally) -> Callable[[zenoh.Sample], None]:
                return lambda s: tally.feedback.append((s.payload.to_bytes(), s.encoding))

            subs += [session.declare_subscriber(ArmKeys(a).pos_feedback, on_feedback(tallies[a])) for a in arm_ids]
        bad: list[subprocess.Popen] = []
        stop = threading.Event()
        try:
            if args.slow_client:
                bad.append(start_bad_client("slow", port))
            if args.reader:  # the bad clients' demand without their badness: a reader that keeps up
                bad.append(start_bad_client("slow", port, "--key", ArmKeys(ANY_ARM).pos_feedback, "--delay-ms", "0"))
            freezer = None
            if args.frozen_client:
                bad.append(start_bad_client("frozen", port))
                freezer = threading.Thread(target=freeze_cycles, args=(bad[-1], stop), daemon=True)
                freezer.start()
            if args.view:
                tools += start_view(port, workdir)
            if args.recorder:
                with (workdir / "record.log").open("w") as said_file:  # the child keeps its own copy
                    recorder = subprocess.Popen([sys.executable, "-m", "jara_arm.launcher", "record", "-o",
                                                 str(workdir / "soak.mcap"), "--connect", f"tcp/127.0.0.1:{port}"],
                                                stdout=subprocess.DEVNULL, stderr=said_file, start_new_session=True)
            if args.hog:
                hogs = [ctx.Process(target=hog, daemon=True) for _ in range(os.cpu_count() or 1)]
                for h in hogs:
                    h.start()
            until = time.monotonic() + args.minutes * 60.0
            cpu_before = cpu.snapshot(roots)
            t0 = time.monotonic()
            steal: list[tuple[float, int]] = []
            steal_stop = threading.Event()
            steal_thread = threading.Thread(target=record_steal, args=(steal, t_start, steal_stop), daemon=True)
            steal_thread.start()
            drivers = [threading.Thread(target=drive, args=(Arm(session, a), args.robot, until, tallies[a], stop))
                       if args.motion == "ptp" else
                       threading.Thread(target=drive_lins, args=(Arm(session, a), until, tallies[a], stop))
                       for a in arm_ids]
            for d in drivers:
                d.start()
            for d in drivers:
                d.join()
            stop.set()
            if freezer is not None:
                freezer.join()
            cpu_after = cpu.snapshot(roots)
            wall = time.monotonic() - t0
            steal_stop.set()
            steal_thread.join()
            for sub in subs:  # the soak's figures end here, not after the recorder's exit
                sub.undeclare()
            if recorder is not None:  # behind (it runs at nice +10), it writes what it holds before it exits
                told = time.monotonic()
                recorder.send_signal(signal.SIGINT)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    recorder.wait(RECORDER_EXIT)
                said = (workdir / "record.log").read_text().replace("\r", "\n").strip().splitlines() or ["(no output)"]
                ended = (f"exit {recorder.returncode} {time.monotonic() - told:.1f} s after SIGINT"
                         if recorder.returncode is not None else f"still running {RECORDER_EXIT:.0f} s after SIGINT")
                recorded = f"{ended} (busy loops still running: {'yes' if hogs else 'no'}): {said[-1].strip()}"
        finally:  # nothing of the soak's outlives it, whatever failed
            stop.set()
            for proc in [*bad, *tools, *([recorder] if recorder is not None else [])]:
                end(proc)
            for h in hogs:
                h.terminate()
            shutil.rmtree(workdir, ignore_errors=True)
    for a, t in tallies.items():
        t.dips = count_dips(args.robot, t) if args.motion == "lin" else 0
        t.feedback = []
    shares: dict[str, float] = {}
    for pid, s in cpu_after.items():
        before = cpu_before[pid].ticks if pid in cpu_before else s.ticks
        shares[s.name] = shares.get(s.name, 0.0) + (s.ticks - before) / cpu._TICK / wall
    print(f"soak: {args.arms} arm(s) of {args.robot}, {wall / 60:.1f} min, hog {'on' if args.hog else 'off'}, "
          f"timing {args.timing}, slow client {'on' if args.slow_client else 'off'}, frozen client "
          f"{'on' if args.frozen_client else 'off'}, reader {'on' if args.reader else 'off'}, view "
          f"{'on' if args.view else 'off'}, recorder {'on' if args.recorder else 'off'}, motions {args.motion}; "
          f"ready after {ready_after:.1f} s")
    print(f"{'arm':<5} {'cycles':>8} {'late>1T':>8} {'late %':>8} {'max ms':>7} {'overrun':>8} "
          f"{'underrun':>8} {'motions':>8} {'refused':>8} {'stalls':>7} {'longest':>8}")
    for a, t in tallies.items():
        pct = 100.0 * t.late / max(1, t.cycles)
        print(f"{a:<5} {t.cycles:>8} {t.late:>8} {pct:>8.3f} {t.lateness_max * 1e3:>7.2f} {t.overruns:>8} "
              f"{t.underruns:>8} {t.motions:>8} {len(t.refused):>8} {stalls[a]:>7} {longest[a]:>6} ms")
    stolen = dict((round(t), ticks) for t, ticks in steal)
    print("worst one-second windows (s after start: late cycles, max lateness, VM steal in that second):")
    for a, t in tallies.items():
        worst = sorted(t.windows, key=lambda w: -w[1])[:5]
        print(f"  {a}: " + "; ".join(f"{w[0]:.0f} s: {w[1]}, {w[2] * 1e3:.1f} ms, "
                                    f"{stolen.get(round(w[0]), 0) * 1000 // cpu._TICK} ms" for w in worst))
    total_steal = sum(ticks for _, ticks in steal) / cpu._TICK
    print(f"VM steal (CPU time the hypervisor gave elsewhere): {total_steal:.1f} s over the soak, "
          f"{100 * total_steal / (wall * (os.cpu_count() or 1)):.2f} % of the CPUs")
    if args.motion == "lin":
        print("LINs with a speed dip: " + ", ".join(f"{a} {t.dips} of {t.motions}" for a, t in tallies.items()))
        for a, t in tallies.items():
            for line in t.dipped[:5]:
                print(f"  {a} {line}")
    print(cpu.table(shares))
    if args.recorder:
        print(f"recorder: {recorded}")
    print(f"alarms raised: {len(alarms)}")
    for line in alarms:
        print("  " + line)
    for a, t in tallies.items():
        for line in t.refused[:10]:
            print(f"  refused ({a}): {line}")
    for a in sorted(longest_line):
        print(f"  longest stall ({a}): {longest_line[a]}")
    print(f"stutters logged (a head held at its last sample, a stream run dry, a clock that waited): {len(stutters)}")
    for line in stutters[:10]:
        print("  " + line)
    print(f"warnings logged: {len(warnings)}")
    for line in warnings[:30]:
        print("  " + line)
    if args.json:
        Path(args.json).write_text(json.dumps({
            "arms": args.arms, "minutes": wall / 60, "hog": args.hog, "slow_client": args.slow_client,
            "frozen_client": args.frozen_client, "reader": args.reader,
            "view": args.view, "recorder": recorded if args.recorder else None, "timing": args.timing,
            "ready_after_s": ready_after, "alarms": alarms, "warnings": warnings, "stutters": stutters,
            "per_arm": {a: dataclasses.asdict(t) | {"stalls": stalls[a], "longest_stall_ms": longest[a]}
                        for a, t in tallies.items()},
            "cpu": shares, "steal_s": total_steal}, indent=1))
    failed = bool(alarms) or any(t.refused or t.dips for t in tallies.values())
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
