"""linkem: a TCP relay that delays both directions of every connection through it by a delay ± jitter.

    python -m tests.linkem --listen HOST:PORT --to HOST:PORT --delay-ms D --jitter-ms J

It accepts connections on ``--listen`` and, for each, opens one to ``--to``, then
forwards every chunk it reads, either way, ``D`` ms ± up to ``J`` ms (uniform)
after it arrived, but never before the chunk read before it on the same
direction: a chunk's release time is ``max(previous release, arrival + delay)``,
so jitter varies the delay without reordering the byte stream (TCP never
reorders what it delivers; a real network's reordering shows to TCP's users only
as delay). A half-close (EOF) is forwarded like a chunk, after its delay; a reset
or failure on either side resets both. ``TCP_NODELAY`` is set on every socket,
so the relay adds no coalescing of its own. When it listens it prints one line,
``linkem: ready``, on stdout.

It is the delay and jitter half of ``hosts.LinkProfile`` (``hosts.py``), which
starts it in a host's network namespace: the kernel here has no netem qdisc. It
loses nothing: loss is done in the kernel, by a filter on the link, so that TCP
sees real losses and retransmits. It relays TCP only (all the Zenoh links of the
tests are TLS over TCP; TLS goes through untouched).

Timers follow the event loop's, so delays are good to about a millisecond.
One process, asyncio, any number of connections; SIGTERM or SIGINT ends it.
"""

from __future__ import annotations

import argparse
import asyncio
import random
import socket
import struct
import sys
from collections.abc import Sequence

READY = "linkem: ready"
"""The line printed on stdout once the relay listens."""

_CHUNK = 65536
"""Bytes read at most at once."""

_IN_FLIGHT = 256
"""Chunks held per direction before the relay stops reading that side (back-pressure)."""


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[v6addr]:PORT`` for IPv6) as ``(host, port)``."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"not HOST:PORT: {text!r}")
    return host.removeprefix("[").removesuffix("]"), int(port)


class Delay:
    """The release times of one direction's chunks: ``delay_s`` ± uniform ``jitter_s``, in order."""

    def __init__(self, delay_s: float, jitter_s: float, rng: random.Random) -> None:
        if delay_s < 0 or jitter_s < 0:
            raise ValueError(f"delay {delay_s} s and jitter {jitter_s} s must be >= 0")
        self.delay_s, self.jitter_s, self._rng = delay_s, jitter_s, rng
        self._last = float("-inf")

    def release(self, arrival: float) -> float:
        """When a chunk that arrived at ``arrival`` leaves: never before the one before it."""
        delay = self.delay_s + (self._rng.uniform(-self.jitter_s, self.jitter_s) if self.jitter_s else 0.0)
        self._last = max(self._last, arrival + max(delay, 0.0))
        return self._last


def _nodelay(writer: asyncio.StreamWriter) -> None:
    sock = writer.get_extra_info("socket")
    if sock is not None:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


def _reset(writer: asyncio.StreamWriter) -> None:
    """Close ``writer``'s connection with a reset (SO_LINGER 0), as the failure of its peer."""
    sock = writer.get_extra_info("socket")
    if sock is not None:
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        except OSError:
            pass
    writer.transport.abort()


class Relay:
    """The relay: forwards connections on ``listen`` to ``to``, each direction delayed."""

    def __init__(self, to: tuple[str, int], delay_s: float, jitter_s: float, seed: int | None = None) -> None:
        self.to, self.delay_s, self.jitter_s = to, delay_s, jitter_s
        Delay(delay_s, jitter_s, random.Random())  # checks them
        self._rng = random.Random(seed)

    async def _read(self, reader: asyncio.StreamReader, queue: asyncio.Queue[tuple[float, bytes]]) -> None:
        loop = asyncio.get_running_loop()
        delay = Delay(self.delay_s, self.jitter_s, self._rng)
        while True:
            chunk = await reader.read(_CHUNK)
            await queue.put((delay.release(loop.time()), chunk))
            if not chunk:  # EOF, queued as b"" to be forwarded in turn
                return

    @staticmethod
    async def _write(queue: asyncio.Queue[tuple[float, bytes]], writer: asyncio.StreamWriter) -> None:
        loop = asyncio.get_running_loop()
        while True:
            release, chunk = await queue.get()
            wait = release - loop.time()
            if wait > 0:
                await asyncio.sleep(wait)
            if not chunk:
                writer.write_eof()
                return
            writer.write(chunk)
            await writer.drain()

    async def connection(self, client_reader: asyncio.StreamReader, client_writer: asyncio.StreamWriter) -> None:
        """Relay one accepted connection until both directions have ended, or either failed."""
        try:
            upstream_reader, upstream_writer = await asyncio.open_connection(*self.to)
        except OSError:
            _reset(client_writer)  # as the target's refusal would have
            return
        writers = (client_writer, upstream_writer)
        for writer in writers:
            _nodelay(writer)
        try:
            async with asyncio.TaskGroup() as tasks:
                for reader, writer in ((client_reader, upstream_writer), (upstream_reader, client_writer)):
                    queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue(_IN_FLIGHT)
                    tasks.create_task(self._read(reader, queue))
                    tasks.create_task(self._write(queue, writer))
        except* OSError:  # a reset or broken pipe on one side: reset the other too
            for writer in writers:
                _reset(writer)
        finally:
            for writer in writers:
                writer.close()


async def serve(listen: tuple[str, int], relay: Relay) -> None:
    """Listen on ``listen``, announce ``READY`` on stdout, relay until cancelled."""
    server = await asyncio.start_server(relay.connection, *listen)
    for sock in server.sockets:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # inherited by accepted sockets
    print(READY, flush=True)
    async with server:
        await server.serve_forever()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tests.linkem",
        description="A TCP relay delaying both directions of every connection by a delay ± jitter.")
    parser.add_argument("--listen", required=True, type=parse_address, metavar="HOST:PORT")
    parser.add_argument("--to", required=True, type=parse_address, metavar="HOST:PORT")
    parser.add_argument("--delay-ms", type=float, default=0.0, metavar="D")
    parser.add_argument("--jitter-ms", type=float, default=0.0, metavar="J")
    parser.add_argument("--seed", type=int, default=None, help="seed of the jitter (default: random)")
    args = parser.parse_args(argv)
    try:
        relay = Relay(args.to, args.delay_ms / 1e3, args.jitter_ms / 1e3, args.seed)
    except ValueError as e:
        parser.error(str(e))
    try:
        asyncio.run(serve(args.listen, relay))
    except KeyboardInterrupt:
        pass
    except OSError as e:  # cannot listen: one line, not a traceback
        print(f"linkem: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
