"""What the read-only tools (``jara-arm view``, ``ros2``) do with their subscriptions: each a channel that
their one loop drains, the newest item taken, every message decoded by its encoding label."""

from __future__ import annotations

import logging
from collections.abc import Iterable
from typing import Any

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.codec import Encoding
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.wire_types import StructType

log = logging.getLogger(__name__)


def decode(kind: StructType[Any], sample: zenoh.Sample | zenoh.Reply) -> Any:
    """A sample's (or a reply's) message by its encoding label, or None (logged) if malformed or an error."""
    if isinstance(sample, zenoh.Reply):
        if sample.ok is None:
            return None
        sample = sample.ok
    payload = sample.payload.to_bytes()
    try:
        return codec.decode_message(kind, payload, Encoding.JSON if payload.lstrip()[:1] == b"{"
                                    else Encoding.of(sample.encoding))
    except JaraArmError as exc:
        log.warning("ignored a malformed %s on %s: %s", kind.name, sample.key_expr, exc)
        return None


def newest(channel: Any) -> Any:
    """The newest item a handler holds (all of them taken), or None."""
    item = latest = channel.try_recv()
    while item is not None:
        latest = item
        item = channel.try_recv()
    return latest


def undeclare(entities: Iterable[Any]) -> None:
    """Undeclare subscribers, publishers, tokens; those of a session already closed are gone anyway."""
    for entity in entities:
        try:
            entity.undeclare()
        except zenoh.ZError:
            pass


__all__ = ["decode", "newest", "undeclare"]
