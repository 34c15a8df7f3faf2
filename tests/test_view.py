"""``jara-arm view`` (issue 13, part 1): the scene from each robot's URDF, the page in a real browser.

Pure tests: every robot model's URDF gives its links' shapes; the planner's path
preview; the 1 kHz feedback thinned to the page's rate; bad input exits 2. The
browser tests load the page in headless Chromium and compare screenshots: first
against a fake arm (this test's own publications on a Zenoh session of its own,
no system), then (``test_live_*``) against ``jara-arm up`` and a PTP move.

Chromium comes from the system's packages (Debian: ``apt-get install -y chromium``,
which ``.ci/run`` does where it can, as root); where it cannot be had, the browser
tests are skipped saying so.
"""

from __future__ import annotations

import base64
import contextlib
import dataclasses
import json
import os
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
import urllib.request
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import pytest
import zenoh
from PIL import Image
from websockets.sync.client import connect

from jara_arm.kinematics import Kinematics
from jara_arm.launcher import cli
from jara_arm.launcher.view.scene import RobotGeometry, ShapeKind, box_edges, limit_box
from jara_arm.launcher.view.view import View, ViewError, ViewSettings, check_port
from jara_arm.robots import ROBOTS, robot
from jara_arm.schema import codec
from jara_arm.schema.codes import StateBit
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.messages import (
    SERVO_STATUS,
    SERVO_WORLD,
    STATE_MESSAGE,
    ServoStatus,
    ServoWorld,
    StateMessage,
    WorldBox,
)
from jara_arm.schema.operations import OP
from jara_arm.schema.planner import (
    MOTION_SETTINGS,
    PLANNED_PATH,
    PLANNER_PROGRESS,
    MotionSettings,
    PlannedPath,
    PlannerProgress,
)
from jara_arm.schema.types import LimitValue, Time
from jara_arm.services.planner.planning import PREVIEW_POINTS, MotionPlanner
from jara_arm.services.runtime.wire import Publication
from jara_arm.services.runtime.zenoh_args import zenoh_config

from .harness import LiveArm, Ticker
from .support import free_port, motion_settings, plan_request, wait_until

# -- the scene, from the URDFs ---------------------------------------------------------------------


def _urdf_visuals(path: Path) -> dict[str, int]:
    """Link name -> number of <visual> elements, read from the URDF with no robotics library."""
    root = ET.parse(path).getroot()
    return {link.get("name", ""): len(link.findall("visual")) for link in root.iter("link")
            if link.findall("visual")}


@pytest.mark.parametrize("name", list(ROBOTS))
def test_every_robot_models_links_have_their_shapes(name: str) -> None:
    model = robot(name)
    geometry = RobotGeometry(model)
    visuals = _urdf_visuals(model.urdf)
    assert geometry.links == tuple(visuals)  # every link with a visual, in the URDF's order
    assert len(geometry.shapes) == sum(visuals.values())
    for shape in geometry.shapes:
        if shape.kind is ShapeKind.MESH:
            assert shape.mesh is not None and shape.mesh.is_file(), shape
        else:
            assert all(v > 0 for v in shape.size), shape
    home = list(model.ready_pose) + ([model.gripper_limits.upper] if model.gripper_limits else [])
    poses = geometry.poses(home)
    assert len(poses) == len(geometry.shapes)
    # The flange the view draws the control point on is where the kinematics puts it.
    assert np.allclose(geometry.flange().homogeneous, Kinematics(model).fk(model.ready_pose).homogeneous, atol=1e-9)


def test_the_links_follow_the_joints() -> None:
    model = robot("arm6")
    geometry = RobotGeometry(model)
    before = [p.copy() for p in geometry.poses(model.ready_pose)]
    after = geometry.poses(np.array(model.ready_pose) + 0.3)
    moved = [not b.isApprox(a) for b, a in zip(before, after)]
    assert not moved[0] and all(moved[-3:])  # the base stays, the wrist moves
    with pytest.raises(ValueError, match="expected 6 joint values"):
        geometry.poses([0.0] * 5)


