"""The liveliness tokens and heartbeats of watched services, taken in the order they arrived.

A service that shuts down in order sends its ``leaving`` beat, then deletes its
token (``Heartbeat.leave``). A watcher that drained its token samples before
its heartbeats met the deletion before the beat that came ahead of it whenever
its thread was held up for longer than ``LEAVE_GRACE`` (a busy machine): a
false "lost" FAULT for a launcher that stops (a fresh-clone CI run, 0x402).
Here both subscriptions feed one :class:`~.inbox.Box`, so a deletion is judged
with every beat that came before it already heard, and a new process's token
and beats come after the old one's departure.
"""

from __future__ import annotations

import dataclasses
import enum

import zenoh

from jara_arm.schema.alarms import HEARTBEAT
from jara_arm.schema.errors import JaraArmError, WireError
from jara_arm.schema.keys import ArmKeys, Service, parse_alive, parse_heartbeat

from .entities import Entities
from .heartbeat import ServiceWatch
from .inbox import Inbox
from .wire import decode_sample


class Change(enum.Enum):
    """What one sample changed in a watch."""

    UP = "up"  # its token appeared
    LEFT = "left"  # its token went after its leaving beat: an orderly shutdown
    LOST = "lost"  # its token went without a leaving beat: the process ended or is unreachable
    STALL = "stall"  # a beat ended a silence longer than ``stall_after`` (``gap``)
    MALFORMED = "malformed"  # a heartbeat that does not decode (``error``)


@dataclasses.dataclass(frozen=True)
class Event:
    """A change of one watched service, for the watcher to log or raise."""

    watch: ServiceWatch
    change: Change
    gap: float = 0.0  # [s] the silence a STALL ended
    error: str = ""  # why a MALFORMED beat was ignored


class Presence:
    """Tokens and heartbeats of ``watches``' services of one arm, in arrival order, until :meth:`close`."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, watches: dict[Service, ServiceWatch],
                 inbox: Inbox | None = None, capacity: int = 1024) -> None:
        """``inbox``: the watcher's, whose thread a sample wakes; none for a watcher that polls."""
        self.watches = watches
        self._box = (inbox or Inbox()).box(capacity)
        self._entities = Entities()
        enter = self._entities.enter_context
        # One token key per service, not ``alive/*``: a watcher hears no other service's token changes.
        for service in watches:
            enter(session.liveliness().declare_subscriber(keys.alive(service), self._box, history=True))
            enter(session.declare_subscriber(keys.heartbeat(service), self._box))

    def drain(self, now: float) -> list[Event]:
        """Everything that arrived, oldest first, taken into the watches at ``now`` [s]; what changed."""
        events: list[Event] = []
        while (sample := self._box.try_recv()) is not None:
            key = str(sample.key_expr)
            try:
                _arm, name = parse_heartbeat(key)
            except JaraArmError:
                self._token(sample, key, now, events)
                continue
            watch = self._watch(name)
            if watch is None:
                continue
            try:
                beat = decode_sample(HEARTBEAT, sample)
            except WireError as exc:
                events.append(Event(watch, Change.MALFORMED, error=str(exc)))
                continue
            gap = watch.heard(now, beat.stuck, beat.leaving, beat.pid, beat.host, beat.tid)
            if gap is not None:
                events.append(Event(watch, Change.STALL, gap=gap))
        return events

    def _token(self, sample: zenoh.Sample, key: str, now: float, events: list[Event]) -> None:
        try:
            _arm, name = parse_alive(key)
        except JaraArmError:
            return
        watch = self._watch(name)
        if watch is None:
            return
        up = sample.kind == zenoh.SampleKind.PUT
        if watch.token(up, now):
            events.append(Event(watch, Change.LEFT if watch.leaving else Change.LOST))
        elif up:
            events.append(Event(watch, Change.UP))

    def _watch(self, name: str) -> ServiceWatch | None:
        try:
            return self.watches.get(Service(name))
        except ValueError:
            return None  # someone else's key under our prefix

    def close(self) -> None:
        self._entities.close()

    def __enter__(self) -> Presence:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["Change", "Event", "Presence"]
