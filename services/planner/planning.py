"""Turn one :class:`~.request.PlanRequest` and its start joints into a sampled joint trajectory.

Every geometric check of DECISIONS.md "Motion commands" happens before a
motion is accepted; a refusal raises :class:`~.request.PlanRefused` with the
return code and a comment saying why, and nothing is queued.

:meth:`MotionPlanner.plan` runs the stages in order, one module each:

1. the start joints and the settings against the model (``checks.py``);
2. the motion's own first stage, by its IDL operation: a PTP, goHome or
   gripper motion is planned whole there (``ptp.py``); a LIN / CIRC is set up
   (``cartesian.py``: its targets in their frames, ``frames.py``, posture,
   ``postures.py``, arm angle, ``elbow.py``, first profile, Cartesian soft
   limits along the path);
3. a LIN / CIRC's joints along the whole path (``cartesian.py``);
4. contacts of the arm's links with the world's boxes and with each other, on
   every sample (``collision.py``): a contact refuses with VALUE_ERR, naming
   the two bodies and where on the path;
5. the blend of the corner with the previous motion, if asked for
   (``corners.py``, ``blend.py``);
6. the viewers' polyline (``preview``).

:meth:`MotionPlanner.head` (the early start) runs stages 1 and 2 of the same
code and then, instead of stage 3, plans the LIN / CIRC's head (``early.py``).
All motions are timed by one profile along one path (``profile.py``); what
each family ignores of a pose is in ``families.py``.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator, Sequence

import numpy as np
from numpy.typing import NDArray

from jara_arm.kinematics import Kinematics, KinematicsError, hg_to_se3
from jara_arm.kinematics.posture import Postures
from jara_arm.robots import Obstacle, RobotModel
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.planner import MotionSettings
from jara_arm.schema.types import CarPosWithElbow, JointPos
from jara_arm.services.runtime.timing import EARLY_START

from . import early
from .cartesian import CartesianMotion, CartesianPlanner
from .checks import Checks
from .collision import DEFAULT_MARGIN, PathChecker
from .corners import Corners
from .early import EARLY_OPS, Head
from .paths import PathGeometryError
from .postures import PostureRule
from .profile import ProfileError
from .ptp import JointMotions
from .request import PlanRefused, PlanRequest
from .sampling import BatchFk
from .trajectory import Joints, PlannedMotion

#: Points of a motion's control point polyline for viewers (``PlannedMotion.preview``, ``Planner/path``).
PREVIEW_POINTS = 200

#: A motion's first stage (2 in the module docstring): planned whole, or a LIN / CIRC set up.
Staged = PlannedMotion | CartesianMotion


@contextlib.contextmanager
def _refusals(op: str) -> Iterator[None]:
    """The errors a request's values lead to in the stages, as the refusals they are (VALUE_ERR)."""
    try:
        yield
    except WireError as exc:
        raise PlanRefused(ReturnCode.VALUE_ERR, str(exc)) from None
    except (PathGeometryError, ProfileError, KinematicsError) as exc:
        raise PlanRefused(ReturnCode.VALUE_ERR, f"{op}: {exc}") from None


