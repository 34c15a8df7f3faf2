"""Collision-checked acceptance: a motion's sampled joint path against the world's boxes and the arm itself.

One :class:`PathChecker` per planning process, built once from the robot's
URDF collision geometry (Pinocchio + coal):

* Bodies: every ``<collision>`` of the URDF, on the full Pinocchio model
  (the gripper's fingers move with the gripper axis); meshes are replaced by
  their convex hulls (GJK distances in microseconds; a hull is never smaller
  than its link). The world's boxes are ``coal.Box`` objects on the universe,
  placed in the arm frame (the arm frame sits at ``RobotModel.base_position``
  in the world frame, unrotated, as the servo loads it).
* Pairs: every link with every box, and every two links except
  (docs/decisions.md "Collision-checked acceptance"): links of one joint
  (Pinocchio never pairs them), adjacent links (a joint's link and its parent
  joint's: they touch at the joint by construction), two gripper fingers (they
  close on each other by design), and pairs in contact in every one of
  ``EXCLUSION_SAMPLES`` random configurations (meshes that overlap for good;
  none in the robots of ``robots/`` today, the rule is for a new URDF).
* Margins: a link must stay ``margin`` [m] away from every box; two links
  must not touch (no margin: links built to pass close to each other, the
  gripper's fingers or a gantry's carriages, would be refused everywhere).

Along the path (conservative advancement): at a checked sample every pair's
clearance ``c`` (distance minus its margin) is known. A pair's distance
changes only through the joints that carry one of its bodies and not the
other, by at most the sum of their travels x their reach (the farthest point
of the body from the joint: an upper bound from the URDF's joint offsets and
the body's bounding sphere). The next check is the last sample at which no
pair can have used up its clearance, at least the next sample. Every
clearance between two checks thus stays >= 0 (the margin kept) down to the
servo's sampling: a path is accepted only if it holds at every sample the
servo gets. A PTP or a 0.5 m LIN needs a few dozen distance computations.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import coal
import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from jara_arm.robots import Obstacle, RobotModel

#: Default clearance between a link and a box of the world [m].
DEFAULT_MARGIN = 0.01
#: Random configurations in which a pair of links must be in contact to be excluded as "always in contact".
EXCLUSION_SAMPLES = 200

Joints = NDArray[np.float64]


@dataclasses.dataclass(frozen=True)
class Contact:
    """The first sample of a path at which two bodies come closer than allowed."""

    first: str  # a link (the URDF link's name)
    second: str  # a link, or a box of the world
    sample: int  # index of the sample on the path
    samples: int  # samples of the path
    distance: float  # [m] between the two bodies, <= 0 in contact
    margin: float  # [m] required between them

    @property
    def percent(self) -> float:
        """Where on the path [%] of its samples (0 the start, 100 the target)."""
        return 100.0 * self.sample / max(1, self.samples - 1)

    def describe(self) -> str:
        where = f"at {self.percent:.0f} % of the path"
        if self.distance <= 0.0:
            return f"{self.first} and {self.second} collide {where}"
        return (f"{self.first} and {self.second} come {self.distance * 1e3:.1f} mm close {where} "
                f"(collision margin {self.margin * 1e3:.0f} mm)")


@dataclasses.dataclass(frozen=True)
class ExcludedPair:
    """A pair of links never checked, and why."""

    first: str
    second: str
    reason: str


def box_name(index: int, box: Obstacle) -> str:
    """How a comment names the world's box ``index`` (0-based: the model's boxes, then ``--obstacle``)."""
    return f"obstacle {index + 1} (box at {', '.join(f'{v:g}' for v in box.position)} m)"


def _prismatic(joint: pin.JointModel) -> bool:
    """A prismatic joint (``JointModelPX`` .. ``PZ``, ``JointModelPrismaticUnaligned``)."""
    return bool(joint.shortname().startswith("JointModelP"))


class PathChecker:
    """Checks sampled joint paths (wire joints, ``(N, dof)``) of ``robot`` among ``obstacles``.

    Not thread-safe (one Pinocchio work area): one instance per planning thread.
    """

    def __init__(self, robot: RobotModel, obstacles: Sequence[Obstacle] = (), margin: float = DEFAULT_MARGIN,
                 *, seed: int = 0) -> None:
        if not margin >= 0.0:
            raise ValueError(f"collision margin must be >= 0 m, got {margin}")
        self.robot = robot
        self.margin = margin
        self.obstacles = tuple(obstacles)
        model, geom = pin.buildModelsFromUrdf(str(robot.urdf), package_dirs=[str(robot.urdf.parent)],
                                              geometry_types=[pin.GeometryType.COLLISION])[:2]
        for g in geom.geometryObjects:
            if isinstance(g.geometry, coal.BVHModelBase):
                g.geometry.buildConvexHull(True, "Qt")
                g.geometry = g.geometry.convex
        self._model = model
        self._columns, self._wire_columns, self._q_lock = self._coordinates(model, robot)
        links = geom.ngeoms
        geom.addAllCollisionPairs()  # every two links on different joints
        self._data = model.createData()
        self.excluded = self._exclude(model, geom, robot, seed)
        base = np.array(robot.base_position, dtype=float)
        for i, box in enumerate(self.obstacles):
            shape = coal.Box(*(2.0 * h for h in box.half_extents))
            placement = pin.SE3(np.eye(3), np.array(box.position, dtype=float) - base)
            b = geom.addGeometryObject(pin.GeometryObject(box_name(i, box), 0, 0, placement, shape))
            for g in range(links):
                if geom.geometryObjects[g].parentJoint != 0:  # the base does not move: not its pairs
                    geom.addCollisionPair(pin.CollisionPair(g, b))
        self._geom = geom
        self._gdata = pin.GeometryData(geom)
        self._names = [self._body(model, geom, i) for i in range(geom.ngeoms)]
        self._pair_margin = np.array([margin if p.second >= links else 0.0 for p in geom.collisionPairs])
        self._reach = self._reaches(model, geom)

    # ------------------------------------------------------------------ set-up

    @staticmethod
    def _coordinates(model: pin.Model, robot: RobotModel) -> tuple[NDArray[np.intp], NDArray[np.intp], Joints]:
        """Pinocchio coordinates driven by the wire axes, the wire column of each, and the other coordinates'
        values (non-arm joints as ``Kinematics`` locks them: 0, clamped into their limits)."""
        q_lock = pin.neutral(model)
        columns, wire = [], []
        for k, name in enumerate(robot.arm_joints + robot.gripper_joints):
            j = model.joints[model.getJointId(name)]
            columns.append(j.idx_q)
            wire.append(min(k, robot.axis_num))  # every gripper joint follows the one gripper axis
        for jid in range(1, model.njoints):
            j = model.joints[jid]
            if j.nq == 1 and j.idx_q not in columns:
                lo, hi = model.lowerPositionLimit[j.idx_q], model.upperPositionLimit[j.idx_q]
                q_lock[j.idx_q] = min(max(0.0, lo), hi) if lo <= hi else 0.0
        return np.array(columns), np.array(wire), q_lock

    def full(self, q: Joints) -> Joints:
        """Wire joints ``(N, dof)`` -> Pinocchio configurations ``(N, nq)`` of the full model."""
        out = np.repeat(self._q_lock[None, :], len(q), axis=0)
        out[:, self._columns] = q[:, self._wire_columns]
        return out

    @staticmethod
    def _body(model: pin.Model, geom: pin.GeometryModel, i: int) -> str:
        g = geom.geometryObjects[i]
        return g.name if g.parentJoint == 0 and g.parentFrame == 0 else model.frames[g.parentFrame].name

    def _exclude(self, model: pin.Model, geom: pin.GeometryModel, robot: RobotModel,
                 seed: int) -> tuple[ExcludedPair, ...]:
        """Remove the link pairs never checked (module docstring) from ``geom``; what was removed, and why."""
        gripper = {model.getJointId(n) for n in robot.gripper_joints}
        rng = np.random.default_rng(seed)
        lo = np.array([lim.lower for lim in robot.hard_limits] + ([robot.gripper_limits.lower]
                                                                   if robot.gripper_limits else []))
        hi = np.array([lim.upper for lim in robot.hard_limits] + ([robot.gripper_limits.upper]
                                                                   if robot.gripper_limits else []))
        qs = self.full(lo + (hi - lo) * rng.random((EXCLUSION_SAMPLES, len(lo))))
        data = pin.GeometryData(geom)
        always = np.ones(len(geom.collisionPairs), dtype=bool)
        for q in qs:
            pin.computeDistances(model, self._data, geom, data, q)
            always &= np.array([r.min_distance <= 0.0 for r in data.distanceResults])
        out = []
        for p, pair in reversed(list(enumerate(geom.collisionPairs))):
            ja, jb = geom.geometryObjects[pair.first].parentJoint, geom.geometryObjects[pair.second].parentJoint
            if model.parents[ja] == jb or model.parents[jb] == ja:
                reason = "adjacent links"
            elif ja in gripper and jb in gripper:
                reason = "gripper fingers"
            elif always[p]:
                reason = f"in contact in all of {EXCLUSION_SAMPLES} random configurations"
            else:
                continue
            out.append(ExcludedPair(self._body(model, geom, pair.first), self._body(model, geom, pair.second),
                                    reason))
            geom.removeCollisionPair(pair)
        return tuple(reversed(out))

    def _reaches(self, model: pin.Model, geom: pin.GeometryModel) -> Joints:
        """``(driven coordinates, pairs)``: how much [m] a pair's distance changes per unit of each coordinate's
        travel, at most.

        A pair's distance depends only on the joints that carry one of its bodies and not the other (the
        joints carrying both move them as one). Such a joint moves a point of a body it carries by at most: its
        travel (prismatic), or its travel [rad] x the point's distance from the joint's origin (revolute),
        bounded by the joint offsets along the chain (a prismatic joint on it at its longest) plus the body's
        bounding sphere about its own joint.
        """
        joints = [next(j for j in range(1, model.njoints) if model.joints[j].idx_q == c) for c in self._columns]
        reach = np.zeros((len(joints), geom.ngeoms))  # (coordinate, body)
        for g, obj in enumerate(geom.geometryObjects):
            chain = list(model.supports[obj.parentJoint])
            obj.geometry.computeLocalAABB()
            centre = obj.placement.translation + obj.placement.rotation @ obj.geometry.aabb_center
            radius = float(np.linalg.norm(centre)) + float(obj.geometry.aabb_radius)
            for c, jid in enumerate(joints):
                if jid not in chain or obj.parentJoint == 0:
                    continue
                if _prismatic(model.joints[jid]):
                    reach[c, g] = 1.0
                    continue
                length = radius
                for k in chain[chain.index(jid) + 1:]:
                    length += float(np.linalg.norm(model.jointPlacements[k].translation))
                    if _prismatic(model.joints[k]):
                        i = model.joints[k].idx_q
                        length += max(abs(model.lowerPositionLimit[i]), abs(model.upperPositionLimit[i]))
                reach[c, g] = length
        out = np.zeros((len(joints), len(geom.collisionPairs)))
        for p, pair in enumerate(geom.collisionPairs):
            a, b = reach[:, pair.first], reach[:, pair.second]
            own = (a > 0.0) != (b > 0.0)  # carries one body, not the other
            out[:, p] = np.where(own, a + b, 0.0)
        return out

    # ------------------------------------------------------------------ checks

    def clearances(self, q_full: Joints) -> NDArray[np.float64]:
        """Per checked pair: distance minus the pair's margin [m] at one full configuration."""
        pin.computeDistances(self._model, self._data, self._geom, self._gdata, q_full)
        d = np.fromiter((r.min_distance for r in self._gdata.distanceResults), float, len(self._pair_margin))
        return d - self._pair_margin

    def _contact(self, c: NDArray[np.float64], sample: int, samples: int) -> Contact:
        p = int(np.argmin(c))
        pair = self._geom.collisionPairs[p]
        margin = float(self._pair_margin[p])
        return Contact(self._names[pair.first], self._names[pair.second], sample, samples,
                       float(c[p] + margin), margin)

    def check(self, q: Joints) -> Contact | None:
        """The first sample of the wire joint path ``q`` ``(N, dof)`` where two bodies come too close; None if
        the whole path keeps clear (module docstring: which samples are computed)."""
        full = self.full(np.atleast_2d(q))
        n = len(full)
        travel = np.cumsum(np.abs(np.diff(full[:, self._columns], axis=0)), axis=0)
        # (N, pairs) [m]: how much each pair's distance may have changed since the start, at most
        swept = np.vstack((np.zeros((1, self._reach.shape[1])), travel @ self._reach)).T.copy()
        i = 0
        while True:
            c = self.clearances(full[i])
            if np.any((c < 0.0) | ((c == 0.0) & (self._pair_margin == 0.0))):  # touching links collide
                return self._contact(c, i, n)
            if i == n - 1:
                return None
            # the last sample at which no pair can have used up its clearance
            nxt = min((int(np.searchsorted(col, col[i] + ci, side="right")) for col, ci in zip(swept, c)),
                      default=n) - 1
            i = min(max(nxt, i + 1), n - 1)

    @property
    def pairs(self) -> tuple[tuple[str, str], ...]:
        """The checked pairs, by body name."""
        return tuple((self._names[p.first], self._names[p.second]) for p in self._geom.collisionPairs)
