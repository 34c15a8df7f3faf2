"""Which blend a corner between two queued motions gets, if any: the planner's side of blending.

``blend.py`` computes a blend's joint trajectory (Ruckig, from the cut to the
rejoin). Here the planner picks the cut and the rejoin for the blend distance
``d`` (at full radius, then at half of it) and keeps the blend only if its
control point stays within ``d`` of the corner, its joints within the soft
limits, its control point within the Cartesian soft limits, and it is clear of
collisions. Anything else keeps the exact stop at that corner: never a reason
to refuse the motion.
"""

from __future__ import annotations

import logging

import numpy as np

from jara_arm.kinematics import hg_to_se3
from jara_arm.schema.planner import MotionSettings

from .blend import UNBLENDED_OPS, Blend, BlendError, JointLimits, cut_points, joint_blend, state_at
from .checks import Checks
from .collision import PathChecker
from .frames import Frames
from .request import PlanRefused
from .sampling import BatchFk
from .trajectory import PlannedMotion

log = logging.getLogger(__name__)


class Corners:
    """Blends the corners of one robot model's motions, checked as every motion is."""

    def __init__(self, fk: BatchFk, checks: Checks, collisions: PathChecker, n: int, dt: float) -> None:
        """``n``: the arm axes; ``dt`` [s]: the servo period, the samples' spacing."""
        self._fk = fk
        self.checks = checks
        self.collisions = collisions
        self.n = n
        self.dt = dt

    def blend(self, previous: PlannedMotion, planned: PlannedMotion, s: MotionSettings) -> Blend | None:
        """The blend of the corner between ``previous`` and ``planned``, or None (exact stop) when
        there is none that passes every check."""
        d = s.blendDistance
        if previous.op in UNBLENDED_OPS or planned.op in UNBLENDED_OPS:
            return None
        if not np.allclose(previous.end, planned.start, rtol=0.0, atol=1e-12):
            return None  # not the corner this motion starts from
        tool = hg_to_se3(s.controlPointOffset)
        pts_prev = self._fk.run(previous.q[:, :self.n], tool)[0]
        pts_next = self._fk.run(planned.q[:, :self.n], tool)[0]
        corner = pts_prev[-1]
        vmax = self.checks.vmax(s)
        limits = JointLimits.from_accel_time(vmax, s.accelTimeJoint)
        lo, hi = self.checks.soft_limits(s)
        why = ""
        for radius in (d, 0.5 * d):  # a blend that bulges out of d at full radius may fit at half of it
            try:
                cut, rejoin = cut_points(pts_prev, pts_next, radius)
                if previous.blend is not None and cut <= previous.blend.rejoin:
                    cut = previous.blend.rejoin + 1  # leave after the previous corner's blend rejoined
                    if cut > len(previous.q) - 2:
                        raise BlendError("the previous motion's own blend reaches this corner")
                traj = joint_blend(state_at(previous.q, cut, self.dt), state_at(planned.q, rejoin, self.dt),
                                   limits, self.dt)
            except BlendError as exc:
                why = str(exc)
                continue
            q = traj.q
            arm = q[:, :self.n]
            deviation = float(np.max(np.linalg.norm(self._fk.run(arm, tool)[0] - corner, axis=1)))
            if deviation > d * (1.0 + 1e-9):
                why = f"it would leave the path by {deviation * 1e3:.1f} mm"
                continue
            if np.any(arm < lo) or np.any(arm > hi):
                why = "it would leave the joint soft limits"
                continue
            try:
                self.checks.path_box(s, q, Frames.of(s), "blend")
            except PlanRefused:
                why = "it would leave the Cartesian soft limits"
                continue
            contact = self.collisions.check(q)
            if contact is not None:
                why = contact.describe()
                continue
            s_rejoin = float(planned.profile.sample(self.dt).s[rejoin])
            return Blend(previous.motion, cut, rejoin, s_rejoin, traj, limits, d, deviation)
        log.info("%s: exact stop at the corner after motion %d, no blend of %.1f mm: %s", planned.op,
                 previous.motion, d * 1e3, why)
        return None


__all__ = ["Corners"]
