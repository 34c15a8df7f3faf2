"""Teaching points and running programs (``Ext/teach``, ``jara-arm program check`` and ``run``;
``schema/program.py``, ``launcher/program/``), on the live system and from the command line.

What a person commissioning a cell checks: points taught where the arm was, a program of them that runs and
reaches each within 0.5 mm, and a program with a mistake that says where (line and column) and moves nothing.
"""

from __future__ import annotations

import re
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from jara_arm.client import rel
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.keys import Service
from jara_arm.schema.operations import OP
from jara_arm.schema.program import ProgramError, load, parse

from .harness import LiveArm, launched, listening
from .support import LAUNCHER, Proc, client_session, wait_until
from .test_collision import TURN, _box_ahead


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[LiveArm, Path]]:
    """The iiwa with a box 0.5 rad ahead of its J1 (test_collision.py's), its program file in a folder of
    the test's own (``--program-dir``)."""
    folder = tmp_path_factory.mktemp("programs")
    with launched("--robot", "iiwa", "--obstacle", _box_ahead().argument(), "--program-dir", str(folder)) as (
            proc, port), client_session(port) as session:
        arm = LiveArm(session, "iiwa", proc=proc)
        arm.client.wait_alive((Service.SERVO, Service.PLANNER, Service.COMMAND))
        yield arm, folder


@pytest.fixture
def arm(cell: tuple[LiveArm, Path]) -> LiveArm:
    cell[0].reset()
    return cell[0]


def program_cli(arm: LiveArm, *args: str, timeout: float = 120.0) -> Proc:
    """``jara-arm program ARGS`` against the live arm, ended."""
    proc = Proc([*LAUNCHER, "program", *args, "--connect", listening(arm.proc)])
    proc.popen.wait(timeout)
    proc.stop()  # ended: its output read to the end
    return proc


def taught(arm: LiveArm, name: str) -> None:
    reply = arm.client.ext(OP.teach, {"name": name})
    assert reply.id == ReturnCode.OK, reply
    # What it stored is where the arm is.
    assert np.abs(np.asarray(reply["jointPoint"]) - arm.joints()).max() < 1e-6  # the drives hold within 1e-6


def test_live_teach_then_a_six_step_program_reaches_every_point(arm: LiveArm, cell: tuple[LiveArm, Path]) -> None:
    path = cell[1] / "arm0.program.yaml"
    path.unlink(missing_ok=True)
    a = arm.client
    a.setSpeedCartesian(50)
    taught(arm, "a")
    a.moveLinearCartesianRel(rel(dz=-0.08))
    taught(arm, "b")
    a.moveLinearCartesianRel(rel(dx=0.05, dy=0.05))
    taught(arm, "v")
    a.moveLinearCartesianRel(rel(dx=0.05, dy=-0.05))
    taught(arm, "c")
    a.movePTPJointAbs(arm.model.ready_pose)
    points = load(path).points
    assert set(points) == {"a", "b", "v", "c"}
    # The steps after the taught points, written by hand as a user would (a comment that teach keeps).
    text = path.read_text()
    steps = textwrap.dedent("""\
        steps:  # PTP, LIN, CIRC, a blend, a wait and a loop
          - ptp: b
            speed: 40
          - lin: a
            speed: 30
          - lin: b
          - circ: [v, c]
          - lin: a
            blend: 0.02
          - wait: 0.2
          - loop: 2
            steps:
              - ptp: c
              - lin: a
        """)
    path.write_text(re.sub(r"steps:.*\Z", steps, text, flags=re.S))
    taught(arm, "home")  # teach again: the steps and their comment stay
    assert "# PTP, LIN, CIRC, a blend, a wait and a loop" in path.read_text()
    assert len(load(path).flat()) == 10
    run = program_cli(arm, "run", str(path))
    assert run.popen.returncode == 0, run.output
    out = run.output
    assert "step 10/10" in out and "program done: 10 steps" in out, out
    # Every motion measured but the CIRC the next LIN blends into: 5 Cartesian, 3 joint targets.
    mm = [float(x) for x in re.findall(r"arrived, ([0-9.e+-]+) mm from its target", out)]
    rad = [float(x) for x in re.findall(r"arrived, ([0-9.e+-]+) rad from its target", out)]
    assert len(mm) == 5 and max(mm) <= 0.5 and len(rad) == 3 and max(rad) < 1e-3, out
    assert "step 4/10: circ c via v" in out, out
    assert "blended into step 5" in out, out
    assert np.abs(arm.pose()[:3, 3] - arm.fk(points["a"].joints)[:3, 3]).max() < 5e-4
    assert not arm.state() & StateBit.ALARM, arm.explain()