def test_the_soft_limit_box_is_drawn_within_reach() -> None:
    settings = _settings(robot("iiwa"), cartesian=(LimitValue(0.8, -0.2), LimitValue(1e30, -1e30),
                                                   LimitValue(1.0, 0.0)))
    centre, size = limit_box(settings)
    assert np.allclose(centre, [0.3, 0.0, 0.5]) and np.allclose(size, [1.0, 6.0, 1.0])
    edges = box_edges(centre, size)
    assert edges.shape == (12, 2, 3)
    along = np.abs(edges[:, 0] - edges[:, 1])
    assert ((along > 0).sum(axis=1) == 1).all()  # each edge along one axis, 4 along each, as long as the box
    assert np.allclose(np.sort(along.sum(axis=1)), np.sort(np.repeat(size, 4)))


def _settings(model: Any, cartesian: tuple[LimitValue, ...] = (LimitValue(2.0, -2.0),) * 3,
              tool: np.ndarray | None = None) -> MotionSettings:
    return motion_settings(model, softLimitCartesian=cartesian,
                           **({} if tool is None else {"controlPointOffset": tool}))


def test_the_planner_previews_the_control_point_path() -> None:
    model = robot("arm6")
    tool = np.eye(4)[:3].copy()
    tool[2, 3] = 0.1  # 10 cm along the flange's z
    start, target = np.array(model.ready_pose), np.array(model.ready_pose) + 0.3
    motion = MotionPlanner(model).plan(plan_request(OP.movePTPJointAbs, {"jointPoints": target.tolist()},
                                                    _settings(model, tool=tool)), start)
    assert 2 <= len(motion.preview) <= PREVIEW_POINTS < len(motion.q)
    kin = Kinematics(model)
    c = pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.1]))
    assert np.allclose(motion.preview[0], kin.control_point(start, c).translation, atol=1e-9)
    assert np.allclose(motion.preview[-1], kin.control_point(target, c).translation, atol=1e-9)


# -- the page, with a fake arm on a Zenoh session of the test's own -------------------------------


@pytest.fixture
def lone_session() -> Iterator[zenoh.Session]:
    """A peer session that talks to no one: the view and the fake arm meet in it."""
    session = zenoh.open(zenoh_config("peer"))
    try:
        yield session
    finally:
        session.close()


class FakeArm:
    """What an arm's services publish that the view reads, from this test: token, world, settings, feedback."""

    def __init__(self, session: zenoh.Session, arm: str, robot_name: str) -> None:
        self.keys = keys = ArmKeys(arm)
        self.model = robot(robot_name)
        self.session = session
        self.joints = np.array(list(self.model.ready_pose)
                               + ([self.model.gripper_limits.upper] if self.model.gripper_limits else []))
        self.world = ServoWorld(robot_name, (0.0, 0.0, 0.0), ())
        self.settings: MotionSettings | None = None  # none published until set
        self._pubs = [Publication(session, keys.servo_world), Publication(session, keys.command_settings),
                      Publication(session, keys.state)]
        self._fb = session.declare_publisher(keys.servo_status)
        self._token = session.liveliness().declare_token(keys.alive(Service.SERVO))
        self.sent = 0
        # ~1 kHz, faster than the servo's 100 Hz (less on a busy machine: the test counts)
        self._ticker = Ticker(0.001, self._tick)

    def _tick(self) -> None:
        world, settings, state = self._pubs
        if self.sent % 200 == 0:
            world.put_message(SERVO_WORLD, self.world)
            if self.settings is not None:
                settings.put_message(MOTION_SETTINGS, self.settings)
            state.put_message(STATE_MESSAGE, StateMessage(int(StateBit.SERVO_ON)))
        self._fb.put(codec.encode_message(*_feedback(self.joints)))
        self.sent += 1

    def publish_path(self, motion: int, running: int) -> None:
        """A ``Planner/path`` of ``motion`` (a line from the origin), then a progress with ``running``."""
        points = tuple((0.1 * k, 0.2, 0.3) for k in range(5))
        with Publication(self.session, self.keys.planner_path) as path:
            path.put_message(PLANNED_PATH, PlannedPath(motion, OP.movePTPJointAbs, points))
        now = Time.from_seconds(time.time())
        with Publication(self.session, self.keys.planner_progress) as progress:
            progress.put_message(PLANNER_PROGRESS, PlannerProgress(now, running, (running,) if running else (),
                                                                   0, 0, False, bool(running), now, motion))

    def close(self) -> None:
        if self._ticker.closed:
            return
        self._ticker.close()
        self._token.undeclare()
        self._fb.undeclare()
        for pub in self._pubs:
            pub.close()


