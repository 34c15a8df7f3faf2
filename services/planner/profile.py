"""One jerk-limited speed profile along a geometric path, computed with Ruckig.

Every motion is a path (``paths.py``) plus one 1-D profile ``s(t)`` of its
normalised parameter ``s`` in ``[0, length]`` (DECISIONS.md, "Timing law"), so
all axes / all Cartesian directions start and stop together with equal
acceleration and deceleration times.

Choice of limits (why ``duration = d/v + aclTime`` holds exactly)
-----------------------------------------------------------------
DECISIONS.md: "aclTime is the time to go from rest to the commanded speed".
With speed ``v``, acceleration time ``T`` and a shape parameter
``f = jerk_fraction`` in (0, 1] (the share of ``T`` spent ramping the
acceleration), the limits are::

    a = v / (T (1 - f/2))        # [1/s²]
    j = 2 a / (f T)              # [1/s³]

The time-optimal rest-to-``v`` transition under these limits ramps the
acceleration up for ``a/j = fT/2``, holds ``a`` for ``v/a - a/j = T(1 - f)``
and ramps down for ``fT/2``: total ``v/a + a/j = T`` exactly.  The default
``f = 1`` is the pure S-curve (``a = 2v/T``, ``j = 4v/T²``): the lowest jerk
that reaches ``v`` in ``T``.  Because the velocity curve of that transition is
point-symmetric about its midpoint, it covers ``vT/2``; deceleration mirrors
it.  So a move of length ``d >= vT`` cruises for ``(d - vT)/v`` and lasts
``d/v + T`` — the law holds exactly (Ruckig's time-optimal solution reproduces
it to ~1e-15 relative).  A shorter move never reaches ``v``; Ruckig returns the
time-optimal profile within the same ``a`` and ``j``, symmetric in its
acceleration and deceleration.

Pause / stop
------------
:func:`stop_profile` (or :meth:`PathProfile.stop_at`) brakes from any state
``(s, sd, sdd)`` to rest along the path within the same ``a`` and ``j``
(Ruckig velocity interface, target speed 0); :func:`resume_profile` (or
:meth:`PathProfile.resume`) goes from rest at ``s`` to the path end, which it
reaches exactly.

Time starts at 0 for every profile; the executor keeps its own clock per
profile.  ``sample(dt)`` gives the states at ``t = k·dt`` (the servo period,
1 ms by default), ending with the exact end state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import ruckig
from numpy.typing import ArrayLike, NDArray

from jara_arm.schema.errors import JaraArmError

from .paths import CartesianArc, CartesianLine, JointLine, Path

__all__ = [
    "NEGLIGIBLE_MOTION",
    "PathMotion",
    "PathProfile",
    "ProfileError",
    "ProfileLimits",
    "ProfileSamples",
    "calculate",
    "cartesian_path_speed",
    "continue_profile",
    "joint_path_speed",
    "move_profile",
    "plan_cartesian",
    "plan_joint_ptp",
    "resume_profile",
    "stop_profile",
]

NEGLIGIBLE_MOTION = 1e-12
"""[rad or m] An axis displacement, translation or rotation at or below this
does not bound the path speed (a move whose every part is negligible takes no
time: it is the target already)."""

_SAMPLE_EPS = 1e-12  # [-] relative slack so that duration = n·dt exactly does not add a sample
_STOP_OVERSHOOT = 1e-9  # [-] relative overshoot of the path end that is rounding, not a real overshoot


class ProfileError(JaraArmError, ValueError):
    """A speed profile cannot be built from the given limits or state."""


def _positive(name: str, value: float, *, allow_inf: bool = False) -> float:
    x = float(value)
    if math.isnan(x) or x <= 0.0 or (math.isinf(x) and not allow_inf):
        kind = "number" if allow_inf else "finite number"
        raise ProfileError(f"{name} must be a positive {kind}, got {value!r}")
    return x


@dataclass(frozen=True)
class ProfileLimits:
    """Bounds on the path parameter's derivatives (units of ``s`` per second^k).

    ``velocity`` may be ``inf`` (then ``acceleration`` and ``jerk`` are too)
    only for a move of negligible size, which never reaches Ruckig.
    """

    velocity: float  # [1/s]   max ds/dt
    acceleration: float  # [1/s²]  max |d²s/dt²|
    jerk: float  # [1/s³]  max |d³s/dt³|

    def __post_init__(self) -> None:
        for name in ("velocity", "acceleration", "jerk"):
            _positive(name, getattr(self, name), allow_inf=True)

    @classmethod
    def from_accel_time(cls, velocity: float, accel_time: float, jerk_fraction: float = 1.0) -> ProfileLimits:
        """Limits under which rest -> ``velocity`` takes exactly ``accel_time`` [s].

        ``jerk_fraction`` f in (0, 1]: share of ``accel_time`` spent ramping the
        acceleration (1 = pure S-curve, no constant-acceleration phase).
        """
        v = _positive("velocity", velocity, allow_inf=True)
        T = _positive("accel_time", accel_time)
        f = float(jerk_fraction)
        if not 0.0 < f <= 1.0:
            raise ProfileError(f"jerk_fraction must be in (0, 1], got {jerk_fraction!r}")
        a = v / (T * (1.0 - 0.5 * f))
        j = 2.0 * a / (f * T)
        return cls(v, a, j)

    @property
    def accel_time(self) -> float:
        """[s] Time-optimal rest -> ``velocity`` under these limits (``v/a + a/j``).

        Valid when ``a²/j <= v`` (true for :meth:`from_accel_time` limits).
        """
        return self.velocity / self.acceleration + self.acceleration / self.jerk

    @property
    def finite(self) -> bool:
        return math.isfinite(self.velocity) and math.isfinite(self.acceleration) and math.isfinite(self.jerk)


@dataclass(frozen=True, eq=False)
class ProfileSamples:
    """A profile sampled at a fixed period: arrays of equal length ``N``."""

    dt: float  # [s] sampling period
    t: NDArray[np.float64]  # [s] k·dt, k = 0 … N-1
    s: NDArray[np.float64]  # [path units]
    sd: NDArray[np.float64]  # [path units/s]
    sdd: NDArray[np.float64]  # [path units/s²]


@dataclass(frozen=True, eq=False)
class PathProfile:
    """Jerk-limited ``s(t)`` on ``[0, duration]`` ending at rest at ``s_end``.

    Build with :func:`move_profile`, :func:`stop_profile`,
    :func:`resume_profile` or the ``plan_*`` helpers, not directly.
    """

    length: float  # [path units] path length (1.0 for the paths of paths.py)
    limits: ProfileLimits
    s_start: float  # [path units] state at t = 0 …
    sd_start: float  # [path units/s]
    sdd_start: float  # [path units/s²]
    s_end: float  # [path units] rest position at t >= duration
    duration: float  # [s]
    _trajectory: ruckig.Trajectory | None  # None for a zero-duration profile

    def at(self, t: float) -> tuple[float, float, float]:
        """``(s, sd, sdd)`` at time ``t`` [s]; before 0 the start, after ``duration`` the end state."""
        if self._trajectory is None or t >= self.duration:
            return (self.s_end, 0.0, 0.0)  # exact end: the target must be reached exactly
        if t <= 0.0:
            return (self.s_start, self.sd_start, self.sdd_start)
        (p,), (v,), (a,) = self._trajectory.at_time(t)
        # rounding can push s a hair past its bounds or sd a hair below 0
        lo, hi = min(self.s_start, self.s_end), max(self.s_start, self.s_end)
        return (min(max(p, lo), hi), max(v, 0.0), a)

    def sample(self, dt: float = 1e-3) -> ProfileSamples:
        """States at ``t = k·dt``, k = 0 … n, ``n = ceil(duration/dt)``.

        Sample 0 is the start state; the last sample (at ``n·dt >= duration``)
        is the exact end state, so a profile of duration 0 gives one sample.
        """
        dt = _positive("dt", dt)
        n = max(0, math.ceil(self.duration / dt * (1.0 - _SAMPLE_EPS)))
        t = np.arange(n + 1, dtype=float) * dt
        out = self._states(t[:n]) if n else np.empty((0, 3))
        out = np.vstack([out, (self.s_end, 0.0, 0.0)])
        return ProfileSamples(dt, t, out[:, 0].copy(), out[:, 1].copy(), out[:, 2].copy())

    def _states(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(s, sd, sdd)`` rows at times ``t`` (0 <= t < duration), as :meth:`at` gives them.

        Vectorised over Ruckig's seven constant-jerk phases (a Python loop over
        ``at`` costs ~6 µs a sample); a profile with a braking pre-phase takes the loop.
        """
        prof = self._trajectory.profiles[0][0]  # type: ignore[union-attr]
        if prof.brake.duration > 0.0:
            return np.array([self.at(float(x)) for x in t]).reshape(-1, 3)
        ends = np.cumsum(prof.t)
        k = np.minimum(np.searchsorted(ends, t, side="right"), 6)
        tau = t - (ends - np.asarray(prof.t))[k]
        j, a0 = np.asarray(prof.j)[k], np.asarray(prof.a)[k]
        v0, p0 = np.asarray(prof.v)[k], np.asarray(prof.p)[k]
        s = p0 + tau * (v0 + tau * (a0 / 2.0 + tau * j / 6.0))
        sd = v0 + tau * (a0 + tau * j / 2.0)
        sdd = a0 + tau * j
        lo, hi = min(self.s_start, self.s_end), max(self.s_start, self.s_end)
        out = np.empty((len(t), 3))
        out[:, 0] = np.clip(s, lo, hi)  # rounding can push s a hair past its bounds or sd below 0
        out[:, 1] = np.maximum(sd, 0.0)
        out[:, 2] = sdd
        if len(t) and t[0] <= 0.0:
            out[t <= 0.0] = (self.s_start, self.sd_start, self.sdd_start)
        return out

    @property
    def finished_at_end(self) -> bool:
        """True when the profile stops at the end of the path."""
        return self.s_end == self.length

    def stop_at(self, t: float) -> PathProfile:
        """Braking continuation from the state at ``t`` [s] (pause / stop)."""
        s, sd, sdd = self.at(t)
        return stop_profile(self.length, s, sd, sdd, self.limits)

    def resume(self) -> PathProfile:
        """From rest at ``s_end`` to the end of the path with the same limits."""
        return resume_profile(self.length, self.s_end, self.limits)


