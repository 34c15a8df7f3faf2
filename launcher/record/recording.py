"""A recording: the samples of ``JARA_ARM/<arm>/**`` in an MCAP file, and how to read it back.

The file is plain MCAP, written and read with the ``mcap`` library, so that
the ``mcap`` CLI and Foxglove open it:

* one channel per key (its topic is the key, e.g. ``JARA_ARM/arm0/Servo/posFeedback``),
  with message encoding ``json``;
* one schema per channel, encoding ``jsonschema``: the key's message type from
  ``schema/`` standing alone (``schema.channels.channel_schema``); keys outside
  the key table get no schema (id 0);
* each message is the sample's value as a JSON object, whatever its encoding on
  the wire (MessagePack samples are transcoded; :func:`to_json`);
  ``log_time`` is when the recorder received it, ``publish_time`` the sample's
  Zenoh timestamp (else the receive time) [ns since the Unix epoch].

Readers (``plot``, ``view``, ``replay``) use :func:`read_messages`,
:func:`arms`, :func:`keys` and :func:`info`; a file that is missing, not MCAP or
cut short raises :class:`RecordingError` with a readable message.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import IO, Any

import zenoh
from mcap.exceptions import McapError
from mcap.reader import McapReader, NonSeekingReader, make_reader
from mcap.writer import Writer

from jara_arm.schema.channels import channel_schema
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import arm_of

from ..tools.echo import decode_payload

MESSAGE_ENCODING = "json"
SCHEMA_ENCODING = "jsonschema"
LIBRARY = "jara-arm"


class RecordingError(JaraArmError):
    """A recording that cannot be written or read: the message says which file and why."""


@dataclasses.dataclass(frozen=True)
class Recorded:
    """One recorded sample."""

    key: str  #: the full key, e.g. ``JARA_ARM/arm0/Servo/posFeedback``
    t: float  #: [s] Unix time the recorder received it (the MCAP log_time)
    value: dict[str, Any]  #: the sample's value as a JSON object (the message in its wire form)


@dataclasses.dataclass(frozen=True)
class Info:
    """What a recording holds."""

    start: float  #: [s] Unix time of the first message (0 if none)
    end: float  #: [s] Unix time of the last message (0 if none)
    counts: dict[str, int]  #: messages per key

    @property
    def messages(self) -> int:
        return sum(self.counts.values())

    @property
    def arms(self) -> list[str]:
        return sorted({_arm(k) for k in self.counts} - {""})


def _jsonable(value: Any) -> Any:
    """``value`` with what JSON cannot hold replaced: binaries as hex, non-finite floats as None."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).hex()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def to_json(payload: bytes, encoding: object | None) -> bytes:
    """A sample's payload as the JSON object a recording holds: decoded by its encoding label (JSON,
    MessagePack, text; ``launcher.echo.decode_payload``); an empty payload is ``{}``, a value that is
    not a map ``{"payload": value}``, one that nothing decodes ``{"payload": its bytes as hex}``."""
    if not payload:
        return b"{}"
    try:
        value = decode_payload(payload, encoding)
    except JaraArmError:
        value = payload.hex()
    if not isinstance(value, dict):
        value = {"payload": value}
    try:  # the common case, at C speed: a wire map of finite numbers, strings, lists
        return json.dumps(value, separators=(",", ":"), allow_nan=False).encode()
    except (TypeError, ValueError):
        return json.dumps(_jsonable(value), separators=(",", ":"), allow_nan=False).encode()


def _arm(key: str) -> str:
    try:
        return arm_of(key)
    except JaraArmError:
        return ""


