"""Payloads onto Zenoh in their key's encoding, labelled with it; samples read by their label.

Every publication and reply of the system carries its encoding
(``application/json`` or ``application/msgpack``), so that any tool can tell
which it got; a key's encoding is declared once, in ``schema/keys.py``
(:func:`~jara_arm.schema.keys.encoding_of`), and so is its traffic class (priority and
congestion control, :func:`~jara_arm.schema.keys.traffic_of`), which every publisher and
reply here is declared with.
"""

from __future__ import annotations

from types import TracebackType
from typing import Any, TypeVar

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.encoding import Encoding
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import encoding_of, traffic_of
from jara_arm.schema.traffic import Traffic
from jara_arm.schema.wire_types import StructType

T = TypeVar("T")

_LABELS = {Encoding.JSON: zenoh.Encoding.APPLICATION_JSON, Encoding.MSGPACK: zenoh.Encoding(Encoding.MSGPACK.value)}


def label(encoding: Encoding) -> zenoh.Encoding:
    """The Zenoh encoding label of ``encoding``."""
    return _LABELS[encoding]


_PRIORITIES = {"real_time": zenoh.Priority.REAL_TIME, "interactive_high": zenoh.Priority.INTERACTIVE_HIGH,
               "interactive_low": zenoh.Priority.INTERACTIVE_LOW, "data_high": zenoh.Priority.DATA_HIGH,
               "data": zenoh.Priority.DATA, "data_low": zenoh.Priority.DATA_LOW,
               "background": zenoh.Priority.BACKGROUND}
_CONGESTION = {"block": zenoh.CongestionControl.BLOCK, "drop": zenoh.CongestionControl.DROP}


def qos(traffic: Traffic) -> dict[str, Any]:
    """Zenoh's ``priority``, ``congestion_control`` and ``express`` options of ``traffic``."""
    c = traffic.value
    return {"priority": _PRIORITIES[c.priority], "congestion_control": _CONGESTION[c.congestion],
            "express": c.express}


def query_qos(key: str) -> dict[str, Any]:
    """The options of a querier on ``key``: its traffic class (``Traffic.REPLY`` for a key outside the table).
    A reply travels with its query's priority and congestion control (Zenoh decides so), so the querier
    chooses both; the client gateway sets every client's queries to ``drop`` (launcher/up/gateway.py)."""
    try:
        return qos(traffic_of(key))
    except JaraArmError:
        return qos(Traffic.REPLY)


def reply(query: zenoh.Query, key: str, body: bytes, encoding: Encoding) -> None:
    """Answer ``query`` on ``key`` with ``body`` (in ``encoding``), labelled, sent at once (express)."""
    query.reply(key, body, encoding=label(encoding), express=traffic_of(key).value.express)


def decode_sample(kind: StructType[T], sample: zenoh.Sample) -> T:
    """A sample's message, decoded by its encoding label (strict: WireError naming the field)."""
    value: T = codec.decode_message(kind, sample.payload.to_bytes(), Encoding.of(sample.encoding))
    return value


def reply_message(query: zenoh.Query, key: str, kind: StructType[T], value: T) -> None:
    """Answer ``query`` with ``value`` in ``key``'s encoding, labelled."""
    encoding = encoding_of(key)
    reply(query, key, codec.encode_message(kind, value, encoding), encoding)


class Publication:
    """A publisher of one key whose samples are in the key's encoding and labelled with it, sent with the
    key's traffic class (``options`` override it: a test's or a tool's own choice).

    ``expect`` is for a publisher that builds its payloads by hand in one
    encoding (the servo's MessagePack fast paths): it refuses to start if the
    schema says otherwise, rather than label one encoding as another.
    """

    def __init__(self, session: zenoh.Session, key: str, expect: Encoding | None = None, **options: Any) -> None:
        self.key = key
        self.encoding = encoding_of(key)
        if expect is not None and expect is not self.encoding:
            raise JaraArmError(f"{key} is {self.encoding.value} (schema/keys.py); this publisher writes {expect.value}")
        # The key's traffic class unless told otherwise.
        self._publisher = session.declare_publisher(key, encoding=label(self.encoding),
                                                    **(qos(traffic_of(key)) | options))

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