# --------------------------------------------------------------------------- builders


def _at_rest(length: float, limits: ProfileLimits, s: float) -> PathProfile:
    return PathProfile(length, limits, s, 0.0, 0.0, s, 0.0, None)


def _input(limits: ProfileLimits, s: float, sd: float, sdd: float) -> ruckig.InputParameter:
    if not limits.finite:
        raise ProfileError("infinite limits are only valid for a move of negligible size")
    inp = ruckig.InputParameter(1)
    inp.current_position = [s]
    inp.current_velocity = [sd]
    inp.current_acceleration = [sdd]
    inp.target_velocity = [0.0]
    inp.target_acceleration = [0.0]
    inp.max_velocity = [limits.velocity]
    inp.max_acceleration = [limits.acceleration]
    inp.max_jerk = [limits.jerk]
    return inp


def calculate(inp: ruckig.InputParameter) -> ruckig.Trajectory:
    """Ruckig's offline trajectory for ``inp`` (any number of DoFs); ProfileError if it has none."""
    n = inp.degrees_of_freedom
    traj = ruckig.Trajectory(n)
    try:
        result = ruckig.Ruckig(n).calculate(inp, traj)  # offline: no delta_time needed
    except ruckig.RuckigError:
        # Ruckig 0.19 throws on some inputs exactly on a profile-type boundary (e.g. a
        # rest-to-rest move of exactly v·aclTime, no cruise): velocity limits 1e-12 tighter
        # are off the boundary and change the duration by ~1e-12 relative.
        inp.max_velocity = [v * (1.0 - 1e-12) for v in inp.max_velocity]
        try:
            result = ruckig.Ruckig(n).calculate(inp, traj)
        except ruckig.RuckigError as exc:
            raise ProfileError(f"Ruckig could not compute the profile: {exc}") from None
    if result not in (ruckig.Result.Working, ruckig.Result.Finished):
        raise ProfileError(f"Ruckig could not compute the profile: {result}")
    return traj