class MotionPlanner:
    """Plans motions for one robot model. Not thread-safe: one instance per planning thread."""

    def __init__(self, model: RobotModel, kinematics: Kinematics | None = None, *,
                 obstacles: Sequence[Obstacle] = (), collision_margin: float = DEFAULT_MARGIN,
                 early_start: float = EARLY_START) -> None:
        """``obstacles``: the world's boxes (the model's own and the ``--obstacle`` ones, in the world frame);
        ``collision_margin`` [m]: the clearance every link keeps from them (``collision.py``);
        ``early_start`` [s]: how much of a LIN / CIRC its head may run before acceptance (:meth:`head`)."""
        self.model = model
        self.early_start = early_start
        self.kin = kinematics or Kinematics(model)
        self.postures = Postures(self.kin) if model.posture_joints is not None else None
        self.collisions = PathChecker(model, obstacles, collision_margin)
        self.n = model.axis_num
        self.dt = model.cmd_cycle
        self._fk = BatchFk(self.kin)
        self.checks = Checks(model, self.kin, self._fk)
        posture = PostureRule(model, self.postures)
        self.joint_space = JointMotions(model, self.kin, self.checks, posture)
        self.cartesian = CartesianPlanner(model, self.kin, self._fk, self.checks, posture)
        self.corners = Corners(self._fk, self.checks, self.collisions, self.n, self.dt)

    # ------------------------------------------------------------------ entry

    def plan(self, req: PlanRequest, start: Joints, previous: PlannedMotion | None = None, *,
             preview: bool = True) -> PlannedMotion:
        """The motion ``req`` from ``start`` (wire joints); raises PlanRefused.

        ``previous``: the queued motion that ends at ``start``, if any: with ``blendDistance`` > 0 the
        motion also carries a blend of that corner (``corners.py``) when one passes every check.
        ``preview``: fill in ``PlannedMotion.preview``; the planning process leaves it out and sends it after
        the motion (a viewer's polyline is no part of the acceptance: it stays off the first command's path).
        """
        with _refusals(req.op):
            staged = self._stage(req, start)
            planned = staged if isinstance(staged, PlannedMotion) else self.cartesian.whole(staged)
            contact = self.collisions.check(planned.q)  # every motion passes here, before it is accepted
            if contact is not None:
                raise PlanRefused(ReturnCode.VALUE_ERR, f"{req.op}: {contact.describe()}")
            if previous is not None and req.settings.blendDistance > 0.0:
                planned = dataclasses.replace(planned, blend=self.corners.blend(previous, planned, req.settings))
            return dataclasses.replace(planned, preview=self.preview(planned.q, req.settings)) if preview else planned

    def head(self, req: PlanRequest, start: Joints) -> Head | None:
        """A LIN / CIRC's :class:`~.early.Head` from ``start``: the stages of :meth:`plan` up to its set-up,
        then its first knot interval planned and checked, the rest not (the early start: ``docs/decisions.md``,
        "First command and acceptance"). None for other motions, with ``early_start`` 0, and wherever the head
        alone cannot tell (a refusal, a joint too fast, a contact): :meth:`plan` of the whole then decides and
        says why."""
        if req.op not in EARLY_OPS or self.early_start <= 0.0:
            return None
        try:
            with _refusals(req.op):
                staged = self._stage(req, start)
                if isinstance(staged, PlannedMotion):
                    return None  # the target is the start: nothing to start early
                return early.head(self.cartesian, staged, self.collisions, self.early_start)
        except PlanRefused:
            return None

    def preview(self, q: Joints, settings: MotionSettings) -> NDArray[np.float64]:
        """(K, 3) [m] the control point at up to ``PREVIEW_POINTS`` of the samples ``q``, evenly
        spread, the first and the last included, in the arm frame (a polyline for viewers)."""
        rows = np.unique(np.linspace(0, len(q) - 1, min(len(q), PREVIEW_POINTS)).round().astype(int))
        points: NDArray[np.float64] = self._fk.run(q[rows, :self.n], hg_to_se3(settings.controlPointOffset))[0]
        return points

    def _stage(self, req: PlanRequest, start: Joints) -> Staged:
        """Stages 1 and 2 (module docstring): the checks, then the method named after the IDL operation."""
        start = np.array(start, dtype=float)
        if start.shape != (self.model.dof,):
            raise PlanRefused(ReturnCode.STATUS_ERR, f"start joints have {start.size} axes, "
                              f"the robot {self.model.dof}")
        self.checks.settings(req.settings)
        motion: Callable[..., Staged] = getattr(self, req.op)  # one method per IDL motion
        return motion(req, start, **req.args)

    # ------------------------------------------------------------------ the IDL motions, by name

    def movePTPJointAbs(self, req: PlanRequest, start: Joints, jointPoints: JointPos) -> Staged:
        return self.joint_space.joint(req, start, self.checks.joint_arg(jointPoints))

    def movePTPJointRel(self, req: PlanRequest, start: Joints, jointPoints: JointPos) -> Staged:
        return self.joint_space.joint(req, start, start[:self.n] + self.checks.joint_arg(jointPoints))

    def goHome(self, req: PlanRequest, start: Joints) -> Staged:
        return self.joint_space.joint(req, start, np.array(req.settings.home, dtype=float), "home")

    def movePTPCartesianAbs(self, req: PlanRequest, start: Joints, carPoint: CarPosWithElbow) -> Staged:
        return self.joint_space.cartesian(req, start, carPoint, relative=False)

    def movePTPCartesianRel(self, req: PlanRequest, start: Joints, carPoint: CarPosWithElbow) -> Staged:
        return self.joint_space.cartesian(req, start, carPoint, relative=True)

    def moveLinearCartesianAbs(self, req: PlanRequest, start: Joints, carPoint: CarPosWithElbow) -> Staged:
        return self.cartesian.linear(req, start, carPoint, relative=False)

    def moveLinearCartesianRel(self, req: PlanRequest, start: Joints, carPoint: CarPosWithElbow) -> Staged:
        return self.cartesian.linear(req, start, carPoint, relative=True)

    def moveCircularCartesianAbs(self, req: PlanRequest, start: Joints, carPointR: CarPosWithElbow,
                                 carPointT: CarPosWithElbow) -> Staged:
        return self.cartesian.circular(req, start, carPointR, carPointT, relative=False)

    def moveCircularCartesianRel(self, req: PlanRequest, start: Joints, carPointR: CarPosWithElbow,
                                 carPointT: CarPosWithElbow) -> Staged:
        return self.cartesian.circular(req, start, carPointR, carPointT, relative=True)

    def moveGripper(self, req: PlanRequest, start: Joints, angleRatio: int) -> Staged:
        return self.joint_space.gripper(req, start, angleRatio)

    def openGripper(self, req: PlanRequest, start: Joints) -> Staged:
        return self.joint_space.gripper(req, start, 100)

    def closeGripper(self, req: PlanRequest, start: Joints) -> Staged:
        return self.joint_space.gripper(req, start, 0)


__all__ = ["MotionPlanner", "PREVIEW_POINTS"]
