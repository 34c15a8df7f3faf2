"""The timing budget: every figure the system's timing depends on, decided once.

Two kinds of detection, kept apart (``docs/timing.md`` gives the reasons):

* **At stake, inside the servo**: what endangers the arm is decided by the
  servo loop from its own inputs, within a few cycles (e-stop, a jumping
  command, a joint soft limit, a stream that runs dry mid-motion). These
  figures do not depend on the network and are not settings.
* **Health across processes and hosts**: a service gone (its liveliness token
  deleted) or silent (its heartbeat not heard). A short stall of a live
  process on a busy machine is not a fault: it is logged as a *stall* with
  its length. Only silence past :attr:`Health.hung_after` is a hung FAULT.
  These figures depend on where the services run, so they come as a
  :class:`Health` profile (``--timing same-host|lan``, ``--hung-after S``).

Every figure carries its unit in brackets and why it has its value.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Final

# -- at stake: decided inside the servo, in cycles of cmdCycle -------------------------

#: Cycles the simulated servo waits, mid-motion, for a late command of a low-level client's
#: stream (``Servo/posCmd``) before it stops the arm as for a dry FIFO [cycles]; simulated
#: time stands still meanwhile. Such a stream crosses the network one command per cycle,
#: and 10 ms covers a scheduling hiccup of the client or the router. The planner's motions
#: never need it: the servo interpolates them from its own buffer (``servo/interpolator.py``).
UNDERRUN_GRACE: Final = 10
#: Behind schedule by more than this, the servo loop stops catching up and restarts its
#: clock [s]: catching up 100 cycles back to back would step the arm 100 times at once.
RESYNC_AFTER: Final = 0.1
#: A LIN / CIRC from rest may run this much of its motion [s] before the whole of it is
#: planned and checked (the early start): its first command goes out after its first knot
#: interval, not all of them. The servo runs such a head slowed down so that it could still
#: slow to 0 before its end (``servo/interpolator.head_cap``): a rest planned late slows the
#: arm, never stops it. A jerk-limited start covers ~0.1 mm in 30 ms and slowing down from
#: there ~1.2 mm more: 1.31 mm in all for the 0.5 m LIN at 0.25 m/s at the iiwa's shortest
#: acceleration time, what a motion refused late can have moved.
EARLY_START: Final = 0.03
#: Servo/status (measured speeds, efforts, joints) every this many cycles [cycles]: the
#: alarm monitor's overload (3 samples) and overspeed (2 samples) detectors count these.
STATUS_EVERY: Final = 10
#: ... and every this many while the arm is settled at rest [cycles], and at once on any
#: change of servo power, alarm, FIFO, target or soft limits: nothing else changes then.
STATUS_EVERY_AT_REST: Final = 100
#: Servo/posFeedbackBlock: the posFeedback samples of this many cycles in one message [cycles], while a
#: client gateway takes them. The cell bus then carries 100 messages a second per arm instead of 1,000,
#: on its real-time side, whoever subscribes through it (and none while no client does); the price is up to this many periods more latency for a
#: client of the gateway (docs/architecture.md, "Feedback in blocks").
FEEDBACK_BLOCK_CYCLES: Final = 10
#: Servo/health (the loop's timing statistics) this often [s].
HEALTH_EVERY: Final = 1.0

# -- polling periods of the services' own threads ------------------------------------

#: The alarm monitor drains its inputs as each arrives (``runtime/inbox.py``), and at least this
#: often [s], to judge the services' silences (heartbeats every 0.1 s; a silence is warned of past
#: 0.25 s): up to this much later than a 10 ms poll said it.
MONITOR_WAIT: Final = 0.05
#: The command service's state watcher drains its inputs when one arrives, at most this often [s]
#: (a call's catch-up drains at once: getState never waits on it).
WATCHER_POLL: Final = 0.01
#: ... and at least this often [s], to say off a servo silent past the hung bound (``command/state.py``).
WATCHER_WAIT: Final = 0.1
#: A motion request listens this long for a ``Servo/status`` before it says none came [s] (the
#: command's state and the planner's start point): on a saturated machine the asker's own receiving
#: threads can be the ones held up (8 arms on 2 cores: moves refused for "no Servo/status" while
#: the servo published on time). A servo really gone is the alarm monitor's to report (0x410); this
#: only delays the refusal of a move sent to a silent servo.
STATUS_LISTEN: Final = 0.5
#: After the planner said a motion done, ``getFeedbackPosJoint`` / ``getFeedbackPosCartesian`` wait this long
#: at most for a ``Servo/status`` stamped then or later [s]: the pose the motion ended at, not one from
#: before its end still newest here. At rest the servo publishes every 100 ms, and at once when it stops
#: moving; a servo on another host whose clock is behind by more than this makes the read wait this long.
#: 0.3 s until 2026-12-05: with the command silent 629 ms beside busy loops, the demo read a CIRC 13.7 mm
#: short of the end it reached (fresh-clone run 160); a pause of the whole host outlasts a short window.
ARRIVAL_LISTEN: Final = 1.0
#: While the servo slows down for a stop, the planner waits at most this long to learn where the
#: arm stopped before it plans the next motion from there [s]: a stop from full speed takes
#: about a min accel time (0.2-0.5 s for the robot models here).
STOP_WAIT: Final = 2.0

# -- queries between services ---------------------------------------------------------

#: The servo has this long to answer a forwarded query [s].
SERVO_TIMEOUT: Final = 2.0
#: The planner has this long to plan one motion [s] (IK along a long CIRC takes ~1 s).
PLAN_TIMEOUT: Final = 5.0
#: The planner has this long to answer pause/resume/stop/abort [s].
CONTROL_TIMEOUT: Final = 2.0
#: The alarm monitor has this long to answer [s]; it answers from memory. A monitor that
#: does not answer is left out (the servo's and the command's own alarms answer instead).
MONITOR_TIMEOUT: Final = 0.3
#: A forwarded query still waiting this long past its requester's deadline is dropped, not
#: acted on [s]: a service that was held up must not act on what its caller gave up on.
DEADLINE_GRACE: Final = 0.05


# -- health across processes ----------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Health:
    """How services judge each other's liveness: one profile for the whole system."""

    name: str
    #: Every service beats this often [s]: ten beats per hung bound at least.
    heartbeat_period: float
    #: A heartbeat that comes after a silence longer than this is logged as a stall [s].
    stall_after: float
    #: Token up, heartbeat silent longer than this: hung FAULT (0x410-0x413) [s].
    hung_after: float
    #: A service just up gets this long for its first beat to arrive [s] (a new subscriber
    #: through a router hears first beats late; a service importing its libraries is slow).
    first_beat_grace: float

    def __post_init__(self) -> None:
        for field in ("heartbeat_period", "stall_after", "hung_after", "first_beat_grace"):
            if not getattr(self, field) > 0.0:
                raise ValueError(f"{field} must be a positive number of seconds, got {getattr(self, field)!r}")
        if not self.heartbeat_period < self.stall_after < self.hung_after:
            raise ValueError(f"need heartbeat_period < stall_after < hung_after [s], got "
                             f"{self.heartbeat_period} < {self.stall_after} < {self.hung_after}")

    def with_hung_after(self, seconds: float) -> Health:
        """This profile with another hung bound [s]; the stall bound scales down with it if needed."""
        stall = min(self.stall_after, seconds / 2)
        return dataclasses.replace(self, hung_after=seconds, stall_after=stall,
                                   heartbeat_period=min(self.heartbeat_period, stall / 2))


