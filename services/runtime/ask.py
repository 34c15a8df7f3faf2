"""Ask another service: the one way a service (or a client) sends a query and reads its reply.

An :class:`Asker` is a Zenoh ``Querier`` on one key: the query carries its
deadline (``codec.deadline_attachment``), so that a service that was held up
drops it instead of acting late; the reply is the first good one; and "nobody
serves this key" comes from the querier's matching status, not from guessing
by how fast the timeout came.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Iterator
from typing import Any

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.codec import Encoding

from .entities import Entities
from .wire import query_qos

log = logging.getLogger(__name__)

#: A new querier learns which queryables match from the router within a round trip; until
#: then, an empty matching status is not yet evidence that nobody serves the key [s].
MATCHING_SETTLE = 1.0


@dataclasses.dataclass(frozen=True)
class Answer:
    """One good reply: its key, payload and encoding."""

    key: str
    payload: bytes
    encoding: Encoding


@dataclasses.dataclass(frozen=True)
class Silence:
    """No good reply, and why: ``nobody`` serves the key, or none came within the timeout,
    or the query failed (``why`` says which, naming the key)."""

    why: str
    nobody: bool = False


class Asker:
    """Queries on ``key`` (which may have wildcards), each waiting at most ``timeout`` [s]."""

    def __init__(self, session: zenoh.Session, key: str, timeout: float,
                 target: zenoh.QueryTarget = zenoh.QueryTarget.BEST_MATCHING) -> None:
        self.key = key
        self.timeout = timeout
        self._entities = Entities()
        self._querier = self._entities.enter_context(session.declare_querier(key, target=target, timeout=timeout,
                                                                             **query_qos(key)))
        self._declared = time.monotonic()

    def served(self) -> bool:
        """Whether a queryable serves the key now (Zenoh's matching status)."""
        try:
            status: Any = self._querier.matching_status  # the stub says bool; it is a MatchingStatus
            return bool(status.matching)
        except zenoh.ZError:  # the session is closing
            return False

    def _nobody(self) -> bool:
        """Nobody serves the key, and the querier is old enough to know it."""
        return time.monotonic() - self._declared > MATCHING_SETTLE and not self.served()

    def _answers(self, payload: bytes) -> Iterator[Answer]:
        """The good replies as they come (an error reply is logged); raises ``zenoh.ZError``."""
        for reply in self._querier.get(payload=payload, attachment=codec.deadline_attachment(self.timeout)):
            if reply.ok is None:
                log.warning("%s answered with an error: %s", self.key, reply.err)
                continue
            yield Answer(str(reply.ok.key_expr), reply.ok.payload.to_bytes(), Encoding.of(reply.ok.encoding))

    def ask(self, payload: bytes = b"") -> Answer | Silence:
        """The first good reply to ``payload``, or why there is none."""
        if self._nobody():
            return Silence(f"nobody serves {self.key}: is the service running?", nobody=True)
        try:
            for answer in self._answers(payload):
                return answer
        except zenoh.ZError as exc:
            return Silence(f"the query on {self.key} failed: {exc}")
        if not self.served():
            return Silence(f"nobody serves {self.key}: is the service running?", nobody=True)
        return Silence(f"no answer on {self.key} within {self.timeout:g} s")

    def ask_all(self, payload: bytes = b"") -> list[Answer]:
        """Every good reply (for a key served by several services) within the timeout."""
        if self._nobody():
            return []
        answers: list[Answer] = []
        try:
            answers.extend(self._answers(payload))
        except zenoh.ZError as exc:
            log.warning("the query on %s failed: %s", self.key, exc)
        return answers

    def close(self) -> None:
        self._entities.close()
