"""Traffic classes: the Zenoh priority and congestion control of every key, chosen per key.

Each key of :class:`~.keys.ArmKeys` names its class (the key table's ``traffic`` column). A link
sends its priorities from separate queues, highest first, so a class decides what overtakes what
when a link is busy; its congestion control decides what a full queue does to the sender:
``block`` waits (and so stalls whoever routes the message), ``drop`` loses the message.

The rule (docs/architecture.md, "Two routers", the bullet "Traffic classes per key"): only what keeps an arm safe and fed may block, and it
only ever travels between the cell's own services on the cell bus; the client gateway turns every
publication it forwards into ``drop`` (``launcher/up/gateway.py``), so no client can make anything wait.
"""

from __future__ import annotations

import dataclasses
import enum


@dataclasses.dataclass(frozen=True)
class TrafficClass:
    """What a key's messages are sent with. ``priority`` is Zenoh's name (``real_time`` ... ``background``)."""

    priority: str
    congestion: str  #: ``block`` or ``drop``
    express: bool  #: sent at once, never batched; else batched only while the link is backed up (Zenoh's adaptive batching)
    why: str


class Traffic(enum.Enum):
    """The traffic classes, highest priority first."""

    #: A low-level client's position commands (``Servo/posCmd``): a lost one is a gap in the servo's
    #: SyncFIFO, so it waits (towards the servo only: it never reaches a client as ``block``). And the
    #: planner's hand-overs and controls (``Servo/trajectory``, ``Servo/motionControl``, queries of the
    #: services only): a trajectory is up to ~200 kB, and dropped for a full queue it was lost whole
    #: (the planner waited 2 s for its reply and refused the motion). The command's ``Servo/power`` too:
    #: a servoOFF is never lost behind a busy link.
    STREAM = TrafficClass("real_time", "block", True,
                          "the arm's position commands: never lost, never behind anything")
    #: Evidence of health and alarms raised: a late heartbeat is a false "hung".
    SAFETY = TrafficClass("real_time", "drop", True,
                          "health and alarm evidence: ahead of everything; a lost beat is one of ten")
    #: What the monitor's detectors count (servo status), motion progress, alarm events.
    CONTROL = TrafficClass("interactive_high", "drop", True,
                           "what detectors and the queue bookkeeping read, 100 Hz at most")
    #: Queries and their replies (a reply travels with its query's priority and congestion control):
    #: behind safety, ahead of every stream a client may also subscribe to. Not express: a burst of
    #: replies to a gateway that is behind shares batches instead of taking one queue slot each.
    REPLY = TrafficClass("interactive_low", "drop", False,
                         "a call and its answer: a client's own streams never hold it up")
    #: State and settings: low rate, read by people and tools.
    STATE = TrafficClass("data_high", "drop", False, "low-rate state people and tools read")
    #: The 1 kHz feedback: for those who ask for it; a slow reader loses samples of its own.
    FEEDBACK = TrafficClass("data", "drop", True, "the 1 kHz stream: best effort per reader")
    #: Logs, loop health, paths, the world: for people.
    INFO = TrafficClass("data_low", "drop", False, "for people: logs, health, paths, the world model")
    #: Call traces: only while someone watches.
    TRACE = TrafficClass("background", "drop", False, "call traces for debugging: last of all")
