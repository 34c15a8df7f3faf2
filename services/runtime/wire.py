"""Payloads onto Zenoh in their key's encoding, labelled with it; samples read by their label.

Every publication and reply of the system carries its encoding
(``application/json`` or ``application/msgpack``), so that any tool can tell
which it got; a key's encoding is declared once, in ``schema/keys.py``
(:func:`~jara_arm.schema.keys.encoding_of`).
"""

from __future__ import annotations

from types import TracebackType
from typing import Any, TypeVar

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.encoding import Encoding
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import encoding_of
from jara_arm.schema.wire_types import StructType

T = TypeVar("T")

_LABELS = {Encoding.JSON: zenoh.Encoding.APPLICATION_JSON, Encoding.MSGPACK: zenoh.Encoding(Encoding.MSGPACK.value)}


def label(encoding: Encoding) -> zenoh.Encoding:
    """The Zenoh encoding label of ``encoding``."""
    return _LABELS[encoding]


def decode_sample(kind: StructType[T], sample: zenoh.Sample) -> T:
    """A sample's message, decoded by its encoding label (strict: WireError naming the field)."""
    value: T = codec.decode_message(kind, sample.payload.to_bytes(), Encoding.of(sample.encoding))
    return value


def reply_message(query: zenoh.Query, key: str, kind: StructType[T], value: T) -> None:
    """Answer ``query`` with ``value`` in ``key``'s encoding, labelled."""
    encoding = encoding_of(key)
    query.reply(key, codec.encode_message(kind, value, encoding), encoding=label(encoding))


class Publication:
    """A publisher of one key whose samples are in the key's encoding and labelled with it.

    ``expect`` is for a publisher that builds its payloads by hand in one
    encoding (the servo's MessagePack fast paths): it refuses to start if the
    schema says otherwise, rather than label one encoding as another.
    """

    def __init__(self, session: zenoh.Session, key: str, expect: Encoding | None = None, **options: Any) -> None:
        self.key = key
        self.encoding = encoding_of(key)
        if expect is not None and expect is not self.encoding:
            raise JaraArmError(f"{key} is {self.encoding.value} (schema/keys.py); this publisher writes {expect.value}")
        self._publisher = session.declare_publisher(key, encoding=label(self.encoding), **options)

    @property
    def publisher(self) -> zenoh.Publisher:
        """The Zenoh publisher (for its matching status); its puts are labelled already."""
        return self._publisher

    def put(self, payload: bytes) -> None:
        """Publish ``payload``, already in :attr:`encoding`."""
        self._publisher.put(payload)

    def put_message(self, kind: StructType[T], value: T) -> None:
        """Publish ``value`` encoded as the key's encoding says."""
        self._publisher.put(codec.encode_message(kind, value, self.encoding))

    def close(self) -> None:
        self._publisher.undeclare()

    def __enter__(self) -> Publication:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