def test_live_check_finds_each_kind_of_mistake_at_its_line_and_run_moves_nothing(
        arm: LiveArm, tmp_path: Path) -> None:
    a = arm.client
    here = a.getFeedbackPosCartesian()
    pose = np.asarray(here.carPos)
    far = pose.copy()
    far[0, 3] += 3.0  # 3 m further out: nobody reaches it
    flipped = here.structFlag ^ 1 or 2
    lower = pose.copy()
    lower[2, 3] -= 0.05  # 5 cm below: a LIN there in another posture
    rows = lambda m: "[" + ", ".join("[" + ", ".join(f"{v:.9g}" for v in r) + "]" for r in m) + "]"  # noqa: E731
    path = tmp_path / "bad.yaml"
    path.write_text(textwrap.dedent(f"""\
        points:
          start: {{joints: {[float(x) for x in arm.joints()[:arm.model.axis_num]]}, pose: {rows(pose)}, elbow: {float(here.elbow)}, posture: {here.structFlag}}}
          turned: {{joints: {[float(x) for x in TURN]}}}
        steps:
          - ptp: start
          - lin: {{pose: {rows(far)}}}
          - ptp: turned
          - lin: {{pose: {rows(lower)}, elbow: {float(here.elbow)}, posture: {flipped}}}
        """))
    before = arm.joints()
    check = program_cli(arm, "check", str(path))
    assert check.popen.returncode == 1, check.output
    found = {int(m.group(1)): m.group(2) for m in re.finditer(rf"{re.escape(str(path))}:(\d+):\d+: (.*)", check.output)}
    assert set(found) == {6, 7, 8}, check.output  # the three motions that cannot be planned, by line
    assert "obstacle 1" in found[7], found[7]  # the PTP through the box
    assert "posture" in found[8], found[8]
    run = program_cli(arm, "run", str(path))
    assert run.popen.returncode == 1 and "nothing moved" in run.output, run.output
    assert np.abs(arm.joints() - before).max() < 1e-6
    assert not arm.state() & StateBit.MOVING


def test_program_mistakes_in_the_file_are_each_given_with_line_and_column(tmp_path: Path) -> None:
    text = textwrap.dedent("""\
        points:
          p1: {joints: [0, 0, 0, 0, 0, 0, 0]}
        steps:
          - ptp: p2
          - lin: p1
            speed: 0
          - wait: soon
          - loop: 0
            steps: [{ptp: p1}]
          - jump: p1
        """)
    with pytest.raises(ProgramError) as raised:
        parse(text, tmp_path / "p.yaml")
    said = [str(m) for m in raised.value.mistakes]
    assert said == [
        "4:10: unknown point 'p2' (points: p1)",
        "6:12: speed: a whole percentage 1 .. 100, got 0",
        "7:11: wait: a number, got 'soon'",
        "8:11: loop: a count of 1 or more, got 0",
        "10:5: step 5: exactly one of ptp, lin, circ, wait, loop, got ['jump']",
    ], said
    bad = tmp_path / "bad.yaml"
    bad.write_text("steps:\n  - ptp: [1, 2\n")
    run = Proc([*LAUNCHER, "program", "run", str(bad), "--connect", "tcp/127.0.0.1:1"])
    run.popen.wait(60)
    assert run.stop() == 1, run.output
    assert re.search(r"bad\.yaml:3:1: not YAML", run.output) and "nothing moved" in run.output, run.output


