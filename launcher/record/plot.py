"""``jara-arm plot``: an arm's joint traces and Cartesian path over a time window, as two PNG files.

    jara-arm plot [--arm ID] (--seconds S | --from FILE.mcap) [--start S] [--end S] [--robot NAME]
                  -o FILE.png [--path FILE.png] [--size WxH] [--no-show] [Zenoh options]

The samples are the arm's ``Servo/posFeedback`` (``TimedJointPos``), from the
live system (subscribed for ``--seconds``, or until Ctrl-C) or from a recording
of ``jara-arm record`` (``launcher/record/recording.py``). Their own timestamps ``tm``
give the time axis and the spacing of the differences (``traces.py``). The
robot model comes from ``--robot``, else from the ``getManipInfo`` reply (asked
live; in a recording if it holds one); the soft limits from
``getSoftLimitJoint`` the same way. Figure 1 (``-o``): position, velocity and
acceleration of each arm axis with the limits; figure 2 (``--path``, default
``<-o stem>_path.png``): the control point's path in the arm base frame, from
forward kinematics of the same samples. Both are also shown on screen if there
is one (and not ``--no-show``).

Input that can be checked before anything is read (a missing file, ``--end``
not after ``--start``, a bad ``--size`` or output name) is refused with exit 2
and nothing written; a window with too few samples, or no robot model, exits 1.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, Protocol, TextIO

import numpy as np
import pinocchio as pin
import zenoh
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from jara_arm.client import Arm, NoAnswer
from jara_arm.kinematics import Kinematics, hg_to_se3
from jara_arm.robots import ROBOTS, RobotModel, RobotModelError, robot
from jara_arm.schema import codec
from jara_arm.schema import wire_types as w
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.operations import OP, Interface
from jara_arm.schema.types import LimitValue

from ..tools.arm_state import sample_encoding
from .plot_figures import DPI, Size, SizeError, draw_joints, draw_path
from .traces import JointLimits, TraceError, cartesian_path, traces

_RING = 1 << 14  #: feedback samples held between two drains (16 s at 1 kHz)
_POLL = 0.01  #: [s] sleep of the drain loop when the channel is empty
_PROGRESS_EVERY = 1.0  #: [s] between two progress reports


class PlotInputError(JaraArmError, ValueError):
    """Options that cannot make a plot, found before anything is read (exit 2, nothing written)."""


class PlotDataError(JaraArmError, RuntimeError):
    """Samples or a robot model that cannot make a plot, found while reading them (exit 1)."""


@dataclasses.dataclass(frozen=True)
class PlotSettings:
    arm: str | None  # None: the live default, or the recording's only arm
    recording: Path | None  # ``--from``; None for the live system
    seconds: float | None  # [s] live only; None: until Ctrl-C
    start: float  # [s] after the first sample
    end: float | None  # [s] after the first sample; None: to the last
    output: Path  # figure 1
    path_output: Path  # figure 2
    size: Size
    robot: str | None  # None: from getManipInfo
    show: bool

    @classmethod
    def check(cls, *, arm: str | None, recording: str | None, seconds: float | None, start: float,
              end: float | None, output: str, path_output: str | None, size: str, robot: str | None,
              show: bool) -> "PlotSettings":
        """The settings if they can make a plot; PlotInputError saying what is wrong otherwise."""
        try:
            pixels = Size.parse(size)
        except SizeError as exc:
            raise PlotInputError(f"--size: {exc}") from None
        if end is not None and end <= start:
            raise PlotInputError(f"--end {end:g} s must come after --start {start:g} s")
        source = None
        if recording is not None:
            source = Path(recording)
            if not source.is_file():
                raise PlotInputError(f"--from {recording}: no such file")
        out = _png(output, "-o")
        path_out = _png(path_output, "--path") if path_output is not None else out.with_name(f"{out.stem}_path.png")
        if path_out.resolve() == out.resolve():
            raise PlotInputError(f"--path {path_out} is the -o file: the two figures need two files")
        return cls(arm, source, seconds, start, end, out, path_out, pixels, robot, show)


def _png(name: str, option: str) -> Path:
    path = Path(name)
    if path.suffix.lower() != ".png":
        raise PlotInputError(f"{option} {name}: the figure is written as PNG: give a name ending in .png")
    if not path.parent.is_dir():
        raise PlotInputError(f"{option} {name}: no directory {path.parent}")
    return path


@dataclasses.dataclass(frozen=True)
class Feedback:
    """An arm's feedback samples, with what is known of the arm."""

    arm: str
    tm: np.ndarray  # (N,) [s] the samples' ``tm``
    pos: np.ndarray  # (N, dof) [rad or m], the gripper axis (if any) last
    robot_type: str | None = None  # ``ManipInfo.type``, if a getManipInfo reply was had
    soft: tuple[LimitValue, ...] | None = None  # from a getSoftLimitJoint reply
    tool: pin.SE3 | None = None  # the control point offset (flange to control point), if known


