"""The two payload encodings of the wire, and how a payload's is told.

A Zenoh payload carries an encoding label (``application/json``,
``application/msgpack``, or none: ``zenoh/bytes``). Our own publications and
replies always set it. A request is read as JSON when its payload is a JSON
object, whatever its label says: generic tools (``z_get -p '{}'``) send JSON
text without any label. The payload's first byte tells the two apart: a JSON
object starts with ``{`` (0x7b, after optional ASCII whitespace), a MessagePack
map with 0x80-0x8f (fixmap), 0xde (map 16) or 0xdf (map 32), never with ``{``
(0x7b is the MessagePack positive fixint 123) nor with whitespace.
"""

from __future__ import annotations

import enum
import functools
import re

#: A JSON object: ``{`` after optional ASCII whitespace (RFC 8259 ``ws``).
_JSON_OBJECT = re.compile(rb"[ \t\r\n]*\{")


class Encoding(enum.Enum):
    """A payload codec; the value is its Zenoh encoding label."""

    MSGPACK = "application/msgpack"
    JSON = "application/json"

    @classmethod
    def of(cls, zenoh_encoding: object | None) -> Encoding:
        """The codec of a Zenoh encoding label: JSON for ``application/json``, else MessagePack."""
        return _encoding_of(str(zenoh_encoding or ""))

    @classmethod
    def of_request(cls, payload: bytes, zenoh_encoding: object | None) -> Encoding:
        """The codec a request is read, and answered, with: JSON if ``payload`` is a JSON object
        whatever its label; else its label's (so MessagePack labelled JSON is invalid JSON)."""
        return cls.JSON if is_json_object(payload) else cls.of(zenoh_encoding)


def is_json_object(payload: bytes) -> bool:
    """Whether ``payload`` starts as a JSON object does (never a MessagePack map); not a validation."""
    return _JSON_OBJECT.match(payload) is not None


@functools.lru_cache(maxsize=64)
def _encoding_of(text: str) -> Encoding:
    return Encoding.JSON if text.split(";", 1)[0] in ("application/json", "text/json") else Encoding.MSGPACK