#: Every service on one host. The hung bound is 1.5 s: far above the longest stall of a live
#: service measured under a CPU hog on every core (bench/soak.py, docs/timing.md), and below
#: SERVO_TIMEOUT, so the alarm names the cause before a client's query times out.
SAME_HOST: Final = Health("same-host", heartbeat_period=0.1, stall_after=0.25, hung_after=1.5,
                          first_beat_grace=5.0)
#: Services on several hosts of one LAN: a switch's or Wi-Fi bridge's hiccup and TCP's
#: retransmission (200 ms minimum RTO on Linux, doubled on a second loss) fit within 5 s.
LAN: Final = Health("lan", heartbeat_period=0.2, stall_after=1.0, hung_after=5.0, first_beat_grace=10.0)

PROFILES: Final = {p.name: p for p in (SAME_HOST, LAN)}
DEFAULT_PROFILE: Final = SAME_HOST.name


def health(profile: str = DEFAULT_PROFILE, hung_after: float | None = None) -> Health:
    """The named profile, optionally with another hung bound [s]."""
    try:
        chosen = PROFILES[profile]
    except KeyError:
        raise ValueError(f"unknown timing profile {profile!r}; choose one of {', '.join(PROFILES)}") from None
    return chosen if hung_after is None else chosen.with_hung_after(hung_after)


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not 0.0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number of seconds, got {text}")
    return value


def add_health_arguments(parser: argparse.ArgumentParser) -> None:
    """``--timing`` and ``--hung-after``: shared by every service and the launcher."""
    g = parser.add_argument_group("timing")
    g.add_argument("--timing", default=DEFAULT_PROFILE, choices=list(PROFILES),
                   help=f"health profile: {', '.join(f'{p.name} (hung after {p.hung_after:g} s)' for p in PROFILES.values())}"
                   f" (default: {DEFAULT_PROFILE})")
    g.add_argument("--hung-after", type=_seconds, metavar="S",
                   help="a service whose heartbeat is silent this long is hung [s] (default: the profile's)")


def health_from_args(args: argparse.Namespace) -> Health:
    return health(args.timing, args.hung_after)


def health_argv(h: Health) -> list[str]:
    """The command-line form of ``h``, to pass it on to a child process."""
    base = PROFILES[h.name]
    return ["--timing", h.name] + ([] if h.hung_after == base.hung_after else ["--hung-after", repr(h.hung_after)])