class Recorded(Protocol):
    """A message of a recording, as ``launcher/record/recording.py`` reads it."""

    @property
    def key(self) -> str: ...
    @property
    def t(self) -> float: ...  # [s]
    @property
    def value(self) -> Any: ...


class Progress:
    """``plot: 12000/60000 messages (20 %)`` on ``err``, at most once a second; in place on a terminal."""

    def __init__(self, err: TextIO, what: str, total: int | None = None) -> None:
        self.err = err
        self.what = what
        self.total = total
        self.count = 0
        self._tty = err.isatty()
        self._next = time.monotonic() + _PROGRESS_EVERY

    def step(self, extra: str = "") -> None:
        self.count += 1
        if time.monotonic() >= self._next:
            self._next = time.monotonic() + _PROGRESS_EVERY
            self._say(extra)

    def done(self, extra: str = "") -> None:
        self._say(extra)
        if self._tty:
            print(file=self.err, flush=True)

    def _say(self, extra: str) -> None:
        text = f"jara-arm plot: {self.what} {self.count}"
        if self.total:
            text += f"/{self.total} ({100.0 * self.count / self.total:.0f} %)"
        text += f" {extra}" if extra else ""
        if self._tty:
            print(f"\r{text}\x1b[K", end="", file=self.err, flush=True)
        else:
            print(text, file=self.err, flush=True)


# -- the samples: from a recording, or live ------------------------------------------------------------

def _query_keys(keys: ArmKeys, op: str) -> tuple[str, str]:
    """Where the calls of a Common operation are traced (``CallTrace``): the command service's and the servo's."""
    return keys.traced(keys.interface(Interface.COMMON, op)), keys.traced(keys.servo_common(op))


def feedback_of(messages: Iterable[Recorded], arm: str, progress: Progress | None = None) -> Feedback:
    """The arm's feedback samples among recorded ``messages`` (the JSON form of ``TimedJointPos``), and the
    robot type and soft limits of any ``getManipInfo`` / ``getSoftLimitJoint`` reply among them."""
    keys = ArmKeys(arm)
    info_keys, soft_keys = _query_keys(keys, OP.getManipInfo), _query_keys(keys, OP.getSoftLimitJoint)
    tm: list[float] = []
    pos: list[Sequence[float]] = []
    robot_type: str | None = None
    soft: tuple[LimitValue, ...] | None = None
    for m in messages:
        if progress is not None:
            progress.step()
        value = m.value
        if m.key == keys.pos_feedback:
            try:
                tm.append(value["tm"]["sec"] + value["tm"]["nsec"] * 1e-9)
                pos.append(value["pos"])
            except (KeyError, TypeError) as exc:
                raise PlotDataError(f"a sample on {m.key} at {m.t:.3f} s is not a TimedJointPos: {exc!r}") from None
        elif not isinstance(value, dict) or not isinstance(reply := value.get("reply"), dict):
            continue
        elif m.key in info_keys and isinstance(reply.get("mInfo"), dict):
            robot_type = str(reply["mInfo"].get("type"))
        elif m.key in soft_keys and isinstance(reply.get("softLimit"), list):
            try:
                soft = tuple(LimitValue(float(v["upper"]), float(v["lower"])) for v in reply["softLimit"])
            except (KeyError, TypeError, ValueError):
                pass  # not a reply we can read: the hard limits are still drawn
    return Feedback(arm, *_arrays(arm, tm, pos), robot_type, soft)


def _arrays(arm: str, tm: list[float], pos: list[Sequence[float]]) -> tuple[np.ndarray, np.ndarray]:
    """(N,) times and (N, dof) positions; PlotDataError if the samples differ in length."""
    if len({len(p) for p in pos}) > 1:
        raise PlotDataError(f"the feedback samples of {arm} do not all have the same number of axes")
    return np.asarray(tm, dtype=float), np.asarray(pos, dtype=float).reshape(len(pos), len(pos[0]) if pos else 0)


