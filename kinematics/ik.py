"""Inverse kinematics on Pinocchio: task masks, seed table and restarts, and the one solver loop.

Everything here works in Pinocchio's coordinate order and with ``pin.SE3``
poses; :meth:`jara_arm.kinematics.Kinematics.ik` checks the request, converts
to and from J1..Jn and documents the method.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Final

import eigenpy
import numpy as np
import pinocchio as pin

from .arm_angle import ArmAngleChain
from .errors import KinematicsError

__all__ = ["FULL_MASK", "POSITION_MASK", "IkResult", "IkSolver", "Mask", "SeedTable", "check_mask",
           "nearest_turn"]

Mask = tuple[bool, bool, bool, bool, bool, bool]
"""Which task components IK constrains: (x, y, z, rx, ry, rz) of the arm base frame."""

FULL_MASK: Final[Mask] = (True, True, True, True, True, True)
POSITION_MASK: Final[Mask] = (True, True, True, False, False, False)

_TABLE_STREAM: Final = 0x5EED7AB1E  # RNG streams of the seed table and of random restarts,
_RESTART_STREAM: Final = 0x4E5747  # distinct from a caller's default_rng(seed)

# Tuning (see Kinematics.ik). Errors are summed as [m^2] + [rad^2].
_DAMP_GAIN: Final = 0.05  # Levenberg-Marquardt damping = gain * squared error + floor
_DAMP_FLOOR: Final = 1e-7
_STALL_DECREASE: Final = 0.3  # progress: the error falls below 0.3 x the attempt's best so far
_STALL_ITERS: Final = 1  # iterations without progress tolerated; one more and the attempt restarts
_ATTEMPT_ITERS: Final = 14  # iterations per attempt before a restart
_NEAR_ERR: Final = 1e-6  # [m^2 + rad^2] below it an attempt is close: slow (near-singular) convergence
_NEAR_DECREASE: Final = 0.9  # needs only this progress ratio
_NEAR_ITERS: Final = 60  # and may last this long
_TABLE_RESTARTS: Final = 12  # restarts drawn from the seed table before uniform random ones
_TABLE_ROT_WEIGHT: Final = 0.1  # [m^2] per unit of (3 - trace(Ra^T Rb)) in the table distance
_TABLE_ELBOW_WEIGHT: Final = 0.1  # [m^2] per unit of (1 - cos(elbow difference))


@dataclasses.dataclass(frozen=True, slots=True)
class IkResult:
    """Outcome of :meth:`Kinematics.ik`.

    On failure ``q`` is the best configuration found (smallest error); it is
    always within the joint limits used.
    """

    q: np.ndarray  # [rad or m] per arm axis, J1..Jn
    success: bool  # True when every tolerance is met
    iterations: int  # Newton iterations spent, restarts included
    pos_err: float  # [m] norm of the constrained position error
    rot_err: float  # [rad] norm of the constrained rotation error (the angle when unmasked)
    elbow_err: float = 0.0  # [rad] arm angle error, 0 unless an elbow was commanded


def check_mask(mask: Sequence[bool]) -> Mask:
    """``mask`` as a :data:`Mask`: six flags, at least one set."""
    m = tuple(bool(x) for x in mask)
    if len(m) != 6:
        raise KinematicsError(f"mask: expected 6 flags (x, y, z, rx, ry, rz), got {len(m)}")
    if not any(m):
        raise KinematicsError("mask: at least one of (x, y, z, rx, ry, rz) must be constrained")
    return m  # type: ignore[return-value]


def nearest_turn(q: np.ndarray, seed: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 revolute: np.ndarray) -> np.ndarray:
    """``q`` with its revolute joints of more than 2 pi of travel moved by whole turns towards ``seed``.

    ``q``, ``seed``, ``lo``, ``hi`` [rad or m] and the flags ``revolute`` per
    coordinate; a joint stays where it is when the turned value leaves [lo, hi].
    """
    out = q.copy()
    for i in np.flatnonzero(revolute & (hi - lo > math.tau)):
        c = q[i] + math.tau * round((seed[i] - q[i]) / math.tau)
        if lo[i] <= c <= hi[i]:
            out[i] = c
    return out


# ---------------------------------------------------------------------------- seeds


class SeedTable:
    """Random configurations with their flange poses and arm angles, to restart IK near the target.

    ``size`` configurations drawn uniformly in [lo, hi] with the RNG ``seed``
    (reproducible); 0 makes an empty table.
    """

    __slots__ = ("q", "_features", "_p2")

    def __init__(self, model: pin.Model, data: pin.Data, flange_id: int, chain: ArmAngleChain | None,
                 lo: np.ndarray, hi: np.ndarray, size: int, seed: int) -> None:
        n = model.nq
        self.q = np.empty((0, n))  # [rad or m], Pinocchio order
        self._features: np.ndarray | None = None
        self._p2: np.ndarray | None = None
        if size <= 0:
            return
        rng = np.random.default_rng((seed, _TABLE_STREAM))
        qs = lo + (hi - lo) * rng.random((size, n))
        feats = np.empty((size, 14))  # p (3), R row-major (9), cos(psi), sin(psi)
        oMf = data.oMf
        for i, q in enumerate(qs):
            pin.forwardKinematics(model, data, q)
            pin.updateFramePlacement(model, data, flange_id)
            flange = oMf[flange_id]
            feats[i, :3] = flange.translation
            feats[i, 3:12] = flange.rotation.reshape(-1)
            psi = chain.angle(False)[0] if chain is not None else 0.0
            feats[i, 12] = math.cos(psi)
            feats[i, 13] = math.sin(psi)
        self.q = qs
        self._features = feats.astype(np.float32)  # only ranks restarts: single precision is plenty
        self._p2 = (feats[:, :3] ** 2).sum(axis=1).astype(np.float32)

    def __len__(self) -> int:
        return len(self.q)

    def distance(self, flange_target: pin.SE3, mask: Mask, elbow: float | None) -> np.ndarray:
        """Squared-ish distance of every entry to the target (flange pose, arm angle [rad]); a new array."""
        f, p2 = self._features, self._p2
        assert f is not None and p2 is not None, "distance() of an empty table"
        g = np.zeros(14, dtype=np.float32)
        mp = np.array(mask[:3])
        g[:3] = -2.0 * flange_target.translation * mp
        c = p2 if mp.all() else (f[:, :3][:, mp] ** 2).sum(axis=1)
        if all(mask[3:]):  # orientation used only when fully constrained
            g[3:12] = -_TABLE_ROT_WEIGHT * flange_target.rotation.reshape(-1)
        if elbow is not None:
            g[12] = -_TABLE_ELBOW_WEIGHT * math.cos(elbow)
            g[13] = -_TABLE_ELBOW_WEIGHT * math.sin(elbow)
        return c + f @ g


class _Restarts:
    """Start configurations of IK restarts: the nearest seed-table entries, then uniform random.

    The table distances and the RNG are only computed when a first restart is needed.
    """

    __slots__ = ("table", "target", "tool", "mask", "elbow", "lo", "hi", "seed", "count", "dist", "rng")

    def __init__(self, table: SeedTable, target: pin.SE3, tool: pin.SE3 | None, mask: Mask,
                 elbow: float | None, lo: np.ndarray, hi: np.ndarray, seed: int) -> None:
        self.table, self.target, self.tool, self.mask, self.elbow = table, target, tool, mask, elbow
        self.lo, self.hi, self.seed = lo, hi, seed
        self.count = 0
        self.dist: np.ndarray | None = None
        self.rng: np.random.Generator | None = None

    def next(self) -> np.ndarray:
        k = self.count
        self.count += 1
        table = self.table
        if k < _TABLE_RESTARTS and len(table):
            if self.dist is None:
                # The table holds flange poses: the flange pose that puts the control point at the target.
                flange = self.target if self.tool is None else self.target * self.tool.inverse()
                self.dist = table.distance(flange, self.mask, self.elbow)
            i = int(self.dist.argmin())
            self.dist[i] = np.inf
            return np.minimum(np.maximum(table.q[i], self.lo), self.hi)
        if self.rng is None:
            self.rng = np.random.default_rng((self.seed, _RESTART_STREAM))
        return self.lo + (self.hi - self.lo) * self.rng.random(len(self.lo))


# ---------------------------------------------------------------------------- solver


class _Task:
    """What the loop needs for one mask, with or without an arm angle row: built once, not per call.

    Rows of the task: the constrained components of (x, y, z, rx, ry, rz), then
    the arm angle. The work arrays are reused by every call with this task.
    """

    __slots__ = ("pos_all", "rot_all", "full", "direct", "partial_rot", "mp", "mr", "rows", "k",
                 "llt", "solve", "A", "Ad", "Jm", "e", "Jt", "e6")

    def __init__(self, mask: Mask, elbow: bool, n: int) -> None:
        self.pos_all, self.rot_all = all(mask[:3]), all(mask[3:])
        self.full = self.pos_all and self.rot_all
        self.direct = self.full and not elbow  # the task Jacobian is the frame Jacobian itself
        self.partial_rot = any(mask[3:]) and not self.rot_all
        self.mp = np.array(mask[:3], dtype=float)
        self.mr = np.array(mask[3:], dtype=float)
        self.rows = np.flatnonzero(np.array(mask))
        self.k = len(self.rows)  # the arm angle row's index
        nrow = self.k + (1 if elbow else 0)
        self.llt = eigenpy.LLT(nrow)
        self.solve: Callable[[np.ndarray], np.ndarray] = self.llt.solve if nrow > 1 else self._solve_one
        self.A = np.empty((nrow, nrow))
        self.Ad = self.A.reshape(-1)[:: nrow + 1]  # its diagonal (a view)
        self.Jm = np.empty((nrow, n))  # task Jacobian: constrained rows, then the arm angle row
        self.e = np.empty(nrow)  # task error, same rows
        self.Jt = np.empty((6, n))  # all six rows before the mask selects some
        self.e6 = np.empty(6)

    def _solve_one(self, b: np.ndarray) -> np.ndarray:
        return self.llt.solve(b).reshape(1)  # eigenpy hands a size-1 solution back as 1x1


class IkSolver:
    """IK of one Pinocchio model on one ``Data`` work area (one per thread), with its seed table.

    ``chain``: the arm angle's joints (7-axis arms), else None; ``lo``/``hi``
    [rad or m]: the hard limits the seed table is drawn in; ``table_size``
    entries drawn with the RNG ``seed``, which also seeds the random restarts.
    """

    def __init__(self, model: pin.Model, data: pin.Data, flange_id: int, chain: ArmAngleChain | None,
                 lo: np.ndarray, hi: np.ndarray, table_size: int, seed: int) -> None:
        self._model, self._data, self._oMf = model, data, data.oMf
        self._n = model.nq
        self._chain = chain
        self._seed = seed
        self._tasks: dict[tuple[Mask, bool], _Task] = {}
        self.table: Final = SeedTable(model, data, flange_id, chain, lo, hi, table_size, seed)

    def solve(self, target: pin.SE3, tool: pin.SE3 | None, frame_id: int, q: np.ndarray,
              lo: np.ndarray, hi: np.ndarray, mask: Mask, elbow: float | None,
              tol_pos: float, tol_rot: float, tol_elbow: float, max_iter: int,
              ) -> tuple[np.ndarray, bool, int, float, float, float]:
        """(q, success, iterations, pos_err [m], rot_err [rad], elbow_err [rad]), q in Pinocchio order.

        ``target``: pose of frame ``frame_id`` (the control point ``flange ·
        tool``) in the arm base frame; ``q`` [rad or m]: the start, within
        [lo, hi]; ``elbow`` [rad] in (-pi, pi]: the arm angle to reach (needs a
        chain), None to leave it free. Method: :meth:`Kinematics.ik`.

        One loop for every task. Errors are taken along the arm base axes with
        the LOCAL_WORLD_ALIGNED Jacobian: ``[p_t - p, w = log3(R_t R^T)]``,
        the constrained rows of it, then the arm angle row ``d(psi)/dq`` when
        an elbow is commanded. When some rotation rows are free their
        components of ``w`` need not be small, so the rotation rows use the
        exact derivative ``dw = -Jlog3(R_t R^T) · omega dt``. The full pose
        without an elbow, the common case, uses the frame Jacobian as it is,
        without copies (every Python operation counts there).
        """
        m, d, oMf, fid = self._model, self._data, self._oMf, frame_id
        frame_jacobian, joint_jacobians, get_jacobian = (pin.computeFrameJacobian, pin.computeJointJacobians,
                                                         pin.getFrameJacobian)
        log3, jlog3, lwa = pin.log3, pin.Jlog3, pin.LOCAL_WORLD_ALIGNED
        mn, mx, dot, sqrt, remainder = np.minimum, np.maximum, np.dot, math.sqrt, math.remainder
        stall_dec, stall_iters, att_iters = _STALL_DECREASE, _STALL_ITERS, _ATTEMPT_ITERS
        near, near_dec, near_iters = _NEAR_ERR, _NEAR_DECREASE, _NEAR_ITERS
        gain, floor = _DAMP_GAIN, _DAMP_FLOOR
        if elbow is not None and self._chain is None:
            raise KinematicsError("ik: an arm angle needs its shoulder, elbow and wrist joints (7-axis arms)")
        chain = None if elbow is None else self._chain  # None: the arm angle is free
        psi_t = 0.0 if elbow is None else elbow  # [rad] the arm angle to reach
        one_axis = self._n == 1
        key = (mask, chain is not None)
        task = self._tasks.get(key)
        if task is None:
            task = self._tasks[key] = _Task(mask, chain is not None, self._n)
        pos_all, rot_all, full, direct = task.pos_all, task.rot_all, task.full, task.direct
        partial_rot, mp, mr, rows, k = task.partial_rot, task.mp, task.mr, task.rows, task.k
        compute, solve = task.llt.compute, task.solve
        A, Ad, Jm, e, Jt, e6 = task.A, task.Ad, task.Jm, task.e, task.Jt, task.e6

        pt, rt = target.translation.copy(), target.rotation.copy()
        tp2, tr2, te2 = tol_pos * tol_pos, tol_rot * tol_rot, tol_elbow * tol_elbow
        restarts = _Restarts(self.table, target, tool, mask, elbow, lo, hi, self._seed)
        # elbow_err is 0 unless an elbow is commanded (IkResult).
        best, best_q, best_pe, best_re = math.inf, q, math.inf, math.inf
        best_ee = 0.0 if chain is None else math.inf
        att_best, since, att = math.inf, 0, 0
        for it in range(max_iter):
            if chain is None:
                J = frame_jacobian(m, d, q, fid, lwa)  # also updates oMf[fid] (in LOCAL it would not)
            else:  # the arm angle needs every joint's placement and Jacobian
                joint_jacobians(m, d, q)
                J = get_jacobian(m, d, fid, lwa)
            if one_axis:  # eigenpy hands a 6x1 matrix back as a vector
                J = J.reshape(6, 1)
            M = oMf[fid]
            ep = pt - M.translation
            E = rt.dot(M.rotation.T)
            w = log3(E)
            pe = ep.dot(ep) if pos_all else (ep * mp).dot(ep)
            re = w.dot(w) if rot_all else (w * mr).dot(w)
            ee = 0.0
            if chain is not None:
                psi, g = chain.angle(True)
                de = remainder(psi_t - psi, math.tau)
                ee = de * de
                Jm[k] = g
                e[k] = de
            if pe <= tp2 and re <= tr2 and ee <= te2:
                return q, True, it, sqrt(pe), sqrt(re), sqrt(ee)
            err = pe + re + ee
            if err < best:
                best, best_q, best_pe, best_re, best_ee = err, q, pe, re, ee
            if err < att_best * (stall_dec if err > near else near_dec):
                att_best = err
                since = 0
            else:
                since += 1
            att += 1
            if since > stall_iters or att > (att_iters if err > near else near_iters):
                q = restarts.next()
                att_best, since, att = math.inf, 0, 0
                continue
            if direct:
                Jtask = J
                e[:3] = ep
                e[3:] = w
            elif full:
                Jm[:6] = J
                e[:3] = ep
                e[3:6] = w
                Jtask = Jm
            else:
                Jt[:3] = J[:3]
                Jt[3:] = jlog3(E).dot(J[3:]) if partial_rot else J[3:]
                e6[:3] = ep
                e6[3:] = w
                Jm[:k] = Jt[rows]
                e[:k] = e6[rows]
                Jtask = Jm
            lam = gain * err + floor
            JT = Jtask.T
            dot(Jtask, JT, out=A)
            Ad += lam
            compute(A)
            qn = q + JT.dot(solve(e))
            qc = mn(mx(qn, lo), hi)
            dv = qn - qc
            if dv.dot(dv) > 0.0:
                # Limit-aware step: stop the offending joints at their limit, re-solve the others.
                free = dv == 0.0
                dqf = qc - q
                dqf *= ~free
                Jf = Jtask * free
                dot(Jf, Jf.T, out=A)
                Ad += lam
                compute(A)
                qn = q + dqf + Jf.T.dot(solve(e - Jtask.dot(dqf)))
                qc = mn(mx(qn, lo), hi)
            q = qc
        return best_q, False, max_iter, sqrt(best_pe), sqrt(best_re), sqrt(best_ee)
