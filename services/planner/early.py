"""The early start's head: a LIN's or CIRC's first samples, checked, that the servo may run before acceptance.

``docs/decisions.md``, "First command and acceptance": while the planning
child plans the whole motion, the plan worker plans its head from the same
:class:`~.cartesian.CartesianMotion` (the set-up stage the whole starts from):
the first knot interval solved, the target reached from the start by IK and
clear of collisions, the samples within the joint speeds and those sent clear
of collisions. Where that is not enough to say (too short, too fast, a
contact, a target IK from the start does not reach) there is no head, and the
whole decides and says why.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .cartesian import CartesianMotion, CartesianPlanner
from .collision import PathChecker
from .sampling import Unreachable
from .trajectory import UNQUEUED, PlannedMotion, TableMap

#: The operations whose motions may start early: the LINs and CIRCs.
EARLY_OPS = frozenset({"moveLinearCartesianAbs", "moveLinearCartesianRel", "moveCircularCartesianAbs",
                       "moveCircularCartesianRel"})
#: Uniform knots solved for a LIN / CIRC's early start (the start and the next): the head's samples.
HEAD_KNOTS = 2


@dataclasses.dataclass(frozen=True, eq=False)
class Head:
    """The checked first samples of a LIN / CIRC still being planned: what the servo may run before acceptance.

    ``motion.q``: the samples that may go out (at most the early-start time's);
    ``motion.path``: the joints up to the head's end (the path's first knot interval), every sample on the
    path and within the joint speeds; those of ``motion.q`` clear of collisions too (the servo never runs a
    head past its last sample).
    The whole motion's samples start with ``motion.q`` bit for bit when its profile is ``motion.profile``
    (not slowed down): the same computation (``CartesianPlanner.samples`` on the same first profile), and
    cubic Hermite pieces are local.
    """

    motion: PlannedMotion
    #: [m] the control point's largest distance from the start up to where braking from the last sample ends
    reach: float


def head(planner: CartesianPlanner, m: CartesianMotion, collisions: PathChecker, early_start: float) -> Head | None:
    """The :class:`Head` of ``m`` with up to ``early_start`` [s] of samples, or None (module docstring)."""
    dt, n = planner.dt, planner.n
    s = m.s  # the first profile's: the whole's too unless it is slowed down
    try:
        joints = planner.path_joints(m, HEAD_KNOTS)
        # Refusals for the target itself come before any motion: unreachable, in contact.
        end = m.start.copy()
        end[:n] = joints.end_from_start()
        if collisions.check(end[None, :]) is not None:
            return None
        k = int(np.searchsorted(s, joints.spline.s[-1], side="right"))  # samples on the solved knots
        early = min(k - 1, int(round(early_start / dt)) + 1)
        if early < 2:
            return None
        # Every sample up to the last knot solved, not only those sent: a sample off the path splits its
        # knot interval at the sample nearest its middle, and the whole must split it where the head did.
        q = planner.samples(m, joints, s[:k])
    except Unreachable:
        return None
    if (np.abs(np.diff(q[:, :n], axis=0)) / dt > m.vmax).any():
        return None  # the whole plan decides and says why
    while early >= 2 and m.profile.stop_at((early - 1) * dt).s_end > s[k - 1]:
        early //= 2  # braking from the last early sample must end on the head
    # Collisions on the samples sent only: the servo never runs a head past its last sample (it slows
    # the head down instead, and a refusal stops it on them); the whole checks the rest.
    if early < 2 or collisions.check(q[:early]) is not None:
        return None
    stop = m.profile.stop_at((early - 1) * dt).s_end
    points = m.path.positions(np.append(s[:k][s[:k] < stop], stop))
    reach = float(np.max(np.linalg.norm(points - points[0], axis=1)))
    return Head(PlannedMotion(UNQUEUED, m.req.op, TableMap.build(s[:k], q), m.profile, q[:early].copy(), dt), reach)


__all__ = ["EARLY_OPS", "HEAD_KNOTS", "Head", "head"]