def read_recording(path: Path, arm: str | None, err: TextIO) -> Feedback:
    """The feedback of ``arm`` (default: the recording's only arm) in the MCAP file ``path``."""
    from . import recording

    try:
        found = recording.arms(str(path))
    except Exception as exc:  # the MCAP reader's own errors have no common root: say what it said
        raise PlotDataError(f"cannot read {path}: {exc}") from None
    if arm is None:
        if len(found) != 1:
            raise PlotDataError(f"{path} holds the arms {', '.join(found) or '(none)'}: choose one with --arm")
        arm = found[0]
    elif arm not in found:
        raise PlotDataError(f"{path} has no arm {arm!r}; it holds {', '.join(found) or 'none'}")
    keys = ArmKeys(arm)
    wanted = [keys.pos_feedback, *_query_keys(keys, OP.getManipInfo), *_query_keys(keys, OP.getSoftLimitJoint)]
    progress = Progress(err, "messages read", _message_total(path, wanted))
    try:
        feedback = feedback_of(recording.read_messages(str(path), wanted), arm, progress)
    except PlotDataError:
        raise
    except Exception as exc:  # as above: a truncated or foreign file
        raise PlotDataError(f"cannot read {path}: {exc}") from None
    progress.done(f"({len(feedback.tm)} feedback samples)")
    return feedback


def _message_total(path: Path, keys: Sequence[str]) -> int | None:
    """The number of messages on ``keys`` by the MCAP file's summary, for the progress; None if it has none."""
    try:
        from mcap.reader import make_reader  # type: ignore[import-not-found,unused-ignore]  # comes with recording

        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
        if summary is None or summary.statistics is None:
            return None
        ids = [cid for cid, channel in summary.channels.items() if channel.topic in keys]
        return sum(summary.statistics.channel_message_counts.get(cid, 0) for cid in ids) or None
    except Exception:  # only the progress's total is lost: the reading says what is wrong with the file
        return None


def _ask(client: Arm, op: str) -> Any | None:
    """A Common operation's reply, from the command service or else the servo; None if neither answers OK."""
    for servo in (False, True):
        try:
            reply = client.call(Interface.COMMON, op, servo=servo)
        except NoAnswer:
            continue
        if reply.ok:
            return reply
    return None


def _live_tool(client: Arm, model: RobotModel) -> pin.SE3 | None:
    """The control point offset C = inv(T_flange) · B · T_robot, from the joint and Cartesian feedback at
    rest (there is no operation that reads C back); None if the arm moved meanwhile or a reply is missing."""
    try:
        before = client.call(Interface.COMMON, OP.getFeedbackPosJoint)
        cartesian = client.call(Interface.MIDDLE, OP.getFeedbackPosCartesian)
        base = client.call(Interface.MIDDLE, OP.getBaseOffset)
        after = client.call(Interface.COMMON, OP.getFeedbackPosJoint)
    except NoAnswer:
        return None
    if not all(r.ok for r in (before, cartesian, base, after)):
        return None
    q0, q1 = np.asarray(before["pos"], dtype=float), np.asarray(after["pos"], dtype=float)
    if np.abs(q1 - q0).max() > 1e-6:  # [rad or m] moving: the two feedbacks are not of one pose
        return None
    arm_pose = hg_to_se3(base["offset"]) * hg_to_se3(cartesian["pos"].carPos)
    return Kinematics(model, seed_table=0).fk(q0[:model.axis_num]).inverse() * arm_pose


