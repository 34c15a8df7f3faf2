"""Reading an arm's state for people and scripts: state bits by name, and the queue from ``state``.

Shared by ``jara-arm state`` and ``jara-arm wait``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from jara_arm.schema import codec
from jara_arm.schema.codec import Encoding
from jara_arm.schema.codes import StateBit
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.messages import STATE_MESSAGE


def state_names(bits: int) -> str:
    """``SERVO_ON|MOVING`` for 0x03; ``none`` for 0; an unknown bit as its hex value."""
    names = [b.name for b in StateBit if bits & b and b.name]
    unknown = bits & ~sum(int(b) for b in StateBit)
    if unknown:
        names.append(f"0x{unknown:02x}")
    return "|".join(names) or "none"


def format_state(bits: int) -> str:
    """``0x03 SERVO_ON|MOVING``."""
    return f"0x{bits:02x} {state_names(bits)}"


def sample_encoding(payload: bytes, zenoh_encoding: object | None) -> Encoding:
    """How to read a sample: as its encoding says, and JSON whatever it says when the payload starts
    like a JSON document (``{`` or ``[``; no MessagePack map or array does)."""
    if payload.lstrip()[:1] in (b"{", b"["):
        return Encoding.JSON
    return Encoding.of(zenoh_encoding)


@dataclasses.dataclass(frozen=True)
class PublishedState:
    """One ``state`` publication: the bits and, when the publisher adds them, the queue."""

    state: int
    queue_length: int | None  # motions in the queue
    queue_capacity: int | None  # motions it holds before FULL_MOTION_QUEUE_ERR


def _count(body: Any, name: str) -> int | None:
    value = body.get(name) if isinstance(body, dict) else None
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 0 else None


def read_state(payload: bytes, zenoh_encoding: object | None) -> PublishedState:
    """A ``state`` sample (``StateMessage``, whose extra members may carry the queue); raises JaraArmError."""
    encoding = sample_encoding(payload, zenoh_encoding)
    body = codec.loads(payload, encoding)
    message = STATE_MESSAGE.decode(body, "")
    if not isinstance(body, dict):  # decode took it, so it is a map; say so to the type checker
        raise JaraArmError("a state message must be a map")
    # The queue members are extras of StateMessage (the command service adds them): read by name.
    return PublishedState(message.state, _count(body, "queueLength"), _count(body, "queueCapacity"))
