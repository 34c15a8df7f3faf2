"""The multi-host harness itself (``hosts.py``, ``linkem.py``): links carry TCP and UDP, relays delay
without reordering, the kernel filter loses packets, cuts silence connections until restored, and
nothing is left behind. Skipped where namespaces (or the tc filters) cannot be had.

The test process talks through sockets it makes in the hosts (``Host.socket``), so
no tool beyond Python and iproute2 is needed, and the round trips it times are
its own.
"""

from __future__ import annotations

import random
import socket
import statistics
import subprocess
import threading
import time
from collections.abc import Iterator

import pytest

from . import linkem
from .hosts import LAN, POOR, PREFIX, CommandError, Host, Hosts, LinkProfile, Relay, RelayError, remove_stale


SO_RCVBUFFORCE = 33
"""Linux's ``SO_RCVBUF`` past ``rmem_max``, for root (not in Python's ``socket``)."""


def _skip_unless_available() -> None:
    reason = Hosts.available()
    if reason is not None:
        pytest.skip(reason)


@pytest.fixture
def hosts() -> Iterator[Hosts]:
    _skip_unless_available()
    with Hosts() as h:
        yield h


class EchoServer:
    """A TCP server in ``host`` (a thread of the test process) that sends back what it receives."""

    def __init__(self, host: Host, address: str, port: int) -> None:
        self._listener = host.socket()
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind((address, port))
        self._listener.listen()
        self._listener.settimeout(0.2)
        self._stopped = threading.Event()
        self._threads = [threading.Thread(target=self._accept, daemon=True)]
        self._threads[0].start()

    def _accept(self) -> None:
        while not self._stopped.is_set():
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            thread = threading.Thread(target=self._echo, args=(conn,), daemon=True)
            self._threads.append(thread)
            thread.start()

    def _echo(self, conn: socket.socket) -> None:
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.settimeout(0.2)
        with conn:
            while not self._stopped.is_set():
                try:
                    data = conn.recv(65536)
                except TimeoutError:
                    continue
                except OSError:
                    return
                if not data:
                    return
                conn.sendall(data)

    def stop(self) -> None:
        self._stopped.set()
        self._listener.close()
        for thread in self._threads:
            thread.join(2)


@pytest.fixture
def echo_hosts(hosts: Hosts) -> Iterator[tuple[Hosts, EchoServer]]:
    """Hosts ``a`` and ``b`` on link 1, an echo server on ``b``'s ``127.0.0.1:7000``."""
    hosts.add_host("a")
    b = hosts.add_host("b")
    hosts.link("a", "b", 1)
    server = EchoServer(b, "127.0.0.1", 7000)
    yield hosts, server
    server.stop()


def relayed(hosts: Hosts, profile: LinkProfile) -> tuple[Relay, socket.socket]:
    """A relay on ``b`` in front of its echo server, with ``profile``, and ``a``'s connection through it."""
    link = hosts.links[0]
    relay = hosts.relay("b", f"{link.address('b')}:7447", "127.0.0.1:7000", profile)
    conn = hosts["a"].socket()
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    conn.settimeout(5)
    conn.connect((link.address("b"), 7447))
    return relay, conn


def recv_exactly(conn: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = conn.recv(n - len(data))
        if not chunk:
            raise EOFError(f"connection closed after {len(data)} of {n} bytes")
        data += chunk
    return data


def round_trip_ms(conn: socket.socket, request: bytes) -> float:
    start = time.perf_counter()
    conn.sendall(request)
    assert recv_exactly(conn, len(request)) == request
    return (time.perf_counter() - start) * 1e3


def test_linked_hosts_reach_each_other(hosts: Hosts) -> None:
    robot, ctl = hosts.add_host("robot"), hosts.add_host("ctl")
    link = hosts.link("robot", "ctl", 1)
    assert (link.address("robot"), link.address("ctl")) == ("10.77.1.1", "10.77.1.2")
    server = EchoServer(robot, link.address("robot"), 7000)
    try:
        with ctl.socket() as conn:
            conn.settimeout(2)
            conn.connect((link.address("robot"), 7000))
            round_trip_ms(conn, b"hello")
        with robot.socket() as other:  # the server is robot's, not on robot's other addresses
            other.settimeout(2)
            with pytest.raises(ConnectionRefusedError):
                other.connect(("127.0.0.1", 7000))
    finally:
        server.stop()


def test_a_relay_delays_both_ways(echo_hosts: tuple[Hosts, EchoServer]) -> None:
    hosts, _ = echo_hosts
    _, conn = relayed(hosts, LinkProfile(delay_ms=20.0))
    with conn:
        rtts = [round_trip_ms(conn, b"%08d" % i) for i in range(20)]
    # 20 ms there, 20 ms back
    assert 40.0 <= statistics.median(rtts) <= 80.0, rtts


def test_jitter_never_reorders(echo_hosts: tuple[Hosts, EchoServer]) -> None:
    hosts, _ = echo_hosts
    _, conn = relayed(hosts, LinkProfile(delay_ms=5.0, jitter_ms=5.0))
    chunks = [b"%05d\n" % i for i in range(200)]
    with conn:
        for chunk in chunks:
            conn.sendall(chunk)  # small chunks a little apart, so the relay reads them one by one
            time.sleep(0.0005)
        conn.shutdown(socket.SHUT_WR)  # the half-close goes through too: the echo ends
        received = b""
        while data := conn.recv(65536):
            received += data
    assert received == b"".join(chunks)


def test_the_release_times_keep_order_and_bounds() -> None:
    delay = linkem.Delay(0.005, 0.005, random.Random(1))
    arrivals = [i * 0.0005 for i in range(1000)]
    releases = [delay.release(t) for t in arrivals]
    assert releases == sorted(releases)
    assert all(t <= r <= t + 0.010 for t, r in zip(arrivals, releases))
    assert len({round(r - t, 6) for t, r in zip(arrivals, releases)}) > 100  # it does jitter


def test_kernel_loss_drops_about_that_fraction(hosts: Hosts) -> None:
    a, b = hosts.add_host("a"), hosts.add_host("b")
    link = hosts.link(a, b, 2)
    with a.socket(type=socket.SOCK_DGRAM) as tx, b.socket(type=socket.SOCK_DGRAM) as rx:
        rx.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, 4 << 20)  # the whole burst fits
        rx.bind((link.address(b), 7001))
        rx.settimeout(2)
        tx.sendto(b"warm", (link.address(b), 7001))  # ARP resolved before the burst
        assert rx.recv(100) == b"warm"
        link.loss(50.0)
        assert link.loss_pct == 50.0
        for i in range(400):
            tx.sendto(b"%d" % i, (link.address(b), 7001))
        rx.settimeout(0.3)
        arrived = 0
        with pytest.raises(TimeoutError):
            while rx.recv(100):
                arrived += 1
    assert 120 <= arrived <= 280, f"{arrived} of 400 arrived at 50 % loss"


