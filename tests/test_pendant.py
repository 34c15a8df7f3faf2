"""``jara-arm pendant`` on the live system: its actions over HTTP, and hold-to-jog in a real browser.

The browser part drives headless Chromium over its DevTools protocol (``test_view.py``'s ``Browser``):
press and hold a jog button, the arm moves; release it, the arm stops; hold it and close the tab, the arm
stops within the lease.
"""

from __future__ import annotations

import json
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from jara_arm.schema import codec
from jara_arm.schema.codec import Encoding
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.messages import CALL_TRACE
from jara_arm.schema.operations import OP
from jara_arm.schema.keys import Service

from .harness import LiveArm, Recorder, launched, listening
from .support import LAUNCHER, Proc, client_session, free_port, wait_until
from .test_view import Browser

#: The pendant's lease per jog call [s] (``pendant.LEASE_MS``).
LEASE = 0.5
#: Farther than this from where the arm came to rest, it was still moving [rad]: a thousand times what the world's
#: joints wander at rest, and the last 0.1 mrad of a jog's stop takes a few milliseconds.
AT_REST = 1e-4


@pytest.fixture(scope="module")
def pendant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[LiveArm, str, Path]]:
    """The iiwa and ``jara-arm pendant`` of it: (arm, the page's URL, a work folder)."""
    folder = tmp_path_factory.mktemp("pendant")
    with launched("--robot", "iiwa", "--program-dir", str(folder)) as (proc, port), client_session(port) as session:
        arm = LiveArm(session, "iiwa", proc=proc)
        arm.client.wait_alive((Service.SERVO, Service.PLANNER, Service.COMMAND))
        page_port = free_port()
        served = Proc([*LAUNCHER, "pendant", "--port", str(page_port), "--program",
                       str(folder / "arm0.program.yaml"), "--connect", listening(proc)])
        try:
            served.wait_for_line("jara-arm pendant: http://", timeout=60)
            yield arm, f"http://127.0.0.1:{page_port}/", folder
        finally:
            assert served.stop() == 0, served.output
            assert "Traceback" not in served.output, served.output


@pytest.fixture
def arm(pendant: tuple[LiveArm, str, Path]) -> LiveArm:
    pendant[0].reset()
    return pendant[0]


def post(url: str, action: str, body: dict[str, Any] | None = None) -> dict[str, Any]:
    request = urllib.request.Request(url + "api/" + action, data=json.dumps(body or {}).encode(),
                                     headers={"Content-Type": "application/json"}, method="POST")
    with urllib.request.urlopen(request, timeout=10) as r:
        reply: dict[str, Any] = json.load(r)
        return reply


def hold(url: str, body: dict[str, Any], seconds: float, until: Callable[[], bool] | None = None) -> None:
    """A held jog button: a ``jog`` call every 0.1 s for ``seconds`` [s] or until ``until()`` holds, as the page
    renews it. A renewal that comes after the lease lapsed (this client starved: seen with two test workers
    beside two busy loops) is refused and the arm brakes, as it must ("call again once it holds"); the hold calls
    again until one is accepted. Any other refusal fails."""
    end = time.monotonic() + seconds
    while time.monotonic() < end and not (until is not None and until()):
        reply = post(url, "jog", body)
        if not (reply["id"] == ReturnCode.STATUS_ERR and "lapsed" in reply["comment"]):
            assert reply["id"] == ReturnCode.OK, reply
        time.sleep(0.1)


def get_state(url: str) -> dict[str, Any]:
    with urllib.request.urlopen(url + "api/state", timeout=10) as r:
        state: dict[str, Any] = json.load(r)
        return state


def test_live_the_pendants_actions_call_the_arm(arm: LiveArm, pendant: tuple[LiveArm, str, Path]) -> None:
    url = pendant[1]
    q0 = arm.joints()
    # Held until J2 went 0.06 rad: held for 0.8 s it went 0.049 rad once, the renewals late (a quiet run of three
    # test workers), where 0.27 rad is its 20 % for 0.8 s.
    hold(url, {"axis": 2, "speedRatio": -20}, 10.0, until=lambda: arm.joints()[1] < q0[1] - 0.06)
    assert post(url, "jogStop")["id"] == ReturnCode.OK
    arm.wait_rest()
    assert arm.joints()[1] < q0[1] - 0.05
    state = get_state(url)
    assert state["axes"] == 7 and state["alarms"] == [] and state["state"] & StateBit.SERVO_ON, state
    taught = post(url, "teach", {"name": "here"})
    assert taught["id"] == ReturnCode.OK and "here" in taught["comment"], taught
    assert post(url, "override", {"ratio": 40})["id"] == ReturnCode.OK
    assert get_state(url)["override"] == 40.0
    assert post(url, "override", {"ratio": 100})["id"] == ReturnCode.OK
    bad = post(url, "fly")
    assert bad["id"] == ReturnCode.VALUE_ERR and "jog" in bad["comment"], bad
    # The big stop is the e-stop: a FAULT, the servo off; cleared as any alarm.
    assert post(url, "estop")["id"] == ReturnCode.OK
    wait_until(lambda: get_state(url)["alarms"], 5.0, what="the e-stop's alarm on the page")
    assert get_state(url)["alarms"][0]["code"] == "0x01"
    assert post(url, "clearAlarms")["id"] == ReturnCode.OK
    assert post(url, "servoON")["id"] == ReturnCode.OK


