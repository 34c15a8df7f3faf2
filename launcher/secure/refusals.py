"""The refusals of a secure router, in its log: who was refused what, and which connections.

Zenoh enforces the roles itself (``schema/roles.py``) and reports a refused
message only as a TRACE event of its access control, beside a TRACE event for
every allowed message, written by its Rust logger to the process's standard
output; a refused TLS handshake (no certificate, another CA, expired) is a
WARN event of its TLS link. So a secure router sends its standard output (fd 1)
through a pipe, and a thread keeps the refusals and warnings and drops the rest.

The allowed-message events cost the router about 1.2 µs each (measured: 80 000
events in 10 s added 0.1 s of CPU; docs/secure_cell.md), and the filter reads the
pipe in 64 KiB blocks, skipping any block that holds neither a refusal nor a
warning, so that the 1 kHz streams cost it next to nothing.
"""

from __future__ import annotations

import fcntl
import io
import logging
import os
import re
import sys
import threading
import time

import zenoh

log = logging.getLogger("jara_arm.router")

#: What Zenoh's logger writes to fd 1: warnings of every module, and every access decision.
LOG_FILTER = "warn,zenoh::net::routing::interceptor::access_control=trace"
#: The same refusal (who, what, where) is logged at most once in this period [s]; the others are counted.
REPEAT_PERIOD = 5.0
#: Refusals remembered for counting repeats; a peer that tries many keys must not grow it without end.
REMEMBERED = 1000
_PIPE_SIZE = 1 << 20  # room for bursts while the filter thread waits for the GIL
_ANSI = re.compile(rb"\x1b\[[0-9;]*m")
_MARKERS = (b"unauthorized", b"caching permissions", b"WARN", b"ERROR")
_TIME_THREAD = re.compile(r"^(?P<t>\S+)\s+\w+\s+(?:\S+\s+)?ThreadId\((?P<thread>\d+)\)")
_SUBJECT = re.compile(r"(?P<zid>[0-9a-f]+) on \S*?CertCommonName\((?P<cn>[^)]*)\)")
_DENIED = re.compile(r" is unauthorized to (?P<what>.+)$")
_CACHED = re.compile(r"Using cached result: (?P<zid>[0-9a-f]+) ")
_LEVEL = re.compile(r"\s(WARN|ERROR)\s+(?:\S+\s+)?ThreadId\(\d+\)\s+(?P<target>[\w:]+): (?P<msg>.*)$")
_HINT = re.compile(r"\s*Hint: .*$")  # zenoh's TLS link adds an unrelated hint to every refused handshake
_RUST_LOCATION = re.compile(r"\s+at \S+\.rs:\d+\.?")
#: Zenoh computes a key's permissions for every message kind at once when it first meets the key on a
#: link, and traces each result right after its "caching permissions" line: those are not refusals.
CACHE_BLOCK = 0.002  # [s]


class RefusalLog:
    """Routes Zenoh's log through the filter; :meth:`start` before the router session opens."""

    def __init__(self) -> None:
        self._repeats: dict[str, tuple[float, int]] = {}
        self._names: dict[str, str] = {}  # Zenoh id -> certificate common name, as the log shows them
        self._cache_blocks: dict[str, float] = {}  # thread -> when its last cache computation began [s]
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        read, write = os.pipe()
        try:
            fcntl.fcntl(write, fcntl.F_SETPIPE_SZ, _PIPE_SIZE)
        except OSError:
            pass  # the default 64 KiB will do
        saved = os.dup(1)
        os.dup2(write, 1)
        os.close(write)
        # Python's own stdout goes on to where fd 1 went before (the ready line, the services' logs).
        sys.stdout.flush()
        sys.stdout = io.TextIOWrapper(io.FileIO(saved, "w"), line_buffering=True)
        zenoh.init_log_from_env_or(LOG_FILTER)
        self._thread = threading.Thread(target=self._read, args=(read,), name="refusals", daemon=True)
        self._thread.start()

    def _read(self, fd: int) -> None:
        rest = b""
        while block := os.read(fd, 1 << 16):
            data = rest + block
            cut = data.rfind(b"\n") + 1
            data, rest = data[:cut], data[cut:]
            if not any(m in data for m in _MARKERS):
                continue
            for line in data.splitlines():
                if any(m in line for m in _MARKERS):
                    self.line(_ANSI.sub(b"", line).decode("utf-8", "replace"))

    def line(self, text: str) -> None:
        """One line of Zenoh's log (colours removed): a refusal or a warning is logged, the rest dropped."""
        subject = _SUBJECT.search(text)
        if subject:
            self._names[subject.group("zid")] = subject.group("cn")
        when = _TIME_THREAD.search(text)
        if "caching permissions" in text:
            if when:
                self._cache_blocks[when.group("thread")] = _seconds(when.group("t"))
            return
        denied = _DENIED.search(text)
        if denied:
            cached = _CACHED.search(text)
            zid = cached.group("zid") if cached else (subject.group("zid") if subject else "")
            if not cached and when:
                began = self._cache_blocks.get(when.group("thread"))
                if began is not None and 0 <= _seconds(when.group("t")) - began < CACHE_BLOCK:
                    return
            who = self._names.get(zid, f"peer {zid or '?'} (no certificate name)")
            self._log(f"refused: {who} may not {denied.group('what')}")
            return
        level = _LEVEL.search(text)
        if level is None:
            return
        msg = _RUST_LOCATION.sub("", _HINT.sub("", level.group("msg"))).strip()
        if level.group("target").startswith("zenoh_link_tls"):
            self._log(f"refused connection: {msg}")
        else:
            log.warning("zenoh: %s", msg)

    def _log(self, message: str) -> None:
        now = time.monotonic()
        last, repeats = self._repeats.get(message, (-REPEAT_PERIOD, 0))
        if now - last < REPEAT_PERIOD:
            self._repeats[message] = (last, repeats + 1)
            return
        if len(self._repeats) >= REMEMBERED:
            self._repeats = {m: v for m, v in self._repeats.items() if now - v[0] < REPEAT_PERIOD}
        self._repeats[message] = (now, 0)
        log.warning("%s%s", message, f" ({repeats} more times since)" if repeats else "")


def _seconds(stamp: str) -> float:
    """Seconds of the day of a log timestamp such as ``2026-11-23T18:15:08.531678Z``."""
    try:
        clock = stamp.rstrip("Z").split("T")[1]
        h, m, sec = clock.split(":")
        return int(h) * 3600 + int(m) * 60 + float(sec)
    except (IndexError, ValueError):
        return -1.0
