"""The planning process: :class:`MotionPlanner` runs in a child process of its own.

Planning a LIN or CIRC solves IK at every servo period and holds the CPU for
a good fraction of a second. In the service's process that computation would
hold the GIL, and the control queries (pause, stop) and the early start's head
would wait behind it. In a child process it only competes for a CPU.

The child is started with ``spawn`` (the parent has Zenoh threads), receives
``(PlanRequest, start joints, previous motion or None)`` on a pipe (the
request decoded already by the plan worker, ``request.py``: the child decodes
nothing) and sends back the :class:`PlannedMotion` (pickled; its Ruckig
profile is rebuilt on arrival) or the refusal. It exits when the pipe closes, so it never outlives the service.

An accepted motion's preview (the viewers' polyline) follows as a second
message: the parent queues the motion first (its first command goes out) and
then reads the preview for ``Planner/path``.
"""

from __future__ import annotations

import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import threading
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from jara_arm.robots import Obstacle, RobotModel
from jara_arm.schema.codes import ReturnCode
from jara_arm.services.runtime.logs import setup_stderr

from .collision import DEFAULT_MARGIN
from .planning import MotionPlanner
from .request import PlanRefused, PlanRequest
from .trajectory import Joints, PlannedMotion

log = logging.getLogger(__name__)

_START_TIMEOUT = 60.0  # [s] for the child to import its libraries and build the kinematics


def _serve(conn: multiprocessing.connection.Connection, model: RobotModel, log_level: str,
           obstacles: tuple[Obstacle, ...], margin: float) -> None:
    """The child's loop: one request in, one answer out, until the pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the service's to handle; EOF ends us
    try:  # a restart from a real-time thread would pass its priority on: planning is no real-time work
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass
    setup_stderr(log_level)
    planner = MotionPlanner(model, obstacles=obstacles, collision_margin=margin)
    conn.send(("ready",))
    while True:
        try:
            req, start, previous = conn.recv()
        except (EOFError, OSError):
            return
        motion = None
        try:
            motion = planner.plan(req, start, previous, preview=False)
            answer: tuple = ("ok", motion)
        except PlanRefused as exc:
            answer = ("refused", int(exc.code), exc.comment)
        except Exception as exc:  # a planner bug: refuse this motion, keep serving
            log.exception("planning %s failed", req.op)
            answer = ("refused", int(ReturnCode.NG), f"internal error while planning {req.op}: {exc}")
        conn.send(answer)
        if motion is not None:  # after the answer: the parent queues the motion meanwhile
            try:
                preview = planner.preview(motion.q, req.settings)
            except Exception:  # a viewer's polyline: never worth a motion
                log.exception("the preview of %s failed", req.op)
                preview = np.zeros((0, 3))
            conn.send(("preview", preview))


class PlanningProcess:
    """A child process that plans motions for ``model`` among ``obstacles`` (the world's boxes: the model's own
    and the ``--obstacle`` ones) with ``collision_margin`` [m]; :meth:`plan` is its only call."""

    def __init__(self, model: RobotModel, log_level: str = "INFO", obstacles: Sequence[Obstacle] = (),
                 collision_margin: float = DEFAULT_MARGIN) -> None:
        self.model = model
        self._log_level = log_level
        self._world = (tuple(obstacles), collision_margin)
        self._ctx = multiprocessing.get_context("spawn")
        self._lock = threading.Lock()  # one request at a time on the pipe
        self._spawn()

    def _spawn(self) -> None:
        self._preview_pending = False  # the child sends an accepted motion's preview after it
        self._conn, child = self._ctx.Pipe()
        self._proc = self._ctx.Process(target=_serve, args=(child, self.model, self._log_level, *self._world),
                                       name="jara-arm-planning", daemon=True)
        self._proc.start()
        child.close()
        self._started = False

    def wait_started(self) -> None:
        """Until the child can plan (it imports its libraries and builds its kinematics meanwhile: the caller's
        own start overlaps it); RuntimeError if it does not within a minute."""
        if self._started:
            return
        if not self._conn.poll(_START_TIMEOUT):
            raise RuntimeError(f"the planning process did not start within {_START_TIMEOUT:.0f} s")
        self._conn.recv()
        self._started = True

    def plan(self, req: PlanRequest, start: Joints, previous: PlannedMotion | None = None,
             meanwhile: Callable[[], None] | None = None) -> PlannedMotion:
        """The planned motion (``previous``: ``MotionPlanner.plan``'s), its ``preview`` empty (:meth:`preview`
        has it); raises PlanRefused (also if the child died: it is restarted). ``meanwhile`` runs in this
        thread while the child plans (the early start: the motion's head)."""
        with self._lock:
            try:
                self.wait_started()
                self._take_preview()  # a preview nobody asked for (the motion was not queued)
                self._conn.send((req, start, previous))
                if meanwhile is not None:
                    try:
                        meanwhile()
                    except Exception:  # the motion then starts once planned
                        log.exception("while %s was planned", req.op)
                answer = self._conn.recv()
                self._preview_pending = answer[0] == "ok"
            except (EOFError, OSError, BrokenPipeError):
                log.error("the planning process died (exit code %s); restarting it", self._proc.exitcode)
                self._proc.join(timeout=1.0)
                self._spawn()  # the next plan() waits for it
                raise PlanRefused(ReturnCode.NG, f"internal error: the planning process died while "
                                  f"planning {req.op}") from None
        if answer[0] == "ok":
            return answer[1]
        raise PlanRefused(ReturnCode(answer[1]), answer[2])

    def preview(self) -> NDArray[np.float64]:
        """(K, 3) [m] the control point polyline of the motion :meth:`plan` returned last (``PlannedMotion.preview``);
        empty if there is none or the child died (the next :meth:`plan` restarts it)."""
        with self._lock:
            try:
                return self._take_preview()
            except (EOFError, OSError):
                return np.zeros((0, 3))

    def _take_preview(self) -> NDArray[np.float64]:
        """The pending preview off the pipe (lock held)."""
        if not self._preview_pending:
            return np.zeros((0, 3))
        self._preview_pending = False
        kind, preview = self._conn.recv()
        assert kind == "preview", kind
        points: NDArray[np.float64] = preview
        return points

    def close(self) -> None:
        self._conn.close()
        self._proc.join(timeout=2.0)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=2.0)