def button_centre(b: Browser, label: str, nth: int) -> tuple[float, float]:
    """The centre of the ``nth`` jog button whose text is ``label`` (J1 - is 0, J1 + is 0 of "+")."""
    expression = (f"(() => {{ const b = [...document.querySelectorAll('button.jog')].filter("
                  f"x => x.textContent === {json.dumps(label)})[{nth}]; if (!b) return null; "
                  "const r = b.getBoundingClientRect(); return [r.x + r.width / 2, r.y + r.height / 2]; })()")
    found: list[Any] = []

    def there() -> bool:
        value = b._call("Runtime.evaluate", expression=expression, returnByValue=True)["result"].get("value")
        found[:] = value or []
        return bool(value)

    wait_until(there, 30.0, 0.2, f"the page's jog button {label!r} #{nth}")
    return float(found[0]), float(found[1])


def mouse(b: Browser, kind: str, x: float, y: float) -> None:
    b._call("Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left", buttons=1 if kind == "mousePressed" else 0,
            clickCount=1)


def moving(arm: LiveArm, joint: int, within: float) -> bool:
    """Whether ``joint`` moves by more than 1e-4 rad over ``within`` [s]."""
    a = arm.joints()[joint]
    time.sleep(within)
    return abs(arm.joints()[joint] - a) > 1e-4


def test_live_a_renewal_of_a_released_hold_moves_nothing(arm: LiveArm, pendant: tuple[LiveArm, str, Path]) -> None:
    """A renewal in flight at the release reaches the pendant after its jogStop: dropped, or the planner would
    start a new jog after the button was let go. The next press is a hold of its own and moves."""
    url = pendant[1]
    hold(url, {"axis": 1, "speedRatio": 20, "page": "test", "hold": 7}, 0.4)
    assert post(url, "jogStop", {"page": "test", "hold": 7})["id"] == ReturnCode.OK
    arm.wait_rest()
    q = arm.joints()
    late = post(url, "jog", {"axis": 1, "speedRatio": 20, "page": "test", "hold": 7})
    assert late["id"] == ReturnCode.OK and "released" in late["comment"], late
    assert not arm.state() & StateBit.MOVING
    time.sleep(0.3)  # a jog it started would be moving by now: nothing may
    assert np.abs(arm.joints() - q).max() < 1e-6, f"moved from {q} to {arm.joints()}"
    again = post(url, "jog", {"axis": 1, "speedRatio": 20, "page": "test", "hold": 8})
    assert again["id"] == ReturnCode.OK and "released" not in again["comment"], again
    wait_until(lambda: arm.joints()[0] > q[0] + 1e-3, 5.0, what="J1 moving for the next hold",
               explain=arm.explain)
    assert post(url, "jogStop", {"page": "test", "hold": 8})["id"] == ReturnCode.OK
    arm.wait_rest()


