"""Joints along a Cartesian path (LIN, CIRC) at every servo sample, from IK at a few knots.

Solving IK at every 1 ms sample costs a few hundred milliseconds per motion.
Here IK runs only at *knots* of the path parameter ``s``; between knots the
joints follow a cubic Hermite spline in ``s`` whose tangents ``dq/ds`` come from
the task Jacobian; every sample the servo will get is then checked by forward
kinematics, and where one is off the path, the knot interval around it is split
(adaptive refinement) until none is.

* **In ``s``, not in time.** The joint path ``q(s)`` depends on the geometry
  only; the jerk-limited profile ``s(t)`` has jumps in its jerk that a spline
  in time would have to straddle. A slowed-down profile (joint speed limits)
  reuses the knots: only the check of the new samples remains.
* **Knots.** IK (``Kinematics.ik``, same tolerances, mask, arm angle and joint
  limits as a per-sample solve) warm-started from a second-order prediction.
  Tangent: the task rows IK zeroes (masked position and rotation-vector rows,
  the arm angle row of a 7-axis arm) are kept at zero along ``s``:
  ``J_task(q) · dq/ds = de/ds`` (least squares if not square), ``de/ds`` by finite differences
  of the target at fixed ``q``.
* **Check.** Batched forward kinematics (:class:`BatchFk`, numpy over all
  samples at once; agrees with Pinocchio to rounding) of every sample: the
  constrained position error, the constrained rotation-vector error, the arm
  angle error and the joint limits. A bad sample splits its knot interval at
  the interior sample nearest the interval's middle; that sample becomes a
  knot, solved by IK. So refinement always ends -- at worst every sample is a
  knot, which is the per-sample solve -- and every returned sample is within
  the sample tolerances.

Joint values are the arm axes J1..Jn [rad or m]; poses are in the arm base
frame unless said otherwise: a single pose (the tool, a knot's IK target) is a
``pin.SE3``, the targets along the path stay an (N, 4, 4) array for speed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from jara_arm.kinematics import Kinematics, Mask

Array = NDArray[np.float64]

#: Step of the finite differences of the target along s [fraction of the path].
_DS = 1e-4
#: Above this rotation angle [rad] the batched log3 hands over to Pinocchio's (axis near pi).
_LOG3_NEAR_PI = 3.0


class Unreachable(Exception):
    """No IK solution within the joint limits at path parameter ``s`` (arm frame ``position``)."""

    def __init__(self, s: float, position: Array) -> None:
        super().__init__(f"unreachable at s = {s}")
        self.s = s
        self.position = position


# ----------------------------------------------------------------------------- batched FK


def _skew(a: Array) -> Array:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _rmul(R: Array, M: Array) -> Array:
    """R @ M for a stack R (N, 3, 3) and one M (3, 3): a single (3N x 3) product."""
    n = R.shape[0]
    return (np.ascontiguousarray(R).reshape(3 * n, 3) @ M).reshape(n, 3, 3)


def _rvec(R: Array, v: Array) -> Array:
    """R @ v for a stack R (N, 3, 3) and one v (3,)."""
    n = R.shape[0]
    return (np.ascontiguousarray(R).reshape(3 * n, 3) @ v).reshape(n, 3)


class BatchFk:
    """Forward kinematics of many configurations at once (numpy), for one :class:`Kinematics`.

    Walks the reduced Pinocchio model's joints (1-DoF revolute or prismatic,
    axis-aligned or not): ``oMi = oMi[parent] · placement · motion(q)``.
    """

    def __init__(self, kin: Kinematics) -> None:
        m = kin.pin_model
        self._kin = kin
        robot = kin.robot
        col = {name: i for i, name in enumerate(robot.arm_joints)}
        self._joints: list[tuple[int, int, Array, Array, Array, Array, Array, bool, int]] = []
        for jid in range(1, m.njoints):
            jm = m.joints[jid]
            kind = jm.shortname()
            if kind.startswith("JointModelR"):
                prismatic = False
            elif kind.startswith("JointModelP"):
                prismatic = True
            else:  # pragma: no cover - Kinematics accepts 1-DoF revolute / prismatic arm joints only
                raise ValueError(f"BatchFk: unsupported joint {kind}")
            aligned = kind[-1] in "XYZ" and not kind.endswith("Unaligned")
            if aligned:
                axis = np.eye(3)["XYZ".index(kind[-1])]
            else:
                axis = np.asarray(jm.extract().axis, dtype=float).reshape(3)
            pl = m.jointPlacements[jid]
            K = _skew(axis)
            A = pl.rotation.copy()  # rotation of placement · motion(x): A + sin x · B + (1 - cos x) · C
            k = "XYZ".index(kind[-1]) if aligned else -1  # about a frame axis: two columns turn
            self._joints.append((int(m.parents[jid]), col[m.names[jid]], A, A @ K, A @ K @ K,
                                 pl.translation.copy(), A @ axis, prismatic, k))
        if m.existFrame(robot.flange_frame, pin.FrameType.BODY):
            fid = m.getFrameId(robot.flange_frame, pin.FrameType.BODY)
        else:
            fid = m.getFrameId(robot.flange_frame)
        self._flange = m.frames[fid].placement.copy()
        self._flange_joint = int(m.frames[fid].parentJoint)
        self._elbow = kin.elbow_joint_ids  # joint ids of shoulder, elbow, wrist (7 axes), else None

    def run(self, q: Array, tool: pin.SE3 | None) -> tuple[Array, Array, Array | None]:
        """Control point positions (N, 3), rotations (N, 3, 3) and S, E, W points (3, N, 3) or None."""
        n = len(q)
        Rs: dict[int, Array] = {0: np.broadcast_to(np.eye(3), (n, 3, 3))}
        ps: dict[int, Array] = {0: np.zeros((n, 3))}
        for jid, (parent, c, A, B, C, t, a, prismatic, k) in enumerate(self._joints, start=1):
            R0, p0 = Rs[parent], ps[parent]
            x = q[:, c]
            if prismatic:  # R0 @ (t + x·A a)
                Rs[jid] = _rmul(R0, A)
                ps[jid] = p0 + _rvec(R0, t) + _rvec(R0, a) * x[:, None]
            elif k >= 0:  # R0 · A · rot_k(x): columns i, j of R0 · A turn by x
                R = _rmul(R0, A)
                i, j = (k + 1) % 3, (k + 2) % 3
                cx, sx = np.cos(x)[:, None], np.sin(x)[:, None]
                ci, cj = R[:, :, i].copy(), R[:, :, j]
                R[:, :, i] = cx * ci + sx * cj
                R[:, :, j] = cx * cj - sx * ci
                Rs[jid] = R
                ps[jid] = p0 + _rvec(R0, t)
            else:
                Rs[jid] = (_rmul(R0, A) + np.sin(x)[:, None, None] * _rmul(R0, B)
                           + (1.0 - np.cos(x))[:, None, None] * _rmul(R0, C))
                ps[jid] = p0 + _rvec(R0, t)
        frame = self._flange if tool is None else self._flange * tool
        R0, p0 = Rs[self._flange_joint], ps[self._flange_joint]
        pts = p0 + _rvec(R0, frame.translation)
        rot = _rmul(R0, frame.rotation)
        sew = None if self._elbow is None else np.stack([ps[j] for j in self._elbow])
        return pts, rot, sew


def batch_log3(Ra: Array, Rb: Array) -> Array:
    """Rotation vectors (N, 3) of ``Ra · Rbᵀ`` for rotations (N, 3, 3); accurate for small angles."""
    def e(i: int, j: int) -> Array:  # (Ra Rb^T)_ij
        return np.einsum("nk,nk->n", Ra[:, i], Rb[:, j])

    v = 0.5 * np.stack([e(2, 1) - e(1, 2), e(0, 2) - e(2, 0), e(1, 0) - e(0, 1)], axis=1)
    sin = np.linalg.norm(v, axis=1)
    cos = 0.5 * (e(0, 0) + e(1, 1) + e(2, 2) - 1.0)
    angle = np.arctan2(sin, cos)
    scale = np.where(sin > 1e-300, angle / np.maximum(sin, 1e-300), 1.0)
    w = v * scale[:, None]
    for k in np.flatnonzero(angle > _LOG3_NEAR_PI):  # the axis is ill-conditioned from v there
        w[k] = pin.log3(Ra[k] @ Rb[k].T)
    return w


def batch_arm_angle(sew: Array) -> Array:
    """Arm angles (N,) [rad] of shoulder, elbow, wrist points (3, N, 3), as ``jara_arm.kinematics.arm_angle``."""
    s, e, w = sew
    u = w - s
    u /= np.linalg.norm(u, axis=1)[:, None]
    n_ref = np.cross(u, (0.0, 0.0, 1.0))
    vertical = np.linalg.norm(n_ref, axis=1) < 1e-6
    if vertical.any():
        n_ref[vertical] = np.cross(u[vertical], (1.0, 0.0, 0.0))
    n_arm = np.cross(u, e - s)
    psi = np.arctan2(np.einsum("ij,ij->i", u, np.cross(n_ref, n_arm)), np.einsum("ij,ij->i", n_ref, n_arm))
    psi[np.linalg.norm(n_arm, axis=1) < 1e-12] = 0.0
    return psi


# ----------------------------------------------------------------------------- spline


@dataclasses.dataclass
class HermiteSpline:
    """Piecewise cubic Hermite ``q(s)`` through knots ``s`` (K,) with values ``q`` and slopes ``dq`` (K, n)."""

    s: Array
    q: Array
    dq: Array

    def __call__(self, s: Array) -> Array:
        ks = self.s
        i = np.clip(np.searchsorted(ks, s, side="right") - 1, 0, len(ks) - 2)
        h = ks[i + 1] - ks[i]
        t = ((s - ks[i]) / h)[:, None]
        t2, t3 = t * t, t * t * t
        out = ((2.0 * t3 - 3.0 * t2 + 1.0) * self.q[i] + (t3 - 2.0 * t2 + t) * (h[:, None] * self.dq[i])
               + (3.0 * t2 - 2.0 * t3) * self.q[i + 1] + (t3 - t2) * (h[:, None] * self.dq[i + 1]))
        k = np.minimum(np.searchsorted(ks, s), len(ks) - 1)
        exact = ks[k] == s  # at a knot: its IK solution bit for bit (the target in particular)
        out[exact] = self.q[k[exact]]
        return out

    def extend(self, s: Array, q: Array, dq: Array) -> None:
        """Append knots beyond the last one."""
        self.s = np.concatenate([self.s, s])
        self.q = np.concatenate([self.q, q])
        self.dq = np.concatenate([self.dq, dq])

    def insert(self, s: float, q: Array, dq: Array) -> None:
        k = int(np.searchsorted(self.s, s))
        self.s = np.insert(self.s, k, s)
        self.q = np.insert(self.q, k, q, axis=0)
        self.dq = np.insert(self.dq, k, dq, axis=0)


# ----------------------------------------------------------------------------- path solver


@dataclasses.dataclass(frozen=True)
class Tolerances:
    """IK tolerances at knots and check tolerances at every sample [m], [rad]."""

    ik_pos: float
    ik_rot: float
    sample_pos: float
    sample_rot: float
    ik_elbow: float = 1e-4  # Kinematics.ik's default
    sample_elbow: float = 2e-4
    max_iter: int = 60


class PathJoints:
    """Joints along one Cartesian path: knots solved once, samples checked per profile.

    ``targets(s)``: control point poses (N, 4, 4) in the arm base frame at path
    parameters ``s`` in ``[0, length]``; ``start``: joints at ``s = 0``;
    ``elbows``: arm angle at the start and the end (moved linearly in ``s``),
    or ``(None, None)``; ``lo``/``hi``: joint limits; ``intervals``: initial
    number of knot intervals (uniform in ``s``); ``first_knots``: solve only that many of the knots now
    (:meth:`solve_knots` the rest). Raises :class:`Unreachable`.
    """

    def __init__(self, kin: Kinematics, fk: BatchFk, targets: Callable[[Array], Array], length: float,
                 start: Array, tool: pin.SE3 | None, mask: Mask, elbows: tuple[float | None, float | None],
                 lo: Array, hi: Array, tol: Tolerances, intervals: int, first_knots: int | None = None) -> None:
        self.kin, self.fk, self.targets, self.length = kin, fk, targets, length
        self.tool, self.mask, self.tol = tool, mask, tol
        self.e0, self.e1 = elbows
        self.lo, self.hi = lo, hi
        self._mp = np.array(mask[:3], dtype=float)
        self._mr = np.array(mask[3:], dtype=float)
        self._rows = np.flatnonzero(np.array(mask))
        self.ik_solves = 0
        self._start = start.copy()
        self._knots = np.linspace(0.0, length, max(1, intervals) + 1)
        self._q: list[Array] = []  # the uniform knots solved so far, and their slopes
        self._dq: list[Array] = []
        self.spline = HermiteSpline(np.zeros(0), np.zeros((0, len(start))), np.zeros((0, len(start))))
        self.solve_knots(len(self._knots) if first_knots is None else first_knots)

    def solve_knots(self, count: int | None = None) -> None:
        """Solve the first ``count`` uniform knots (all by default) that are not solved yet; the spline then
        runs to the last of them. Cubic Hermite pieces are local: the samples before an already solved knot
        do not change, which lets a motion's first samples go out while the rest is solved."""
        done, count = len(self._q), len(self._knots) if count is None else min(count, len(self._knots))
        if count <= done:
            return
        ks = self._knots[done:count]
        T, w = self._stencils(ks)
        for j in range(len(ks)):  # warm start: Taylor prediction from the previous knot
            k = done + j
            if k == 0:
                qk = self._start
            else:
                h = self._knots[k] - self._knots[k - 1]
                seed = self._q[-1] + h * self._dq[-1]
                if k > 1:  # second order, the curvature from the last two slopes: IK then needs one step
                    seed += (0.5 * h * h / (self._knots[k - 1] - self._knots[k - 2])) * (self._dq[-1] - self._dq[-2])
                qk = self._solve(float(ks[j]), T[j, 0], seed)
            self._q.append(qk)
            self._dq.append(self._tangent(qk, T[j], w[j]))
        self.spline.extend(ks, np.array(self._q[done:]), np.array(self._dq[done:]))

    def end_from_start(self) -> Array:
        """Joints at the path's end by IK seeded at the start, not along the knots: whether the target is
        reachable at all, before the knots between are solved (they may end in another solution).
        Raises :class:`Unreachable`."""
        return self._solve(self.length, self.targets(np.array([self.length]))[0], self._start)

    def _elbow_at(self, s: float | Array) -> float | Array | None:
        return None if self.e0 is None else self.e0 + (s / self.length) * (self.e1 - self.e0)

    def _stencils(self, ks: Array) -> tuple[Array, Array]:
        """Targets (K, 3, 4, 4) at each knot and two neighbours, and the weights (K, 3) of d/ds.

        Central differences inside, second-order one-sided ones at the ends of the path;
        ``T[:, 0]`` is the target at the knot itself.
        """
        L, d = self.length, _DS * self.length
        ss = np.stack([ks, ks - d, ks + d], axis=1)
        w = np.tile(np.array([0.0, -0.5, 0.5]) / d, (len(ks), 1))
        first, last = ks - d < 0.0, ks + d > L
        ss[first, 1:] = np.stack([ks[first] + d, ks[first] + 2 * d], axis=1)
        w[first] = np.array([-1.5, 2.0, -0.5]) / d
        ss[last, 1:] = np.stack([ks[last] - d, ks[last] - 2 * d], axis=1)
        w[last] = np.array([1.5, -2.0, 0.5]) / d
        return self.targets(ss.reshape(-1)).reshape(len(ks), 3, 4, 4), w

    def _solve(self, s: float, T: Array, seed: Array) -> Array:
        tol = self.tol
        target = pin.SE3(T[:3, :3], T[:3, 3])  # one pose of the batch (4x4): IK takes an SE3
        res = self.kin.ik(target, np.minimum(np.maximum(seed, self.lo), self.hi), tool=self.tool,
                          elbow=self._elbow_at(s), mask=self.mask, tol_pos=tol.ik_pos, tol_rot=tol.ik_rot,
                          tol_elbow=tol.ik_elbow, max_iter=tol.max_iter, lower=self.lo, upper=self.hi)
        self.ik_solves += 1
        if not res.success:
            raise Unreachable(s, T[:3, 3])
        return res.q

    def _tangent(self, q: Array, T: Array, w: Array) -> Array:
        """dq/ds at a knot keeping the constrained task rows (and the arm angle) on the path.

        ``T``, ``w``: the knot's stencil of :meth:`_stencils`.
        """
        Rc = self.kin.control_point(q, self.tool).rotation.T
        # d(error)/ds at fixed q, error = [p_t - p, log3(R_t R^T)] (target - current, arm frame)
        de = np.concatenate([w @ T[:, :3, 3], sum(wk * pin.log3(Tk[:3, :3] @ Rc) for wk, Tk in zip(w, T) if wk)])
        J = self.kin.jacobian(q, self.tool)
        Jt = np.vstack([J[:3], pin.Jlog3(T[0, :3, :3] @ Rc) @ J[3:]])  # d(current)/dq
        A, b = Jt[self._rows], de[self._rows]
        if self.e0 is not None:
            A = np.vstack([A, self.kin.elbow_jacobian(q)])
            b = np.append(b, (self.e1 - self.e0) / self.length)
        if A.shape[0] == A.shape[1]:
            try:
                return np.linalg.solve(A, b)
            except np.linalg.LinAlgError:  # singular: the least-squares slope
                pass
        return np.linalg.lstsq(A, b, rcond=None)[0]

    def _bad(self, s: Array, T: Array, q: Array) -> NDArray[np.bool_]:
        """Samples (targets T) off the path beyond the sample tolerances, or outside the joint limits."""
        tol = self.tol
        pts, rot, sew = self.fk.run(q, self.tool)
        ep = T[:, :3, 3] - pts
        pe = (ep * ep) @ self._mp
        w = batch_log3(T[:, :3, :3], rot)
        re = (w * w) @ self._mr
        bad = (pe > tol.sample_pos ** 2) | (re > tol.sample_rot ** 2)
        bad |= np.any((q < self.lo) | (q > self.hi), axis=1) | ~np.isfinite(q).all(axis=1)
        if self.e0 is not None and sew is not None:
            ee = np.remainder(batch_arm_angle(sew) - self._elbow_at(s) + math.pi, 2 * math.pi) - math.pi
            bad |= np.abs(ee) > tol.sample_elbow
        return bad

    def joints(self, s: Array, targets: Array | None = None) -> Array:
        """Joints (N, n) at the increasing path parameters ``s``, every one checked on the path.

        ``targets``: the poses at ``s`` if the caller has them (arm frame).
        """
        T = self.targets(s) if targets is None else targets
        q = self.spline(s)
        check = np.arange(len(s))  # samples to check: all, then those of the intervals just split
        while True:
            bad = check[self._bad(s[check], T[check], q[check])]
            if not bad.size:
                return q
            ks = self.spline.s
            split: list[tuple[float, float, float]] = []
            for i in np.unique(np.clip(np.searchsorted(ks, s[bad], side="right") - 1, 0, len(ks) - 2)):
                a, b = ks[i], ks[i + 1]
                inside = np.flatnonzero((s > a) & (s < b))
                if inside.size:  # else the bad sample is a knot itself: IK failed its tolerance
                    split.append((a, b, float(s[inside[np.argmin(np.abs(s[inside] - 0.5 * (a + b)))]])))
            if not split:  # pragma: no cover - knots meet the IK tolerances, below the sample ones
                k = int(bad[0])
                raise Unreachable(float(s[k]), T[k, :3, 3])
            new = np.array([sk for _, _, sk in split])
            seeds = self.spline(new)
            Tn, wn = self._stencils(new)
            for k, sk in enumerate(new):
                qk = self._solve(float(sk), Tn[k, 0], seeds[k])
                self.spline.insert(float(sk), qk, self._tangent(qk, Tn[k], wn[k]))
            check = np.flatnonzero(np.any([(s >= a) & (s <= b) for a, b, _ in split], axis=0))
            q[check] = self.spline(s[check])


__all__ = ["BatchFk", "HermiteSpline", "PathJoints", "Tolerances", "Unreachable", "batch_arm_angle",
           "batch_log3"]