def collect_live(session: zenoh.Session, client: Arm, seconds: float | None, stop: threading.Event,
                 err: TextIO) -> Feedback:
    """The arm's feedback for ``seconds`` [s] (None: until ``stop``), with its manipulator info, soft limits
    and control point offset, asked first."""
    info = _ask(client, OP.getManipInfo)
    soft = _ask(client, OP.getSoftLimitJoint)
    robot_type = info["mInfo"].type if info is not None else None
    known = next((r for r in ROBOTS.values() if r.type == robot_type), None)
    tool = _live_tool(client, known) if known is not None else None
    sub = session.declare_subscriber(client.keys.pos_feedback, zenoh.handlers.RingChannel(_RING))
    tm: list[float] = []
    pos: list[Sequence[float]] = []
    progress = Progress(err, f"feedback samples of {client.keys.arm}:")
    if seconds is None:
        print("jara-arm plot: recording the feedback until Ctrl-C", file=err, flush=True)
    deadline = time.monotonic() + seconds if seconds is not None else None
    try:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            sample = sub.try_recv()
            if sample is None:
                stop.wait(_POLL)
                continue
            payload = sample.payload.to_bytes()
            try:
                fb = codec.decode_message(w.TIMED_JOINT_POS, payload, sample_encoding(payload, sample.encoding))
            except JaraArmError as exc:  # anyone may publish here: say it and go on
                print(f"jara-arm plot: undecodable feedback sample: {exc}", file=err, flush=True)
                continue
            tm.append(fb.tm.to_seconds())
            pos.append(tuple(fb.pos))
            progress.step(f"({tm[-1] - tm[0]:.1f} s)")
    finally:
        sub.undeclare()
    progress.done()
    return Feedback(client.keys.arm, *_arrays(client.keys.arm, tm, pos), robot_type,
                    tuple(soft["softLimit"]) if soft is not None else None, tool)


# -- the figures --------------------------------------------------------------------------------------

def model_of(feedback: Feedback, name: str | None, err: TextIO) -> RobotModel:
    """``--robot`` if given (a note if the arm said otherwise), else the model of the arm's ``ManipInfo.type``."""
    said = next((r for r in ROBOTS.values() if r.type == feedback.robot_type), None)
    if name is not None:
        model = robot(name)
        if said is not None and said is not model:
            print(f"jara-arm plot: {feedback.arm} says it is a {said.name}; plotting it as --robot {name}",
                  file=err, flush=True)
        return model
    if said is None:
        why = (f"its type {feedback.robot_type!r} is none of the robot models" if feedback.robot_type
               else "no getManipInfo reply was had")
        raise PlotDataError(f"which robot {feedback.arm} is is not known ({why}): give --robot "
                            f"({', '.join(ROBOTS)})")
    return said


def has_display() -> bool:
    """Whether figures can be shown: a desktop system, or an X11/Wayland display."""
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _figure(size: Size, on_screen: bool) -> Figure:
    """A pyplot figure when it will be shown, else a bare one on the Agg canvas (no GUI toolkit needed)."""
    if on_screen:
        import matplotlib.pyplot as plt

        return plt.figure(figsize=size.inches, dpi=DPI)
    fig = Figure(figsize=size.inches, dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def render(feedback: Feedback, settings: PlotSettings, err: TextIO) -> int:
    """Both figures of ``feedback`` written (and shown if asked and possible); 0, or 1 with a message."""
    try:
        model = model_of(feedback, settings.robot, err)
        n = model.axis_num
        if len(feedback.pos) and feedback.pos.shape[1] < n:
            raise PlotDataError(f"the feedback of {feedback.arm} has {feedback.pos.shape[1]} axes, "
                                f"a {model.name} {n}")
        joints = traces(feedback.tm, feedback.pos[:, :n], model.cmd_cycle, settings.start, settings.end)
    except (PlotDataError, TraceError, RobotModelError) as exc:
        print(f"jara-arm plot: {exc}", file=err, flush=True)
        return 1
    soft = feedback.soft if feedback.soft is not None and len(feedback.soft) == n else None
    limits = JointLimits.of(model, soft)
    window = f"{joints.t[0]:.2f} .. {joints.t[-1]:.2f} s"
    on_screen = settings.show and has_display()
    fig = _figure(settings.size, on_screen)
    draw_joints(fig, joints, limits, model.prismatic,
                f"{feedback.arm} ({model.name}): joints, {window}, {len(joints.t)} samples, "
                f"{joints.gaps} gap(s){'' if soft is not None else ', soft limits not known'}")
    fig.savefig(settings.output, dpi=DPI)
    print(f"jara-arm plot: wrote {settings.output}", file=err, flush=True)
    tool = feedback.tool
    points = cartesian_path(Kinematics(model, seed_table=0), joints.q, tool)
    path_fig = _figure(settings.size, on_screen)
    what = "control point" if tool is not None else "flange"
    draw_path(path_fig, points, f"{feedback.arm} ({model.name}): {what}"
              f"{'' if tool is not None else ' (control point offset not known)'} in the arm base frame, {window}",
              what)
    path_fig.savefig(settings.path_output, dpi=DPI)
    print(f"jara-arm plot: wrote {settings.path_output}", file=err, flush=True)
    if on_screen:
        import matplotlib.pyplot as plt

        plt.show()
    return 0