def test_live_hold_to_jog_in_a_browser_and_release_or_close_the_tab_to_stop(
        arm: LiveArm, pendant: tuple[LiveArm, str, Path], tmp_path: Path) -> None:
    from .test_view import chromium

    chromium()  # skips, saying why, where there is no Chromium
    url = pendant[1]
    b = Browser(tmp_path)
    try:
        b._call("Page.navigate", url=url)
        # Every jog call the command answers is traced (``trace/Ext/jogJoint``, while someone subscribes): the last
        # one is the page's last renewal, which the arm must stop within the lease of.
        calls = arm.session.declare_subscriber(arm.keys.trace("Ext", OP.jogJoint), zenoh.handlers.FifoChannel(4096))
        traces: list[Any] = []

        def traced() -> bool:
            while (sample := calls.try_recv()) is not None:
                traces.append(codec.decode_message(CALL_TRACE, sample.payload.to_bytes(),
                                                   Encoding.of(sample.encoding)))
            return bool(traces)

        feedback = Recorder(arm.session, arm.keys.pos_feedback)

        def stops(since: float, what: str) -> None:
            """At rest within 3 s of ``since`` [s, monotonic], and within the lease of the page's last renewal
            and the 50 ms the jog's stop may take after it (up to 50 ms more for the feedback to show it).
            Not within the lease of ``since``: a headless Chromium beside busy loops handles a release or a
            close late, and renews meanwhile (release to rest 1.30 s, a quiet run of three test workers).
            When the arm came to rest is its last moving feedback sample (the servo's stamp), not when this
            test saw the state say so: beside a busy loop per core that was 662 ms after the last renewal,
            the polls through the gateway late (fresh-clone run 109)."""
            wait_until(lambda: not arm.state() & StateBit.MOVING, 5.0, 0.01, f"the arm at rest after {what}")
            stopped = time.monotonic() - since
            assert stopped < 3.0, f"at rest {stopped:.3f} s after {what}"
            assert traced(), f"no renewal of the page traced before {what}"
            tm, q = feedback.through(time.time(), timeout=10.0)
            # Moving: more than 0.1 mrad from where it came to rest. Not a speed between two samples: at rest the
            # world's joints wander by about 5e-7 rad a cycle, which over a short stamp gap read as 1e-3 rad/s.
            away = np.abs(q - q[-1]).max(axis=1) > AT_REST
            moved = tm[away]
            assert len(moved), f"no motion in the feedback before {what}"
            bound = LEASE + 0.05 + 0.05

            def after_last_renewal() -> float:
                return float(moved[-1]) - max(t.t for t in traces)

            # A trace comes after its call's reply, at normal priority and dropped rather than queued: beside
            # busy loops one can arrive after this test saw the arm at rest. Up to 2 s more for a late one.
            deadline = time.monotonic() + 2.0
            while after_last_renewal() >= bound and time.monotonic() < deadline:
                time.sleep(0.05)
                traced()
            after_last = after_last_renewal()
            last = float(moved[-1]) - after_last
            window = tm > tm[-1] - 1.5
            j1 = [(round((a - last) * 1e3), round(float(b), 5)) for a, b in zip(tm[window][::25], q[window][::25, 0])]
            assert after_last < bound, (f"at rest {after_last * 1e3:.0f} ms after the page's last renewal; J1 over "
                                        f"the last 1.5 s (stamp - last renewal [ms], rad): {j1}")
            print(f"pendant in Chromium: at rest {stopped * 1e3:.0f} ms after {what}, "
                  f"{after_last * 1e3:.0f} ms after its last renewal (lease {LEASE * 1e3:.0f} ms)")
            traces.clear()

        x, y = button_centre(b, "+", 0)  # J1 +
        q0 = arm.joints()[0]
        mouse(b, "mouseMoved", x, y)
        mouse(b, "mousePressed", x, y)
        wait_until(lambda: arm.joints()[0] > q0 + 0.02, 10.0, what="J1 moving while the button is held",
                   explain=lambda: f"the page: {b.text()[-600:]}\n{arm.explain()}")
        time.sleep(0.6)  # held: it goes on (the page renews the lease)
        assert moving(arm, 0, 0.1), f"J1 stopped while the button was held; the page: {b.text()[-600:]}\n{arm.explain()}"
        mouse(b, "mouseReleased", x, y)
        stops(time.monotonic(), "the release")
        assert not moving(arm, 0, 0.2)
        # Held, then the tab hidden (another tab in front, a phone's screen off): released. J1 - this time: three
        # presses of J1 + beside busy loops reached its soft limit (2.97 rad) and the third was refused.
        xm, ym = button_centre(b, "-", 0)
        mouse(b, "mouseMoved", xm, ym)
        mouse(b, "mousePressed", xm, ym)
        q2 = arm.joints()[0]
        wait_until(lambda: arm.joints()[0] < q2 - 0.02, 10.0, what="J1 moving back, held",
                   explain=lambda: f"the page: {b.text()[-600:]}\n{arm.explain()}")
        b._call("Runtime.evaluate", expression="Object.defineProperty(document, 'hidden', {value: true, "
                "configurable: true}); document.dispatchEvent(new Event('visibilitychange'))")
        stops(time.monotonic(), "the tab was hidden")
        b._call("Runtime.evaluate", expression="delete document.hidden")
        mouse(b, "mouseReleased", xm, ym)
        arm.home()  # J1 back to 0: the third press has the whole way to the soft limit
        mouse(b, "mouseMoved", x, y)
        # Held, then the tab closed: the calls stop, the lease lapses.
        q1 = arm.joints()[0]
        mouse(b, "mousePressed", x, y)
        wait_until(lambda: arm.joints()[0] > q1 + 0.02, 10.0, what="J1 moving again",
                   explain=lambda: f"the page: {b.text()[-600:]}\n{arm.explain()}")
        wait_until(traced, 10.0, what="the page's renewals traced",
                   explain=lambda: f"the page: {b.text()[-600:]}\n{arm.explain()}")

        def close_tab() -> None:
            try:
                b._call("Page.close")
            except Exception:  # the page's socket may go before its answer does: closed either way
                pass

        closing = threading.Thread(target=close_tab, daemon=True)  # its answer may take a while: watch meanwhile
        closed = time.monotonic()
        closing.start()
        stops(closed, "the tab closed")
        calls.undeclare()
        assert not arm.state() & StateBit.ALARM, arm.explain()
    finally:
        b.close()
    assert np.isfinite(arm.joints()).all()
