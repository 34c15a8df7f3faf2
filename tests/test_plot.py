"""``jara-arm plot`` (issue 13, part 2): the traces, the figures, the command.

The tests without ``live`` in their name need no system (``pytest -k 'not live'``):
the differencing on known trajectories, gaps, the window, the limit lines, the
PNG's pixel size, a recording read through the reader's interface (a stand-in
for ``launcher/record/recording.py``), and bad input refused (exit 2, nothing written,
no session opened). The ``live`` ones run ``jara-arm plot`` as a process against
``jara-arm up`` (the ``live``/``arm`` fixtures of conftest.py) during a PTP, and
from a recording of ``jara-arm record``.
"""

from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import matplotlib.image
import numpy as np
import pytest
import zenoh
from matplotlib.figure import Figure

from jara_arm.launcher import cli
from jara_arm.launcher.record.plot import Feedback, PlotSettings, feedback_of, render
from jara_arm.launcher.record.plot_figures import ACCEL, HARD, SOFT, SPEED, Size, SizeError, draw_joints, limit_lines
from jara_arm.launcher.record.recording import Recorded, RecordingWriter
from jara_arm.launcher.record.traces import JointLimits, TraceError, differences, traces
from jara_arm.robots import robot
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.operations import OP, Interface
from jara_arm.schema.types import LimitValue

from .harness import LiveArm
from .support import Proc, wait_recording

LAUNCHER = [sys.executable, "-m", "jara_arm.launcher"]
CYCLE = 1e-3  # [s]
IIWA = robot("iiwa")