def _feedback(joints: np.ndarray) -> tuple[Any, Any]:
    """A ``Servo/status`` whose measured joints are ``joints``: what the view draws."""
    q = tuple(joints.tolist())
    zeros = (0.0,) * len(q)
    return SERVO_STATUS, ServoStatus(Time.from_seconds(time.time()), True, False, False, 0, 0, 0, 0, zeros, zeros,
                                     q, pos=q)


def _step_for(view: View, seconds: float, rate: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        t0 = time.monotonic()
        view.step()
        time.sleep(max(0.0, 1.0 / rate - (time.monotonic() - t0)))


@pytest.mark.timeout(60)
def test_the_view_draws_a_fake_arm_at_the_page_rate(lone_session: zenoh.Session) -> None:
    rate = 20.0
    view = View(lone_session, ViewSettings(port=free_port(), rate=rate))
    fake = FakeArm(lone_session, "v1", "arm6")
    try:
        _step_for(view, 1.0, rate)  # discovered, world and first feedback
        arm = view.arms["v1"]
        assert arm.robot == "arm6" and arm.scene is not None and arm.scene.link_count == 8
        assert "SERVO_ON" in arm.state
        frames, sent, t0 = arm.frames, fake.sent, time.monotonic()
        fake.joints = fake.joints + 0.01  # keeps changing: every frame has something new to draw
        for _ in range(40):
            fake.joints = fake.joints + 0.001
            _step_for(view, 1.0 / rate, rate)
        drawn, received = arm.frames - frames, fake.sent - sent
        elapsed = time.monotonic() - t0
        assert received > 5 * drawn  # ~1 kHz in (fewer on a busy machine), at most `rate` a second drawn
        assert 5 <= drawn <= rate * elapsed + 1
        # The running motion's path is drawn while it runs.
        fake.publish_path(7, running=7)
        _step_for(view, 0.3, rate)
        assert arm.scene.path_shown and arm.running == 7 and "motion 7 (movePTPJointAbs)" in arm.markdown()
        fake.publish_path(8, running=0)  # accepted, not running (the queue's next): nothing drawn
        _step_for(view, 0.3, rate)
        assert not arm.scene.path_shown
        fake.close()
        _step_for(view, 0.5, rate)
        assert not arm.present and "gone" in arm.label()  # greyed at its last pose, kept
        fake = FakeArm(lone_session, "v1", "scara4")  # back, with another robot: drawn anew
        _step_for(view, 1.0, rate)
        assert arm.present and arm.robot == "scara4" and arm.scene.link_count == 11
        assert list(view.arms) == ["v1"] and "gone" not in arm.label()
    finally:
        fake.close()
        view.close()


def test_a_port_in_use_is_a_readable_error(lone_session: zenoh.Session) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(ViewError, match=f"127.0.0.1:{port}: in use"):
            check_port("127.0.0.1", port)
        with pytest.raises(ViewError, match="in use"):
            View(lone_session, ViewSettings(port=port))
    with pytest.raises(ViewError, match="not an address of this host"):
        check_port("no-such-host.invalid", free_port())


@pytest.mark.parametrize("argv, message", [
    (["view", "--port", "0"], "'0' is not a TCP port (1..65535)"),
    (["view", "--port", "70000"], "'70000' is not a TCP port"),
    (["view", "--port", "http"], "'http' is not a TCP port"),
    (["view", "--arm", "a/b"], "arm id 'a/b' must be one chunk"),
    (["view", "--rate", "0"], "expected a positive number"),
])
def test_bad_view_options_exit_2(argv: list[str], message: str, monkeypatch: pytest.MonkeyPatch,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(zenoh, "open", lambda *_: pytest.fail("the command opened a Zenoh session"))
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_a_port_in_use_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert cli.main(["view", "--mode", "peer", "--port", str(port)]) == 2
    err = capsys.readouterr().err
    assert f"jara-arm view: cannot serve the page on 127.0.0.1:{port}: in use" in err and "Traceback" not in err


# -- the page in a real browser ---------------------------------------------------------------------

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")


def chromium() -> str:
    """The headless browser's path; pytest.skip saying why where there is none (see the module doc)."""
    for name in CHROMIUM_NAMES:
        if (path := shutil.which(name)) is not None:
            return path
    pytest.skip("no Chromium on this machine (Debian: apt-get install -y chromium, as root; .ci/run does it "
                "where it can): the page is not tested in a browser")


class Browser:
    """Headless Chromium (software WebGL) driven over its DevTools protocol: a page stays open and
    updates live, and is photographed in real time (a virtual-time budget would not wait for the
    page's websocket). Every host but loopback resolves to nothing: a page that needs the internet
    shows it here."""

    def __init__(self, workdir: Path, width: int = 960, height: int = 600) -> None:
        profile = workdir / "chromium-profile"
        argv = [chromium(), "--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                "--hide-scrollbars", "--no-first-run", "--remote-debugging-port=0", f"--user-data-dir={profile}",
                "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1, EXCLUDE localhost",
                f"--window-size={width},{height}", "about:blank"]
        self._proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                      env={**os.environ, "HOME": str(workdir)})
        active = profile / "DevToolsActivePort"
        deadline = time.monotonic() + 60.0
        while not (active.is_file() and len(active.read_text().splitlines()) >= 2):
            assert self._proc.poll() is None and time.monotonic() < deadline, "Chromium did not start"
            time.sleep(0.1)
        port = active.read_text().splitlines()[0]
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as listing:
            page = next(t for t in json.load(listing) if t["type"] == "page")
        self._ws = connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=10)
        self._id = 0
        self._call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=SCALE,
                   mobile=False)

    def _call(self, method: str, **params: Any) -> dict[str, Any]:
        self._id += 1
        self._ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            message = json.loads(self._ws.recv(timeout=60))
            if message.get("id") == self._id:
                assert "error" not in message, message
                return dict(message.get("result", {}))

    def open(self, url: str, timeout: float = 60.0) -> None:
        """Navigate to ``url`` and wait until the page has loaded there: until then the page may be between
        renderers ("Not attached to an active page", seen once beside two busy loops) and cannot be shot."""
        self._call("Page.navigate", url=url)
        deadline = time.monotonic() + timeout
        while True:
            self._id += 1
            self._ws.send(json.dumps({"id": self._id, "method": "Runtime.evaluate", "params": {
                "expression": "[document.readyState, location.href]", "returnByValue": True}}))
            while True:
                message = json.loads(self._ws.recv(timeout=60))
                if message.get("id") == self._id:
                    break
            value = message.get("result", {}).get("result", {}).get("value")
            if value and value[0] == "complete" and str(value[1]).startswith(url.rstrip("/")):
                return
            assert time.monotonic() < deadline, f"the page did not load {url} within {timeout} s: {message}"
            time.sleep(0.1)

    def text(self) -> str:
        """The page's visible text (hidden elements left out), e.g. the panel's rendered markdown."""
        result = self._call("Runtime.evaluate", expression="document.body.innerText", returnByValue=True)
        return str(result["result"].get("value", ""))

    def shot(self, out: Path) -> np.ndarray:
        """The page now, an (H, W, 3) uint8 array (also written to ``out``)."""
        out.write_bytes(base64.b64decode(self._call("Page.captureScreenshot", format="png")["data"]))
        return np.asarray(Image.open(out).convert("RGB"))

    def close(self) -> None:
        self._ws.close()
        self._proc.terminate()
        self._proc.wait(20)


