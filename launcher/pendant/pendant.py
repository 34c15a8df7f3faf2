"""``jara-arm pendant``: a teach pendant in the browser for one arm.

A page (``page.html``, served by this process, nothing from the internet) with hold-to-jog buttons per
joint and per Cartesian axis in the base and tool frames, the jog speed and the speed override, servo on
and off, a big STOP (the e-stop), the alarm list with clear, teach point, the program's steps with run,
step, pause, resume and stop, and the arm in 3D (``jara-arm view``'s page in a frame, served beside it).

The dead-man is end to end: while a jog button is held the page sends a jog every ``RENEW_MS``, and this
process makes one ``Ext/jog*`` call with a lease of ``LEASE_MS`` for each. Released, a lost connection, a
hidden tab or a closed one: the calls stop and the lease lapses in the planner (the page also sends
``jogStop`` on release, to brake at once). This process holds no lease of its own: a frozen pendant cannot
keep an arm moving. Each press is a hold of its own (``hold``, a number each page, ``page``, counts up); a
renewal of a hold already released (sent before the release, arriving after its ``jogStop``) is dropped here,
or the planner would take it for a new jog and move the arm again after the button was let go. Every action
is a call of the specification's or the extensions' operations through ``jara_arm.client.Arm``; in a
secure cell an observer's page shows everything and each action it tries is refused by the router (the page
shows the refusal).

HTTP: ``GET /`` the page, ``GET /api/state`` what it shows (JSON), ``POST /api/<action>`` with a JSON body,
answered ``{"id": .., "comment": ..}`` as RETURN_ID.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import http.server
import json
import logging
import sys
import threading
import time
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

from jara_arm.client import Arm, ArmError, Refused
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.keys import DEFAULT_ARM
from jara_arm.schema.operations import JOG_AXES, OP, Interface
from jara_arm.schema.program import Program, ProgramError, load

from ..command import USAGE_ERROR, Command, setup_logging
from ..program.run import Runner
from ..session import add_client_zenoh_arguments, arm_id, listening
from ..view.view import DEFAULT_HOST, View, ViewError, ViewSettings, check_port

log = logging.getLogger(__name__)

#: The lease of each jog call the page's hold makes [ms], and how often the page renews it [ms]: four
#: renewals may be lost or late before the arm stops. A jog goes no faster than it stops within half its lease
#: (``services/planner/jog.py``): 500 ms lets it reach full speed at acceleration times up to 0.24 s.
LEASE_MS = 500
RENEW_MS = 100
DEFAULT_PORT = 8090
#: Pages whose released holds are kept (each tab, each reload is a page of its own).
_PAGES_KEPT = 256


@dataclasses.dataclass
class ProgramRun:
    """The program the page runs: its steps, and where the run is."""

    program: Program | None = None
    error: str = ""
    running: bool = False
    stepping: bool = False
    said: list[str] = dataclasses.field(default_factory=list)
    go: threading.Event = dataclasses.field(default_factory=threading.Event)


class Pendant:
    """The actions of the page on one arm, and what the page shows of it."""

    def __init__(self, arm: Arm, program_path: Path | None, view_url: str) -> None:
        self.arm = arm
        self.view_url = view_url
        self.program_path = program_path
        self.run = ProgramRun()
        self._lock = threading.Lock()
        #: The newest hold each page released; a jog and its jogStop are one at a time, so that a renewal in
        #: flight at the release either comes before the jogStop or is dropped.
        self._released: dict[str, int] = {}
        self._jog_lock = threading.Lock()
        self.reload()

    def reload(self) -> None:
        if self.program_path is None:
            return
        try:
            self.run.program, self.run.error = load(self.program_path), ""
        except ProgramError as exc:
            self.run.program, self.run.error = None, str(exc)

    # -- what the page shows ---------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        a = self.arm
        out: dict[str, Any] = {"arm": a.keys.arm, "view": self.view_url}
        try:
            info = a.getManipInfo()
            bits = a.state
            out.update(axes=info.axisNum, state=bits,
                       stateText=" ".join(b.name for b in StateBit if bits & b) or "none",
                       joints=[round(q, 4) for q in a.getFeedbackPosJoint()],
                       alarms=[{"code": f"0x{x.code:02x}", "type": x.type.value, "description": x.description}
                               for x in a.getActiveAlarm()],
                       override=a.getSpeedOverride())
        except ArmError as exc:
            out["error"] = str(exc)
        r = self.run
        out["program"] = {
            "path": str(self.program_path or ""), "error": r.error, "running": r.running, "said": r.said[-12:],
            "steps": [f"line {s.where.line}: {s.describe()}" for s in (r.program.flat() if r.program else [])]}
        return out

    # -- what the page asks ------------------------------------------------------------------
    def act(self, action: str, body: dict[str, Any]) -> dict[str, Any]:
        """One action of the page; the reply as RETURN_ID ``{id, comment}``."""
        handler = self._ACTIONS.get(action)
        if handler is None:
            return {"id": int(ReturnCode.VALUE_ERR),
                    "comment": f"action: unknown {action!r}; one of {', '.join(sorted(self._ACTIONS))}"}
        try:
            return handler(self, body)
        except Refused as exc:
            return {"id": int(exc.code), "comment": exc.comment}
        except ArmError as exc:
            return {"id": int(ReturnCode.NG), "comment": str(exc)}
        except (KeyError, TypeError, ValueError) as exc:
            return {"id": int(ReturnCode.VALUE_ERR), "comment": f"{action}: bad request: {exc}"}

    def _call(self, interface: Interface, name: str, args: dict[str, Any] | None = None) -> dict[str, Any]:
        reply = self.arm.call(interface, name, args or {})
        return {"id": reply.id, "comment": reply.comment}

    def _jog(self, body: dict[str, Any]) -> dict[str, Any]:
        page, hold = str(body.get("page", "")), int(body.get("hold", 0))
        with self._jog_lock:
            if hold and hold <= self._released.get(page, 0):
                return {"id": int(ReturnCode.OK), "comment": f"OK: ignored: hold {hold} was released"}
            return self._jog_call(body)

    def _jog_stop(self, body: dict[str, Any]) -> dict[str, Any]:
        page, hold = str(body.get("page", "")), int(body.get("hold", 0))
        with self._jog_lock:
            if len(self._released) >= _PAGES_KEPT and page not in self._released:
                self._released.pop(next(iter(self._released)))  # the oldest page's: long closed
            self._released[page] = max(self._released.get(page, 0), hold)
            return self._call(Interface.EXT, OP.jogStop)

    def _jog_call(self, body: dict[str, Any]) -> dict[str, Any]:
        ratio = float(body["speedRatio"])
        if body.get("frame"):
            if body["axis"] not in JOG_AXES:
                raise ValueError(f"axis {body['axis']!r}")
            return self._call(Interface.EXT, OP.jogCartesian, {"frame": str(body["frame"]), "axis": body["axis"],
                                                               "speedRatio": ratio, "leaseMs": LEASE_MS})
        return self._call(Interface.EXT, OP.jogJoint, {"axis": int(body["axis"]), "speedRatio": ratio,
                                                       "leaseMs": LEASE_MS})

    def _estop(self, body: dict[str, Any]) -> dict[str, Any]:
        self.arm.session.put(self.arm.keys.estop, b"")
        return {"id": int(ReturnCode.OK), "comment": "OK: emergency stop put"}

    def _program(self, body: dict[str, Any]) -> dict[str, Any]:
        r = self.run
        with self._lock:
            if r.running:
                if body.get("step"):
                    r.go.set()  # the next step
                    return {"id": int(ReturnCode.OK), "comment": "OK: next step"}
                return {"id": int(ReturnCode.STATUS_ERR), "comment": "a program runs: pause, stop or wait"}
            self.reload()
            if r.program is None:
                return {"id": int(ReturnCode.VALUE_ERR), "comment": r.error or "no program (--program FILE)"}
            r.running, r.stepping, r.said = True, bool(body.get("step")), []
            r.go.clear()
            program = r.program
        threading.Thread(target=self._run_program, args=(program,), daemon=True, name="pendant-program").start()
        return {"id": int(ReturnCode.OK), "comment": "OK: running" + (" step by step" if body.get("step") else "")}

    def _run_program(self, program: Program) -> None:
        r = self.run

        class Lines:
            def write(self, text: str) -> None:
                r.said.extend(line for line in text.splitlines() if line)

            def flush(self) -> None:
                pass

        def ask(prompt: str) -> str:  # --step: the page's Step button instead of Enter
            r.said.append(prompt.strip())
            r.go.wait()
            r.go.clear()
            return ""

        try:
            code = Runner(self.arm, Lines(), ask if r.stepping else None).run(program)  # type: ignore[arg-type]
            r.said.append("program ended" if code == 0 else "program FAILED")
        except ArmError as exc:
            r.said.append(f"program FAILED: {exc}")
        finally:
            r.running = False

    _ACTIONS: dict[str, Callable[[Pendant, dict[str, Any]], dict[str, Any]]] = {
        "jog": _jog,
        "jogStop": _jog_stop,
        "servoON": lambda self, b: self._call(Interface.COMMON, OP.servoON),
        "servoOFF": lambda self, b: self._call(Interface.COMMON, OP.servoOFF),
        "clearAlarms": lambda self, b: self._call(Interface.COMMON, OP.clearAlarms),
        "estop": _estop,
        "override": lambda self, b: self._call(Interface.EXT, OP.setSpeedOverride, {"ratio": float(b["ratio"])}),
        "teach": lambda self, b: self._call(Interface.EXT, OP.teach, {"name": str(b["name"])}),
        "pause": lambda self, b: self._call(Interface.MIDDLE, OP.pause),
        "resume": lambda self, b: self._call(Interface.MIDDLE, OP.resume),
        "stop": lambda self, b: self._call(Interface.MIDDLE, OP.stop),
        "run": _program,
    }


def page() -> bytes:
    return resources.files(__package__).joinpath("page.html").read_bytes()


class _Handler(http.server.BaseHTTPRequestHandler):
    pendant: Pendant  # set on the subclass the server is made with

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - http.server's name
        log.debug("%s " + format, self.address_string(), *args)

    def _send(self, code: int, body: bytes, kind: str) -> None:
        try:
            self.send_response(code)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)
        except (BrokenPipeError, ConnectionResetError):  # the page went (a closed tab) before its answer
            log.debug("the page went before its answer")

    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        if self.path == "/":
            self._send(200, page(), "text/html; charset=utf-8")
        elif self.path == "/api/state":
            self._send(200, json.dumps(self.pendant.state()).encode(), "application/json")
        else:
            self._send(404, b"not found", "text/plain")

    def do_POST(self) -> None:  # noqa: N802 - http.server's name
        if not self.path.startswith("/api/"):
            self._send(404, b"not found", "text/plain")
            return
        try:
            length = int(self.headers.get("Content-Length") or 0)
            body = json.loads(self.rfile.read(length) or b"{}") if length else {}
            if not isinstance(body, dict):
                raise ValueError("a JSON object")
        except ValueError as exc:
            self._send(400, json.dumps({"id": int(ReturnCode.VALUE_ERR), "comment": f"body: {exc}"}).encode(),
                       "application/json")
            return
        reply = self.pendant.act(self.path[len("/api/"):], body)
        self._send(200, json.dumps(reply).encode(), "application/json")


def serve(pendant: Pendant, host: str, port: int) -> http.server.ThreadingHTTPServer:
    handler = type("Handler", (_Handler,), {"pendant": pendant})
    server = http.server.ThreadingHTTPServer((host, port), handler)
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, daemon=True, name="pendant-http").start()
    return server


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--arm", type=arm_id, default=DEFAULT_ARM, metavar="ID", help=f"the arm (default: {DEFAULT_ARM})")
    parser.add_argument("--host", default=DEFAULT_HOST, metavar="ADDRESS",
                        help=f"serve the page on this address (default: {DEFAULT_HOST}, this host only)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, metavar="P",
                        help=f"serve the page on this TCP port (default: {DEFAULT_PORT}); the 3D view on P + 1")
    parser.add_argument("--program", type=Path, default=None, metavar="FILE",
                        help="the program whose steps the page shows and runs (default: <arm>.program.yaml in "
                        "the working directory, if there is one)")
    parser.add_argument("--no-3d", action="store_true", help="no 3D view (it costs a WebGL page and a process thread)")
    add_client_zenoh_arguments(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    setup_logging("WARNING")
    program = args.program or (Path(f"{args.arm}.program.yaml") if Path(f"{args.arm}.program.yaml").exists() else None)
    try:
        check_port(args.host, args.port)
    except ViewError as exc:
        print(f"{parser.prog}: {exc}", file=sys.stderr)
        return USAGE_ERROR
    with listening(args, parser) as (session, stop), Arm(session, args.arm) as arm:
        view: View | None = None
        if not args.no_3d:
            try:
                view = View(session, ViewSettings((args.arm,), args.host, args.port + 1))
            except ViewError as exc:
                print(f"{parser.prog}: the 3D view: {exc}", file=sys.stderr)
                return USAGE_ERROR
        pendant = Pendant(arm, program, view.url if view is not None else "")
        server = serve(pendant, args.host, args.port)
        print(f"jara-arm pendant: http://{args.host}:{args.port}/ (arm {args.arm}; Ctrl-C to stop)", flush=True)
        try:
            while not stop.is_set():
                if view is not None:
                    view.step()
                stop.wait(0.1)
        finally:
            server.shutdown()
            server.server_close()
            if view is not None:
                view.close()
            with contextlib.suppress(ArmError):
                if pendant.run.running:
                    arm.stop()
    return 0


COMMAND = Command(
    "pendant", arguments=_arguments, run=_run,
    help="a teach pendant in the browser: jog with a dead-man, teach, run programs",
    description="Serve a web page for one arm: hold-to-jog buttons (joints; base and tool frames), jog speed "
    "and speed override, servo on/off, the e-stop, the alarms and clear, teach point, the program's steps "
    "with run, step, pause, resume and stop, and the arm in 3D. A jog moves only while a button is held: "
    f"the page renews a {LEASE_MS} ms lease every {RENEW_MS} ms; released, hidden, closed or cut off, the arm "
    "brakes.")
