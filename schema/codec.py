"""Bytes on the wire <-> Python values, for requests, replies and messages.

MessagePack or JSON (:class:`~.encoding.Encoding` says which a payload is,
and how a request's is told). Decoding is strict (WIRE.md "Bad input"): any
defect raises :class:`WireError` naming the field, which a service answers
with ``VALUE_ERR``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Mapping
from typing import Any

import msgpack

from .codes import ReturnCode
from .encoding import Encoding as Encoding  # re-exported: the codec's argument
from .errors import WireError
from .operations import Operation
from .wire_types import LONG, STRING, StructType


def loads(payload: bytes, encoding: Encoding = Encoding.MSGPACK) -> Any:
    """Parse a payload; an empty one is an empty map. Raises WireError(``payload``)."""
    if not payload:
        return {}
    try:
        if encoding is Encoding.JSON:
            # NaN/Infinity tokens parse, so that the field holding them is named below.
            return json.loads(payload)
        return msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception as exc:  # every parser error is the client's
        hint = (" (it is a MessagePack map: label it application/msgpack, or leave the encoding unset)"
                if encoding is Encoding.JSON and _is_msgpack_map(payload) else "")
        raise WireError("payload", f"not valid {encoding.name}: {exc}{hint}") from None


def _is_msgpack_map(payload: bytes) -> bool:
    """Whether ``payload`` starts as a MessagePack map does: fixmap 0x80-0x8f, map 16 0xde, map 32 0xdf."""
    return bool(payload) and (0x80 <= payload[0] <= 0x8F or payload[0] in (0xDE, 0xDF))


def dumps(value: Any, encoding: Encoding = Encoding.MSGPACK) -> bytes:
    if encoding is Encoding.JSON:
        return json.dumps(value, separators=(",", ":"), allow_nan=False).encode()
    payload: bytes = msgpack.packb(value, use_bin_type=True)
    return payload


def decode_request(op: Operation, payload: bytes, encoding: Encoding = Encoding.MSGPACK) -> dict[str, Any]:
    """The ``in`` parameters of ``op`` by name, strictly checked."""
    if not payload and not op.inputs:
        return {}
    return decode_args(op, loads(payload, encoding))


def decode_args(op: Operation, value: Any) -> dict[str, Any]:
    """The ``in`` parameters of ``op`` from their wire form (a map already parsed), strictly checked."""
    if not isinstance(value, dict):
        raise WireError("payload", f"expected a map of the in parameters of {op.name}, "
                        f"got {type(value).__name__}")
    names = [p.name for p in op.inputs]
    for key in value:
        if key not in names:
            valid = ", ".join(names) if names else "none"
            raise WireError(str(key), f"unexpected parameter of {op.name}; valid parameters: {valid}")
    args = {}
    for p in op.inputs:
        if p.name not in value:
            raise WireError(p.name, f"missing parameter of {op.name}")
        args[p.name] = p.type.decode(value[p.name], p.name)
    return args


def encode_request(op: Operation, args: Mapping[str, Any] | None = None,
                   encoding: Encoding = Encoding.MSGPACK) -> bytes:
    """A request for ``op``; ``args`` holds Python values or their wire form (maps for structs)."""
    return dumps(encode_args(op, args or {}), encoding)


def encode_args(op: Operation, args: Mapping[str, Any]) -> dict[str, Any]:
    """The ``in`` parameters of ``op`` in wire form (a map, not yet serialised): the inverse of
    :func:`decode_args`; ``args`` holds Python values or their wire form."""
    names = [p.name for p in op.inputs]
    extra = set(args) - set(names)
    if extra:
        raise WireError(sorted(extra)[0], f"unexpected parameter of {op.name}; valid: {names}")
    out: dict[str, Any] = {}
    for p in op.inputs:
        if p.name not in args:
            raise WireError(p.name, f"missing parameter of {op.name}")
        out[p.name] = p.type.encode(args[p.name])
    return out


@dataclasses.dataclass(frozen=True)
class Reply:
    """``RETURN_ID`` plus the ``out`` parameters (present only when ``id == OK``)."""

    id: int
    comment: str
    outs: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.id == ReturnCode.OK

    def __getitem__(self, name: str) -> Any:
        return self.outs[name]


def encode_reply(op: Operation, reply: Reply, encoding: Encoding = Encoding.MSGPACK) -> bytes:
    out: dict[str, Any] = {"id": int(reply.id), "comment": reply.comment}
    if reply.id == ReturnCode.OK:
        for p in op.outputs:
            out[p.name] = p.type.encode(reply.outs[p.name])
    return dumps(out, encoding)


def decode_reply(op: Operation, payload: bytes, encoding: Encoding = Encoding.MSGPACK) -> Reply:
    """A reply to ``op``, strictly checked; ``outs`` hold Python values."""
    value = loads(payload, encoding)
    if not isinstance(value, dict):
        raise WireError("payload", "a reply must be a map")
    code = LONG.decode(value.get("id"), "id")
    comment = STRING.decode(value.get("comment"), "comment")
    outs = {}
    if code == ReturnCode.OK:
        for p in op.outputs:
            if p.name not in value:
                raise WireError(p.name, f"missing out parameter of {op.name}")
            outs[p.name] = p.type.decode(value[p.name], p.name)
    return Reply(code, comment, outs)


def encode_message(kind: StructType[Any], value: Any, encoding: Encoding = Encoding.MSGPACK) -> bytes:
    return dumps(kind.encode(value), encoding)


def decode_message(kind: StructType[Any], payload: bytes, encoding: Encoding = Encoding.MSGPACK) -> Any:
    return kind.decode(loads(payload, encoding), "")


def deadline_attachment(timeout: float) -> bytes:
    """The attachment of a query whose requester waits ``timeout`` [s]: ``{"deadline": <wall time [s]>}``.

    A service that takes the query up after its deadline (it was stopped, or
    starved, while the query waited in its queue) drops it unanswered rather
    than act on a request its requester already gave up on. WIRE.md does not
    speak of attachments: this one is ours, used between our services; a
    query without it is always answered.
    """
    payload: bytes = msgpack.packb({"deadline": time.time() + timeout}, use_bin_type=True)
    return payload


def attachment_deadline(attachment: bytes | None) -> float | None:
    """The deadline [s, wall time] in a query's attachment; None if there is none or it is not one."""
    if not attachment:
        return None
    try:
        value = msgpack.unpackb(attachment, raw=False)
    except Exception:
        return None
    deadline = value.get("deadline") if isinstance(value, dict) else None
    if isinstance(deadline, bool) or not isinstance(deadline, (int, float)) or not math.isfinite(deadline):
        return None
    return float(deadline)