def _check_length(length: float) -> float:
    return _positive("length", length)


def move_profile(length: float, limits: ProfileLimits, s_start: float = 0.0) -> PathProfile:
    """From rest at ``s_start`` to rest at ``length`` [path units], time-optimal within ``limits``."""
    length = _check_length(length)
    s_start = float(s_start)
    if not 0.0 <= s_start <= length:
        raise ProfileError(f"s_start must lie in [0, {length}], got {s_start!r}")
    if s_start == length:
        return _at_rest(length, limits, length)
    inp = _input(limits, s_start, 0.0, 0.0)
    inp.target_position = [length]
    traj = calculate(inp)
    return PathProfile(length, limits, s_start, 0.0, 0.0, length, float(traj.duration), traj)


def resume_profile(length: float, s: float, limits: ProfileLimits) -> PathProfile:
    """From rest at ``s`` to the end of the path (after a pause); same as :func:`move_profile`."""
    return move_profile(length, limits, s)


def continue_profile(length: float, s: float, sd: float, sdd: float, limits: ProfileLimits) -> PathProfile:
    """From the moving state ``(s, sd, sdd)`` on to rest at the end of the path within ``limits``, time-optimal:
    an early start handing over to its whole motion slowed down (a state beyond the new limits is first
    braked into them, Ruckig's brake phase)."""
    length = _check_length(length)
    s, sd, sdd = float(s), float(sd), float(sdd)
    if not (math.isfinite(s) and math.isfinite(sd) and math.isfinite(sdd)) or not 0.0 <= s <= length or sd < 0.0:
        raise ProfileError(f"cannot continue from s={s!r}, sd={sd!r}, sdd={sdd!r} on a path of length {length}")
    if s == length:
        return _at_rest(length, limits, length)
    inp = _input(limits, s, sd, sdd)
    inp.target_position = [length]
    traj = calculate(inp)
    return PathProfile(length, limits, s, sd, sdd, length, float(traj.duration), traj)