def test_profiles_set_and_clear_the_loss(hosts: Hosts) -> None:
    a, b = hosts.add_host("a"), hosts.add_host("b")
    link = hosts.link(a, b, 3)

    def filters() -> str:
        return str(a.run(["tc", "filter", "show", "dev", link.interface(a), "ingress"]).stdout)

    link.set_profile(POOR)
    assert (link.profile, link.loss_pct) == (POOR, 2.0)
    assert "protocol ip pref 2 bpf" in filters()
    link.set_profile(LAN)
    assert link.loss_pct == 0.1
    link.cut()
    assert "pref 1 bpf" in filters() and "pref 2 bpf" in filters()
    link.restore()
    assert "pref 1 bpf" not in filters() and "pref 2 bpf" in filters()  # the loss is back alone
    link.set_profile(None)
    assert (link.profile, link.loss_pct) == (None, 0.0)
    assert "bpf" not in filters()
    with pytest.raises(ValueError):
        LinkProfile(delay_ms=1.0, loss_pct=101)


def test_a_cut_silences_a_relayed_connection_until_restored(echo_hosts: tuple[Hosts, EchoServer]) -> None:
    hosts, _ = echo_hosts
    link = hosts.links[0]
    link.set_profile(LAN)
    _, conn = relayed(hosts, LAN)
    with conn:
        round_trip_ms(conn, b"before")
        link.cut()
        conn.sendall(b"during")
        conn.settimeout(1.0)
        with pytest.raises(TimeoutError):  # silence: no answer, no reset
            conn.recv(100)
        link.restore()
        conn.settimeout(5.0)  # TCP retransmits it (backing off: the next try is within ~2 s)
        assert recv_exactly(conn, 6) == b"during"
        assert link.loss_pct == LAN.loss_pct


def _namespaces() -> list[str]:
    return subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=True).stdout.split()


def test_namespaces_and_relays_are_gone_on_exit() -> None:
    _skip_unless_available()
    with pytest.raises(RuntimeError), Hosts() as hosts:
        names = [hosts.add_host(n).namespace for n in ("x", "y")]
        link = hosts.link("x", "y", 4)
        relay = hosts.relay("y", f"{link.address('y')}:7447", "127.0.0.1:7000", POOR)
        assert set(names) <= set(_namespaces())
        assert all(n.startswith(PREFIX) for n in names)
        assert relay.proc.poll() is None
        raise RuntimeError("a test failing inside")
    assert not set(names) & set(_namespaces())
    assert relay.proc.poll() is not None
    assert not hosts.relays


def test_a_relay_that_cannot_listen_says_why(hosts: Hosts) -> None:
    h = hosts.add_host("h")
    with pytest.raises(RelayError, match=r"(?is)exited with 1.*cannot assign requested address"):
        hosts.relay(h, "10.99.0.1:7447", "127.0.0.1:7000", LAN)  # not an address of h
    assert not hosts.relays


def test_a_failing_command_names_itself_and_its_stderr(hosts: Hosts) -> None:
    host = hosts.add_host("h")
    with pytest.raises(CommandError, match=r"ip netns exec \S+ ls /no/such/path.* exited with 2: .*No such file"):
        host.run(["ls", "/no/such/path"])


def test_remove_stale_deletes_the_namespaces_of_dead_processes() -> None:
    _skip_unless_available()
    dead = subprocess.Popen(["true"])
    dead.wait()  # its pid is now free: a test process killed before cleaning up
    stale = f"ja{dead.pid}-0-x"
    subprocess.run(["ip", "netns", "add", stale], check=True)
    try:
        assert stale in remove_stale()
        assert stale not in _namespaces()
    finally:
        subprocess.run(["ip", "netns", "delete", stale], capture_output=True)