@contextlib.contextmanager
def browser(workdir: Path) -> Iterator[Browser]:
    b = Browser(workdir)
    try:
        yield b
    finally:
        b.close()


#: [s] Between the shots that must agree for the page to have settled: longer than a change takes to draw, and
#: short enough that a fade (viser fades new objects in) differs between two of them.
SETTLE_SPACING = 0.5


def settled_shot(b: Browser, out: Path) -> np.ndarray:
    """The page once its scene is drawn and stopped changing (faded in): two shots ``SETTLE_SPACING`` apart that
    agree, the scene not blank (before it draws, the page's shots agree too: one colour, its panel text already
    there)."""
    deadline = time.monotonic() + 60.0
    time.sleep(SETTLE_SPACING)
    last = b.shot(out)
    while True:
        time.sleep(SETTLE_SPACING)
        now = b.shot(out)
        if (differ(last, now) < 1e-4 and drawn(now)) or time.monotonic() > deadline:
            return now
        last = now


def drawn(shot: np.ndarray) -> bool:
    """Whether the scene shows anything (its grid at least): over 1 % of its pixels away from its most common
    colour."""
    scene = shot[scene_mask(shot.shape)].astype(int)
    colours, counts = np.unique(scene, axis=0, return_counts=True)
    background = colours[np.argmax(counts)]
    return float((np.abs(scene - background).max(axis=1) > 24).mean()) > 0.01