class RecordingWriter:
    """An MCAP file being written: a channel and a schema registered at a key's first message."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self._stream: IO[bytes] = open(path, "wb")
        except OSError as exc:
            raise RecordingError(f"cannot write {path}: {exc.strerror or exc}") from None
        self._writer = Writer(self._stream)
        self._writer.start(profile="", library=LIBRARY)
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self.count = 0  #: messages written
        self._size = 0  # once closed

    @property
    def size(self) -> int:
        """[bytes] written to the file so far (a chunk reaches it when full, about 1 MiB)."""
        return self._size if self._stream.closed else self._stream.tell()

    @property
    def channels(self) -> int:
        return len(self._channels)

    def _channel(self, key: str) -> int:
        channel = self._channels.get(key)
        if channel is None:
            try:
                name, schema = channel_schema(key)
            except JaraArmError:  # not a key of the contract: recorded, without a schema
                schema_id = 0
            else:
                if name not in self._schemas:
                    self._schemas[name] = self._writer.register_schema(name, SCHEMA_ENCODING, schema)
                schema_id = self._schemas[name]
            channel = self._channels[key] = self._writer.register_channel(key, MESSAGE_ENCODING, schema_id)
        return channel

    def write(self, key: str, log_time: int, publish_time: int, data: bytes) -> None:
        """One message: ``data`` a JSON object (:func:`to_json`), times [ns since the Unix epoch]."""
        self._writer.add_message(self._channel(key), log_time=log_time, data=data, publish_time=publish_time)
        self.count += 1

    def close(self) -> None:
        """Write the summary (index, statistics) and close the file."""
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]  # mcap leaves it unannotated
        finally:
            self._size = self._stream.tell()
            self._stream.close()


def _open(path: Path | str) -> tuple[IO[bytes], McapReader]:
    path = Path(path)
    try:
        stream: IO[bytes] = open(path, "rb")
    except OSError as exc:
        raise RecordingError(f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        return stream, make_reader(stream)
    except (McapError, EOFError, ValueError) as exc:
        stream.close()
        raise RecordingError(f"{path} is not an MCAP recording: {exc or type(exc).__name__}") from None


def _matcher(patterns: Sequence[str] | None) -> Any:
    """``topic -> bool``: whether a key meets one of ``patterns`` (key expressions; None: all)."""
    if patterns is None:
        return lambda _topic: True
    try:
        exprs = [zenoh.KeyExpr(p) for p in patterns]
    except zenoh.ZError as exc:
        raise RecordingError(f"not a key expression among {list(patterns)}: {exc}") from None
    seen: dict[str, bool] = {}

    def meets(topic: str) -> bool:
        if topic not in seen:
            try:
                seen[topic] = any(e.intersects(zenoh.KeyExpr(topic)) for e in exprs)
            except zenoh.ZError:
                seen[topic] = False
        return seen[topic]
    return meets


def read_messages(path: Path | str, keys: Sequence[str] | None = None) -> Iterator[Recorded]:
    """The messages of the recording at ``path`` in the order they were received, only those on
    keys that meet one of ``keys`` (full key expressions: ``JARA_ARM/arm0/Servo/posFeedback``,
    ``JARA_ARM/*/state``, ``JARA_ARM/arm0/**``; None: every key). Raises RecordingError."""
    stream, reader = _open(path)
    meets = _matcher(keys)
    try:
        summary = _summary(reader)
        topics = None
        if summary is not None:
            topics = [c.topic for c in summary.channels.values() if meets(c.topic)]
            if not topics:
                return
        for _schema, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
            if topics is None and not meets(channel.topic):
                continue
            try:
                value = json.loads(message.data)
            except ValueError as exc:
                raise RecordingError(f"{path}: a message on {channel.topic} is not JSON: {exc}") from None
            yield Recorded(channel.topic, message.log_time * 1e-9, value)
    except (McapError, EOFError, OSError) as exc:
        detail = "it ends in the middle of a record" if isinstance(exc, (EOFError, OSError)) else str(exc)
        raise RecordingError(f"{path} is damaged: {detail}") from None
    finally:
        stream.close()


def _summary(reader: McapReader) -> Any:
    """The file's summary (channels, statistics); None for a file whose writer did not finish."""
    if isinstance(reader, NonSeekingReader):
        return None
    try:
        return reader.get_summary()
    except (McapError, EOFError, OSError):  # OSError: shorter than a footer
        return None


def info(path: Path | str) -> Info:
    """The time span and the message count per key of the recording (from its summary; read through
    if it has none: a recorder killed before it finished). Raises RecordingError."""
    stream, reader = _open(path)
    try:
        summary = _summary(reader)
        stats = summary.statistics if summary is not None else None
    finally:
        stream.close()
    if summary is not None and stats is not None:
        counts = {summary.channels[c].topic: n for c, n in stats.channel_message_counts.items()}
        for channel in summary.channels.values():
            counts.setdefault(channel.topic, 0)
        if stats.message_count == 0:
            return Info(0.0, 0.0, counts)
        return Info(stats.message_start_time * 1e-9, stats.message_end_time * 1e-9, counts)
    counts = {}
    start = end = 0.0
    for rec in read_messages(path):
        counts[rec.key] = counts.get(rec.key, 0) + 1
        start = rec.t if not start else min(start, rec.t)
        end = max(end, rec.t)
    return Info(start, end, counts)


def keys(path: Path | str) -> list[str]:
    """Every key recorded in the file, sorted."""
    return sorted(info(path).counts)


def arms(path: Path | str) -> list[str]:
    """Every arm that has a key in the file, sorted."""
    return info(path).arms