def test_live_teach_refuses_a_bad_name_and_a_moving_arm(arm: LiveArm) -> None:
    reply = arm.client.ext(OP.teach, {"name": "9 lives"})
    assert reply.id == ReturnCode.VALUE_ERR and reply.comment.startswith("name"), reply
    target = np.array(arm.model.ready_pose) + np.array([-0.6, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    arm.client.setSpeedJoint(10)
    moving = arm.client.movePTPJointAbs(target, wait=False)
    reply = arm.client.ext(OP.teach, {"name": "mid"})
    assert reply.id == ReturnCode.STATUS_ERR and "moves" in reply.comment, reply
    moving.wait(60)


def test_live_a_program_run_step_by_step_waits_for_enter(arm: LiveArm, tmp_path: Path) -> None:
    import subprocess

    here = [float(x) for x in arm.joints()[:arm.model.axis_num]]
    there = [*here]
    there[0] += 0.2
    path = tmp_path / "two.yaml"
    path.write_text(f"points:\n  here: {{joints: {here}}}\n  there: {{joints: {there}}}\n"
                    "steps:\n  - ptp: there\n  - ptp: here\n")
    run = subprocess.run([*LAUNCHER, "program", "run", str(path), "--step", "--connect", listening(arm.proc)],
                         input="\n\n", capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert run.stdout.count("Enter to run it") == 2 and "step 2/2: ptp here: arrived" in run.stdout, run.stdout


def test_live_pause_resume_and_stop_act_on_a_running_program(arm: LiveArm, tmp_path: Path) -> None:
    """Another client pauses the program's motion: the arm holds and the run waits; resumed, it goes on to its
    end (exit 0). Stopped, the run ends saying so (exit 1) and the step after it never starts."""
    here = [float(x) for x in arm.joints()[:arm.model.axis_num]]
    there = [*here]
    there[0] -= 0.4
    path = tmp_path / "there_and_back.yaml"
    path.write_text(f"points:\n  here: {{joints: {here}}}\n  there: {{joints: {there}}}\n"
                    "steps:\n  - ptp: there\n    speed: 10\n  - ptp: here\n    speed: 10\n")
    run = Proc([*LAUNCHER, "program", "run", str(path), "--connect", listening(arm.proc)])
    try:
        run.wait_for_line("step 1/2: ptp there: motion", timeout=60)
        wait_until(lambda: arm.joints()[0] < here[0] - 0.05, 30.0, what="J1 under way")
        assert arm.client.middle(OP.pause).ok
        wait_until(lambda: arm.state() & StateBit.PAUSED and not moving(arm), 10.0, what="the arm held")
        held = arm.joints()[0]
        time.sleep(0.5)  # paused: the run waits, nothing moves
        assert abs(arm.joints()[0] - held) < 1e-4 and run.popen.poll() is None, run.output
        assert arm.client.middle(OP.resume).ok
        assert run.popen.wait(120) == 0, run.output
    finally:
        run.stop()
    assert "step 2/2: ptp here: arrived" in run.output and "program done: 2 steps" in run.output, run.output
    # Stopped in its first step: the run says so and ends; the second step never starts.
    run = Proc([*LAUNCHER, "program", "run", str(path), "--connect", listening(arm.proc)])
    try:
        run.wait_for_line("step 1/2: ptp there: motion", timeout=60)
        wait_until(lambda: arm.joints()[0] < here[0] - 0.05, 30.0, what="J1 under way")
        assert arm.client.middle(OP.stop).ok
        assert run.popen.wait(60) == 1, run.output
    finally:
        run.stop()
    assert "step 1/2: ptp there: FAILED" in run.output and "step 2/2" not in run.output, run.output
    arm.wait_rest()
    assert here[0] - 0.4 < arm.joints()[0] < here[0] - 0.05, "it went on after the stop"


def moving(arm: LiveArm) -> bool:
    """Whether J1 moves by more than 1e-5 rad over 50 ms."""
    a = arm.joints()[0]
    time.sleep(0.05)
    return abs(arm.joints()[0] - a) > 1e-5


def test_live_check_finds_a_step_that_would_run_at_a_speed_ratio_of_0(arm: LiveArm, tmp_path: Path) -> None:
    """A fresh arm's speed ratios may be 0 %: a lin with no speed of its own, after no step that set the Cartesian
    one, would be refused by the arm; check says so at its line, and a step's speed mends it for those after."""
    here = [float(x) for x in arm.joints()[:arm.model.axis_num]]
    pose = arm.pose()[:3].tolist()
    path = tmp_path / "slow.yaml"
    path.write_text(f"points:\n  here: {{joints: {here}, pose: {pose}}}\n"
                    "steps:\n  - ptp: here\n    speed: 20\n  - lin: here\n  - lin: here\n    speed: 10\n"
                    "  - lin: here\n")
    assert arm.client.middle(OP.setSpeedCartesian, {"spdRatio": 0}).ok
    check = program_cli(arm, "check", str(path))
    assert check.popen.returncode == 1, check.output
    assert f"{path.name}:6:10: lin here: the arm's speed ratio is 0 %" in check.output, check.output
    assert ":7:" not in check.output and ":9:" not in check.output and "1 mistake(s)" in check.output, check.output