def eventually(b: Browser, out: Path, than: np.ndarray, share: float, timeout: float = 30.0) -> float:
    """Shots until one differs from ``than`` by more than ``share`` of the scene's pixels; the largest share."""
    deadline = time.monotonic() + timeout
    best = 0.0
    while time.monotonic() < deadline:
        best = max(best, differ(than, b.shot(out)))
        if best > share:
            break
        time.sleep(0.5)
    return best


def differ(a: np.ndarray, b: np.ndarray) -> float:
    """Share of the 3D view's pixels that differ by more than a little (rendering noise is not a change).

    The panel (top right: its text changes with the arms' state) and viser's notice of software WebGL
    (top left) are left out (``scene_mask``): what is compared is the scene alone."""
    changed = np.abs(a.astype(int) - b.astype(int)).max(axis=2) > 24
    return float(changed[scene_mask(changed.shape)].mean())


#: [px] viser's overlays, fixed in CSS pixels whatever the window: the panel at the top right (two arms'
#: lines fit), the notice of software WebGL at the top left (960 x 600 shots: panel 625-945 x 15-170,
#: notice 15-310 x 15-150).
PANEL = (360, 300)
NOTICE = (330, 170)
#: Device pixels per CSS pixel of the browser tests' page: the page is laid out at 960 x 600 and drawn at a
#: quarter of the pixels. Chromium draws WebGL in software here (SwiftShader), at about one core for a
#: full-size page: the suite's largest single CPU cost beside the systems it tests.
SCALE = 0.5


def scene_mask(shape: tuple[int, ...]) -> np.ndarray:
    """True where a shot of ``shape`` shows the 3D scene, not the page's overlays."""
    h, w = shape[:2]
    mask = np.ones((h, w), dtype=bool)
    mask[:round(PANEL[1] * SCALE), w - round(PANEL[0] * SCALE):] = False
    mask[:round(NOTICE[1] * SCALE), :round(NOTICE[0] * SCALE)] = False
    return mask


class _Served:
    """The view's loop on a thread of the test, so that a browser can load the page meanwhile."""

    def __init__(self, view: View, rate: float = 30.0) -> None:
        self.view = view
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(rate,), daemon=True)
        self._thread.start()

    def _run(self, rate: float) -> None:
        while not self._stop.is_set():
            self.view.step()
            self._stop.wait(1.0 / rate)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.view.close()


def test_the_page_needs_nothing_from_the_internet(lone_session: zenoh.Session) -> None:
    served = _Served(View(lone_session, ViewSettings(port=free_port())))
    try:
        with urllib.request.urlopen(served.view.url, timeout=10) as page:
            html = page.read().decode("utf-8", errors="replace")
    finally:
        served.close()
    assert "<html" in html
    # The client is one file (its code inside, compressed); the only URL in it is the SVG namespace.
    assert {u for u in re.findall(r"https?://[A-Za-z0-9.\-]+", html)} <= {"http://www.w3.org"}