def cubic(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two axes of known cubics: positions, velocities and accelerations at ``t`` [s]."""
    c = np.array([[2.0, -1.0, 0.5], [-3.0, 0.7, 1.2]])  # per axis: t³, t², t coefficients
    q = np.stack([a * t**3 + b * t**2 + d * t for a, b, d in c], axis=1)
    v = np.stack([3 * a * t**2 + 2 * b * t + d for a, b, d in c], axis=1)
    acc = np.stack([6 * a * t + 2 * b for a, b, _ in c], axis=1)
    return q, v, acc


def jittered_times(n: int, seed: int = 1) -> np.ndarray:
    """``n`` sample times one cycle apart, each late or early by up to 10 % of a cycle (as a real loop)."""
    return np.arange(n) * CYCLE + np.random.default_rng(seed).uniform(-0.1, 0.1, n) * CYCLE


# -- the differences ---------------------------------------------------------------------------------

def test_a_cubic_gives_its_velocity_and_acceleration() -> None:
    t = jittered_times(2000)
    q, _, _ = cubic(t)
    one, vel, acc = differences(t, q, CYCLE)
    assert one.all()
    mid = 0.5 * (t[:-1] + t[1:])
    assert np.abs(vel - cubic(mid)[1]).max() < 1e-5  # [rad/s] the slope over the real spacing, not the nominal
    got = traces(t, q, CYCLE)
    # [rad/s²] at the midpoint of the two midpoints; uneven spacings h1, h2 leave (h1² - h2²) q''' / 24h of the
    # velocities' own error, some 1e-4 here
    assert np.abs(got.acc - cubic(got.t_acc)[2]).max() < 1e-3
    assert np.allclose(got.vel, vel, atol=1e-9) and np.allclose(got.acc, acc, atol=1e-6)  # the same, from t - t[0]
    nominal = np.diff(q, axis=0) / CYCLE
    assert np.abs(nominal - cubic(mid)[1]).max() > 1e-3  # the nominal cycle would have been wrong


def test_a_gap_gives_nan_not_a_spike() -> None:
    t = np.arange(1000) * CYCLE
    q, v, a = cubic(t)
    keep = np.ones(len(t), dtype=bool)
    keep[400:403] = False  # three samples lost in transit
    got = traces(t[keep], q[keep], CYCLE)
    assert got.gaps == 1
    gap = np.flatnonzero(np.isnan(got.vel[:, 0]))
    assert gap.tolist() == [399]  # the one difference across the gap
    assert np.isnan(got.acc[398:400]).all() and np.count_nonzero(np.isnan(got.acc[:, 0])) == 2
    assert np.nanmax(np.abs(got.vel)) <= np.abs(v).max() + 1e-3  # no spike where the samples were lost
    assert np.nanmax(np.abs(got.acc)) <= np.abs(a).max() + 1e-3


def test_repeated_and_out_of_order_samples() -> None:
    t = np.arange(50) * CYCLE
    q, _, _ = cubic(t)
    shuffled = np.random.default_rng(2).permutation(50)
    got = traces(np.append(t[shuffled], t[10]), np.vstack([q[shuffled], q[10]]), CYCLE)
    assert np.array_equal(got.t, np.sort(np.append(t, t[10])))  # in time order
    assert got.gaps == 1 and np.count_nonzero(np.isnan(got.vel[:, 0])) == 1  # the zero spacing is a gap
    assert np.isfinite(got.vel).sum() == 2 * 49


def test_the_window_is_after_the_first_sample() -> None:
    t = 1.7e9 + np.arange(3000) * CYCLE  # Unix times, as the feedback's tm
    q, _, _ = cubic(t - t[0])
    got = traces(t, q, CYCLE, start=1.0, end=1.5)
    assert got.t[0] == pytest.approx(1.0) and got.t[-1] == pytest.approx(1.5) and len(got.t) == 501
    with pytest.raises(TraceError, match="0 sample.* in the window 4 .. 5 s of the 2.999 s"):
        traces(t, q, CYCLE, start=4.0, end=5.0)


# -- the figures ------------------------------------------------------------------------------------------

def test_the_limit_lines_are_drawn() -> None:
    t = np.arange(300) * CYCLE
    q = np.tile(IIWA.ready_pose, (300, 1)) + 0.1 * t[:, None]
    soft = tuple(LimitValue(h.upper - 0.1, h.lower + 0.1) for h in IIWA.hard_limits[:6]) + (IIWA.hard_limits[6],)
    fig = Figure(figsize=Size(1600, 1200).inches)
    draw_joints(fig, traces(t, q, CYCLE), JointLimits.of(IIWA, soft), IIWA.prismatic, "test")
    axes = np.array(fig.axes[:21]).reshape(7, 3)
    for j, (pos, vel, acc) in enumerate(axes):
        hard, rated = IIWA.hard_limits[j], IIWA.rated_speed[j]
        expected = {HARD: [hard.lower, hard.upper]}
        if j < 6:  # J7's soft limits are its hard ones: drawn once
            expected[SOFT] = [soft[j].lower, soft[j].upper]
        assert limit_lines(pos) == expected
        assert limit_lines(vel) == {SPEED: [-rated, rated]}
        assert limit_lines(acc) == {ACCEL: [-IIWA.max_accel[j], IIWA.max_accel[j]]}
    assert len(fig.legends) == 1 and [t.get_text() for t in fig.legends[0].get_texts()] == [HARD, SOFT, SPEED, ACCEL]


@pytest.mark.parametrize("text, size", [("1600x1200", Size(1600, 1200)), (" 640X480 ", Size(640, 480))])
def test_size_parses(text: str, size: Size) -> None:
    assert Size.parse(text) == size


@pytest.mark.parametrize("text", ["1600", "1600x", "x1200", "16OOx1200", "-5x10", "100x100", "20000x1000"])
def test_a_bad_size_says_what_is_expected(text: str) -> None:
    with pytest.raises(SizeError, match="WIDTHxHEIGHT in pixels|must be 200 .. 10000 px"):
        Size.parse(text)


def synthetic_feedback(seconds: float = 2.0, lost: slice = slice(700, 705)) -> Feedback:
    """iiwa feedback at 1 kHz (Unix times), every axis on a sine, a few samples lost."""
    t = 1.7e9 + np.arange(int(seconds / CYCLE)) * CYCLE
    q = np.array(IIWA.ready_pose) + 0.3 * np.sin(np.outer(t - t[0], np.arange(1, 8)))
    keep = np.ones(len(t), dtype=bool)
    keep[lost] = False
    return Feedback("arm0", t[keep], q[keep], IIWA.type)


def png_shape(path: Path) -> tuple[int, ...]:
    return tuple(matplotlib.image.imread(path).shape[:2])


def test_the_pngs_have_the_size_asked_for(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    settings = PlotSettings.check(arm=None, recording=None, seconds=None, start=0.5, end=None,
                                  output=str(tmp_path / "run.png"), path_output=None, size="1234x567", robot=None,
                                  show=False)
    assert render(synthetic_feedback(), settings, sys.stderr) == 0
    assert png_shape(tmp_path / "run.png") == (567, 1234)
    assert png_shape(tmp_path / "run_path.png") == (567, 1234)
    err = capsys.readouterr().err
    assert f"wrote {tmp_path / 'run.png'}" in err and f"wrote {tmp_path / 'run_path.png'}" in err


def test_an_unknown_robot_asks_for_robot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    settings = PlotSettings.check(arm=None, recording=None, seconds=None, start=0.0, end=None,
                                  output=str(tmp_path / "x.png"), path_output=None, size="800x600", robot=None,
                                  show=False)
    feedback = dataclasses.replace(synthetic_feedback(), robot_type=None)
    assert render(feedback, settings, sys.stderr) == 1
    assert "no getManipInfo reply was had): give --robot (iiwa," in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


# -- a recording ---------------------------------------------------------------------------------------------


def recorded_run(arm: str = "arm0", n: int = 1500) -> list[Recorded]:
    """A recording's messages: the feedback as its JSON form, the traces of a getManipInfo and a
    getSoftLimitJoint call (``CallTrace``), and another arm's feedback."""
    keys, other = ArmKeys(arm), ArmKeys("arm1")
    fb = synthetic_feedback(n * CYCLE, slice(0, 0))
    soft = [{"upper": h.upper - 0.2, "lower": h.lower + 0.2} for h in IIWA.hard_limits]
    info = {"manufactur": IIWA.manufacturer, "type": IIWA.type, "axisNum": 7, "cmdCycle": 1, "isGripper": False}
    out = [Recorded(keys.traced(keys.interface(Interface.COMMON, OP.getManipInfo)), 0.001,
                    {"t": 0.001, "request": {}, "reply": {"id": 0, "comment": "", "mInfo": info}}),
           Recorded(keys.traced(keys.servo_common(OP.getSoftLimitJoint)), 0.003,
                    {"t": 0.003, "request": {}, "reply": {"id": 0, "comment": "", "softLimit": soft}})]
    for tm, q in zip(fb.tm, fb.pos):
        value = {"tm": {"sec": int(tm), "nsec": int(round((tm % 1) * 1e9))}, "pos": q.tolist()}
        out += [Recorded(keys.pos_feedback, tm - fb.tm[0], value), Recorded(other.pos_feedback, tm - fb.tm[0], value)]
    return out


def test_the_feedback_and_the_arms_replies_are_read_from_recorded_messages() -> None:
    messages = recorded_run()
    keys = ArmKeys("arm0")
    got = feedback_of((m for m in messages if m.key.startswith(keys.root + "/")), "arm0")
    assert got.pos.shape == (1500, 7) and got.robot_type == IIWA.type
    assert got.soft is not None and got.soft[0] == LimitValue(IIWA.hard_limits[0].upper - 0.2,
                                                              IIWA.hard_limits[0].lower + 0.2)
    assert np.diff(got.tm) == pytest.approx(CYCLE, abs=2e-6)  # the samples' own tm, to the ns


@pytest.fixture
def recording_file(tmp_path: Path) -> Path:
    """:func:`recorded_run` written by the recorder's own writer (``launcher/record/recording.py``)."""
    path = tmp_path / "run.mcap"
    writer = RecordingWriter(path)
    try:
        for m in recorded_run():
            t = int(round(m.t * 1e9))
            writer.write(m.key, t, t, json.dumps(m.value).encode())
    finally:
        writer.close()
    return path


@pytest.fixture
def no_network(monkeypatch: pytest.MonkeyPatch) -> None:
    """Any attempt of the command line to join a network fails the test."""
    def refuse(*_: Any, **__: Any) -> Any:
        raise AssertionError("the command opened a Zenoh session")
    monkeypatch.setattr(zenoh, "open", refuse)


def test_plot_from_a_recording(tmp_path: Path, recording_file: Path, no_network: None,
                               capsys: pytest.CaptureFixture[str]) -> None:
    source = recording_file
    out = tmp_path / "ptp.png"
    argv = ["plot", "--from", str(source), "--arm", "arm0", "--start", "0.2", "--end", "1.2", "-o", str(out),
            "--path", str(tmp_path / "cp.png"), "--size", "900x700", "--no-show"]
    assert cli.main(argv) == 0, capsys.readouterr().err
    assert png_shape(out) == (700, 900) and png_shape(tmp_path / "cp.png") == (700, 900)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cp.png", "ptp.png", "run.mcap"]
    err = capsys.readouterr().err
    assert "jara-arm plot: messages read 1502/1502 (100 %) (1500 feedback samples)" in err, err  # the last word
    # Two arms in the file: which one must be said.
    assert cli.main(["plot", "--from", str(source), "-o", str(tmp_path / "x.png"), "--no-show"]) == 1
    assert "holds the arms arm0, arm1: choose one with --arm" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("argv, message", [
    (["--from", "{tmp}/missing.mcap"], "--from {tmp}/missing.mcap: no such file"),
    (["--start", "2", "--end", "1"], "--end 1 s must come after --start 2 s"),
    (["--start", "2", "--end", "2"], "--end 2 s must come after --start 2 s"),
    (["--size", "1600"], "expected WIDTHxHEIGHT in pixels"),
    (["--size", "50x50"], "width and height must be 200 .. 10000 px"),
    (["--start", "-1"], "expected a number of 0 or more"),
    (["--seconds", "0"], "expected a positive number"),
    (["--seconds", "2", "--from", "x.mcap"], "not allowed with argument"),
    (["--robot", "r2d2"], "invalid choice: 'r2d2'"),
])
def test_bad_input_exits_2_and_writes_nothing(argv: list[str], message: str, tmp_path: Path, no_network: None,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert cli.main(["plot", *argv, "-o", str(tmp_path / "out.png"), "--no-show"]) == 2
    err = capsys.readouterr().err
    assert message.replace("{tmp}", str(tmp_path)) in err and "Traceback" not in err, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("output, path, message", [
    ("out.jpg", None, "-o {tmp}/out.jpg: the figure is written as PNG"),
    ("nowhere/out.png", None, "no directory {tmp}/nowhere"),
    ("out.png", "out.png", "is the -o file: the two figures need two files"),
])
def test_bad_file_names_exit_2(output: str, path: str | None, message: str, tmp_path: Path, no_network: None,
                               capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["plot", "--seconds", "1", "-o", str(tmp_path / output), "--no-show"]
    assert cli.main(argv + (["--path", str(tmp_path / path)] if path else [])) == 2
    assert message.replace("{tmp}", str(tmp_path)) in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


# -- live: the command as a process against `jara-arm up` -------------------------------------------------

class Arm(LiveArm):
    """The live system's client (conftest.py ``live``)."""

    def ptp(self, delta: float = 0.3) -> None:
        target = (np.array(self.model.ready_pose) + delta).tolist()
        assert self.client.middle(OP.movePTPJointAbs, {"jointPoints": target}).ok

    def command(self, *argv: str) -> list[str]:
        command, *rest = argv
        return [*LAUNCHER, command, "--connect", self.endpoint, *rest]


@pytest.fixture(scope="module", params=["iiwa"])
def robot_name(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.mark.timeout(120)
def test_live_plot_during_a_ptp(arm: Arm, tmp_path: Path) -> None:
    out = tmp_path / "ptp.png"
    plot = Proc(arm.command("plot", "--arm", "arm0", "--seconds", "3", "-o", str(out), "--size", "1000x800",
                            "--no-show"))
    try:
        plot.wait_for_line("feedback samples of arm0:", timeout=30)  # subscribed, 1 s of samples in
        arm.ptp()
        assert plot.popen.wait(30) == 0, plot.output
    finally:
        plot.stop()
    assert png_shape(out) == (800, 1000) and png_shape(tmp_path / "ptp_path.png") == (800, 1000)
    assert f"wrote {out}" in plot.output
    arm.client.wait_idle()


@pytest.mark.timeout(180)
def test_live_plot_from_a_recording(arm: Arm, tmp_path: Path) -> None:
    mcap = tmp_path / "run.mcap"
    record = Proc(arm.command("record", "--arm", "arm0", "-o", str(mcap)))
    try:
        wait_recording(record)
        arm.ptp()
        arm.client.wait_idle()
    finally:
        assert record.stop(signal.SIGINT, timeout=30) == 0, record.output
    out = tmp_path / "ptp.png"
    run = subprocess.run(arm.command("plot", "--from", str(mcap), "--robot", "iiwa", "-o", str(out), "--size",
                                     "1200x900", "--no-show"), capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert png_shape(out) == (900, 1200) and png_shape(tmp_path / "ptp_path.png") == (900, 1200)
    assert "messages read" in run.stderr  # the progress