def stop_profile(length: float, s: float, sd: float, sdd: float, limits: ProfileLimits) -> PathProfile:
    """Decelerate from ``(s, sd, sdd)`` to rest along the path within ``limits``.

    Time-optimal braking to zero speed and zero acceleration (Ruckig velocity
    interface); it never ends later than the running profile would have.  From
    the deceleration phase of the running profile it retraces that profile and
    lands on the path end up to rounding, which is clamped.  A state that truly
    cannot stop before the end (no rest-to-rest profile on this path passes
    through it) gets a position-target profile onto the end instead; its ``s``
    is clipped to the end if Ruckig overshoots.
    """
    length = _check_length(length)
    s, sd, sdd = float(s), float(sd), float(sdd)
    if not (math.isfinite(s) and math.isfinite(sd) and math.isfinite(sdd)):
        raise ProfileError("stop state must be finite")
    if not 0.0 <= s <= length:
        raise ProfileError(f"s must lie in [0, {length}], got {s!r}")
    if sd < 0.0:
        raise ProfileError(f"path speed must be >= 0 (motion runs forward along the path), got {sd!r}")
    if sd == 0.0 and sdd <= 0.0:  # at rest (a negative sdd here is rounding noise)
        return _at_rest(length, limits, s)
    if not limits.finite:  # a negligible move has no state worth braking from
        return _at_rest(length, limits, length)
    inp = _input(limits, s, sd, sdd)
    inp.control_interface = ruckig.ControlInterface.Velocity
    traj = calculate(inp)
    (s_stop,), _, _ = traj.at_time(float(traj.duration))
    if s_stop > length * (1.0 + _STOP_OVERSHOOT):
        # Not a state of a profile that ends at `length`: it cannot brake in time.
        # Brake onto the end instead (Ruckig may then exceed the path and come back).
        inp = _input(limits, s, sd, sdd)
        inp.target_position = [length]
        traj = calculate(inp)
        s_stop = length
    # Braking from the deceleration phase of the running profile retraces it and
    # lands on the end up to rounding: clamp (at() clips s to [s, s_end]).
    s_stop = min(max(float(s_stop), s), length)
    return PathProfile(length, limits, s, sd, sdd, s_stop, float(traj.duration), traj)


# --------------------------------------------------------------------------- motions


@dataclass(frozen=True, eq=False)
class PathMotion:
    """A path and the speed profile that runs along it."""

    path: Path  # JointLine, CartesianLine or CartesianArc
    profile: PathProfile

    @property
    def duration(self) -> float:
        """[s]"""
        return self.profile.duration

    def sample(self, dt: float = 1e-3) -> tuple[ProfileSamples, NDArray[np.float64]]:
        """Profile samples and the path points at them: joints ``(N, n)`` or poses ``(N, 4, 4)``."""
        samples = self.profile.sample(dt)
        return samples, self.path.sample(samples.s)


def _check_ratio(speed_ratio: float) -> float:
    r = float(speed_ratio)
    if not 0.0 < r <= 1.0:
        raise ProfileError(f"speed_ratio must be in (0, 1], got {speed_ratio!r}")
    return r