@pytest.mark.timeout(240)
def test_the_page_shows_a_fake_arm_and_its_moves(lone_session: zenoh.Session, tmp_path: Path) -> None:
    chromium()
    served = _Served(View(lone_session, ViewSettings(port=free_port())))
    fake: FakeArm | None = None
    try:
        with browser(tmp_path) as b:
            b.open(served.view.url)
            empty = settled_shot(b, tmp_path / "empty.png")
            fake = FakeArm(lone_session, "v2", "arm6")  # the links and the label alone (~0.3 %)
            assert eventually(b, tmp_path / "arm.png", empty, 0.01) > 0.01, "the page shows no arm"
            links = settled_shot(b, tmp_path / "arm.png")
            fake.world = dataclasses.replace(fake.world, obstacles=(WorldBox((0.6, 0.3, 0.1), (0.1, 0.1, 0.1)),))
            fake.settings = _settings(fake.model, cartesian=(LimitValue(0.8, -0.4), LimitValue(0.6, -0.6),
                                                             LimitValue(1.0, 0.0)))
            assert eventually(b, tmp_path / "world.png", links, 0.005) > 0.005, "no obstacle, no soft-limit box"
            shown = settled_shot(b, tmp_path / "world.png")
            fake.joints = fake.joints + np.array([1.2, 0.4, -0.4, 0.0, 0.5, 0.0])
            assert eventually(b, tmp_path / "moved.png", shown, 0.005) > 0.005, "the page did not follow the arm"
    finally:
        if fake is not None:
            fake.close()
        served.close()


# -- live: the page of `jara-arm up` in a browser --------------------------------------------------


@pytest.fixture(scope="module", params=["iiwa"])
def robot_name(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@contextlib.contextmanager
def _view_process(arm: LiveArm, port: int) -> Iterator[subprocess.Popen[str]]:
    """``jara-arm view`` as a process, a client of the live system, until its URL line."""
    proc = subprocess.Popen([sys.executable, "-m", "jara_arm.launcher", "view", "--connect", arm.endpoint,
                             "--port", str(port)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert f"http://127.0.0.1:{port}/" in line, (line, proc.stderr.read() if proc.poll() is not None else "")
        yield proc
    finally:
        proc.terminate()
        assert proc.wait(20) == 0


@pytest.mark.timeout(300)
def test_live_the_page_shows_the_arm_and_a_ptp_move(arm: LiveArm, tmp_path: Path) -> None:
    chromium()
    with browser(tmp_path) as b:
        with _view_process_empty(port=free_port()) as empty_url:  # the same page with no arm on its network
            b.open(empty_url)
            empty = settled_shot(b, tmp_path / "empty.png")
        port = free_port()
        with _view_process(arm, port):
            b.open(f"http://127.0.0.1:{port}/")
            shown = settled_shot(b, tmp_path / "arm.png")
            assert differ(empty, shown) > 0.02, "the page looks the same with the arm as without"
            # The panel says what the README promises: the arm, its robot, its state bits, its alarms, its services.
            said = ("arm0 — iiwa", "state: 0x01 SERVO_ON", "alarms: none", "services: alarm-monitor, command, "
                    "planner, servo")
            wait_until(lambda: all(s in b.text() for s in said), 30.0, 0.5, f"the panel to say {said}",
                       explain=lambda: f"the page's text: {b.text()!r}")
            target = np.array(arm.model.ready_pose) + np.array([0.8, 0.3, 0.0, 0.3, 0.0, 0.4, 0.0])
            reply = arm.client.middle(OP.movePTPJointAbs, {"jointPoints": target.tolist()})
            assert reply.ok, f"{reply}\n{arm.explain()}"
            arm.client.wait_idle()
            assert not arm.client.state & StateBit.ALARM, arm.explain()
            # The open page follows the move by itself (no reload).
            assert eventually(b, tmp_path / "moved.png", shown, 0.005) > 0.005, "the page did not follow the PTP move"
            # It only reads: the arm is where the move left it, and nothing moves it since.
            pos = np.asarray(arm.client.common(OP.getFeedbackPosJoint)["pos"])[:len(target)]
            assert np.abs(pos - target).max() < 1e-3, f"the arm is at {pos}, not {target}\n{arm.explain()}"
            assert not arm.client.state & StateBit.MOVING


@contextlib.contextmanager
def _view_process_empty(port: int) -> Iterator[str]:
    """A view of a network with no arm (a peer that meets no one): the empty scene."""
    session = zenoh.open(zenoh_config("peer"))
    served = _Served(View(session, ViewSettings(port=port)))
    try:
        yield served.view.url
    finally:
        served.close()
        session.close()