def joint_path_speed(line: JointLine, max_speed: ArrayLike, speed_ratio: float) -> float:
    """[1/s] Max ``ds/dt`` on ``line``: ``ratio · min_i vmax_i / |Δq_i|``.

    The slowest axis relative to its own max speed sets the pace, so it alone
    runs at ``ratio · vmax_i``; the others are synchronised below theirs.
    ``inf`` when no axis moves more than :data:`NEGLIGIBLE_MOTION`.
    """
    vmax = np.asarray(max_speed, dtype=float)
    if vmax.shape != line.delta.shape:
        raise ProfileError(f"max_speed needs {line.delta.size} entries, got shape {vmax.shape}")
    if not np.all(np.isfinite(vmax)) or np.any(vmax <= 0.0):
        raise ProfileError("every max joint speed must be positive and finite")
    ratio = _check_ratio(speed_ratio)
    dist = np.abs(line.delta)
    moving = dist > NEGLIGIBLE_MOTION
    if not np.any(moving):
        return math.inf
    return ratio * float(np.min(vmax[moving] / dist[moving])) * line.length


def cartesian_path_speed(
    path: CartesianLine | CartesianArc,
    max_translation_speed: float,
    max_rotation_speed: float,
    speed_ratio: float,
    *,
    elbow_change: float = 0.0,
    max_elbow_speed: float = math.inf,
) -> float:
    """[1/s] Max ``ds/dt``: the slowest of translation, rotation and arm angle sets it.

    ``ratio · min(v_trans / translation_length, v_rot / rotation_angle, v_elbow / |elbow_change|)``,
    ignoring a part of at most :data:`NEGLIGIBLE_MOTION`; ``inf`` if all are.  ``elbow_change`` [rad]:
    how far a 7-axis arm's arm angle turns along the path (linearly in ``s``), ``max_elbow_speed``
    [rad/s] its limit (``elbow.py``): a move of the elbow alone takes time too.
    """
    vt = _positive("max_translation_speed", max_translation_speed)
    vr = _positive("max_rotation_speed", max_rotation_speed)
    ratio = _check_ratio(speed_ratio)
    bounds = []
    if path.translation_length > NEGLIGIBLE_MOTION:
        bounds.append(vt / path.translation_length)
    if path.rotation_angle > NEGLIGIBLE_MOTION:
        bounds.append(vr / path.rotation_angle)
    if abs(elbow_change) > NEGLIGIBLE_MOTION:
        bounds.append(_positive("max_elbow_speed", max_elbow_speed) / abs(elbow_change))
    if not bounds:
        return math.inf
    return ratio * min(bounds) * path.length


def plan_joint_ptp(
    q0: ArrayLike,
    q1: ArrayLike,
    max_speed: ArrayLike,
    speed_ratio: float,
    accel_time: float,
    *,
    jerk_fraction: float = 1.0,
) -> PathMotion:
    """PTP in joint space: a :class:`JointLine` and its synchronised profile.

    ``max_speed`` [rad/s or m/s per axis], ``speed_ratio`` in (0, 1],
    ``accel_time`` [s].  Axis ``i`` never exceeds ``ratio·vmax_i``; its peak
    acceleration is ``|Δq_i|·a <= ratio·vmax_i / (accel_time·(1 - f/2))``
    (``2·ratio·vmax_i/accel_time`` for the default S-curve), equality on the
    slowest axis.
    """
    line = JointLine(q0, q1)
    v = joint_path_speed(line, max_speed, speed_ratio)
    limits = ProfileLimits.from_accel_time(v, accel_time, jerk_fraction)
    return PathMotion(line, move_profile(line.length, limits, line.length if math.isinf(v) else 0.0))


def plan_cartesian(
    path: CartesianLine | CartesianArc,
    max_translation_speed: float,
    max_rotation_speed: float,
    speed_ratio: float,
    accel_time: float,
    *,
    jerk_fraction: float = 1.0,
) -> PathMotion:
    """LIN / CIRC: ``path`` with the profile whose slower part (translation [m/s]
    or rotation [rad/s], each at ``ratio × max``) sets the duration."""
    v = cartesian_path_speed(path, max_translation_speed, max_rotation_speed, speed_ratio)
    limits = ProfileLimits.from_accel_time(v, accel_time, jerk_fraction)
    return PathMotion(path, move_profile(path.length, limits, path.length if math.isinf(v) else 0.0))

