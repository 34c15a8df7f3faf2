"""Hosts for multi-host tests: Linux network namespaces joined by veth links.

A multi-host test needs machines that reach each other only over a network that
the test can make slow, lossy or cut. On one machine a network namespace stands
for a host: its own interfaces, addresses, routes and sockets, so a process run in
it (``ip netns exec``, ``Host.argv``) sees only that host's network, and so does a
socket the test makes in it (``Host.socket``). A veth pair is the cable between
two hosts.

A link's quality is a ``LinkProfile``: delay ± jitter and loss, each direction.
The kernel of these machines (and of CI's) has no netem qdisc (nor fq or tbf),
so a profile is made of two parts:

* Loss, in the kernel: ``link.set_profile(p)`` (or ``link.loss(pct)``) drops that
  fraction of the IPv4 packets arriving on either end, at random: a classic-BPF
  filter on the ingress hook that compares the kernel's random number (the
  ``SKF_AD_RANDOM`` ancillary load) with a threshold. So TCP loses real segments
  and retransmits them. ARP and IPv6 are never lost (a lost ARP would stall a
  test for a second, which is no property of the links being modelled).
* Delay and jitter, in user space: ``hosts.relay(host, listen, to, p)`` starts a
  TCP relay (``linkem.py``) in ``host`` that forwards each chunk, either way,
  after ``delay ± jitter``, never reordering. It models a TCP link only, which is
  all the tests need: every Zenoh link here is TLS over TCP. Put it on the
  listening host, in front of the service: the service listens on ``127.0.0.1``
  (or on another port) and the relay on the link's address, so the clients dial
  the address they would dial anyway (and TLS checks that name). Only connections
  through a relay are delayed; the relay's own leg to the service (over ``lo``)
  is not, and neither is other traffic on the link.

A round trip through a relay crosses its delay twice (a 20 ms profile makes a
request's answer come at least 40 ms later); the loss applies to both directions.

A cut drops every packet arriving on either end (another ingress filter, ahead of
the loss). The senders see their packets leave, nobody sees them arrive, so a TCP
connection meets silence, not a reset, as with a pulled cable. A drop on the
sending side instead would be reported to the sender's own socket (ENOBUFS).
``restore()`` removes only the cut: the loss set before is in force again, and
relays run on throughout (their connections stall, then TCP retransmits).

The namespaces are named ``ja<pid>-<n>-<host>`` (``n`` counts the ``Hosts`` of
this process), so tests running side by side never share one; addresses and
interface names live inside the namespaces, so they may repeat between tests.
All is deleted on leaving the ``Hosts`` context (its relays stopped first), at
interpreter exit if that was missed, and by ``remove_stale()`` (called on entering
a ``Hosts``) when the test process that made them was killed (their processes,
relays included, are killed with them).

Requires root, ``ip`` and ``tc`` (iproute2) and the kernel's ``clsact`` qdisc and
``bpf`` classifier: ``Hosts.available()`` tells whether all are here.

    with Hosts() as hosts:
        robot, ctl = hosts.add_host("robot"), hosts.add_host("ctl")
        link = hosts.link(robot, ctl, 1)
        link.set_profile(POOR)                                    # its loss
        router = Proc(robot.argv([..., "--listen", "tls/127.0.0.1:7447"]))  # support.Proc
        hosts.relay(robot, f"{link.address(robot)}:7447", "127.0.0.1:7447", POOR)  # its delay
        client = Proc(ctl.argv([..., "--connect", f"tls/{link.address(robot)}:7447"]))
        link.cut()
        ...
        link.restore()
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import dataclasses
import functools
import itertools
import os
import re
import selectors
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from .linkem import READY, parse_address

PREFIX = f"ja{os.getpid()}"
"""The start of every namespace name that this process makes."""

_NAMESPACE = re.compile(r"ja(\d+)-\S+")
"""A namespace of some test process: the pid of that process in group 1."""

_HOST_NAME = re.compile(r"[a-z][a-z0-9]{0,9}")
"""A host name: short (it is part of interface names), nothing ``ip`` would misread."""

_COMMAND_TIMEOUT = 10.0
"""Seconds for one ``ip`` or ``tc`` command: each is quick; a hang is a failure."""

_RELAY_START_TIMEOUT = 10.0
"""Seconds for a relay to print that it listens."""

# The ingress filters of a link's ends, in classic BPF (tc's "bytecode": count, then
# "code jt jf k" per instruction), run in direct-action mode: a program returns a tc
# action, TC_ACT_SHOT (2) to drop the packet, TC_ACT_UNSPEC (-1) to leave it to the
# next filter, and past the last one it is received.
_CUT_PREF, _LOSS_PREF = 1, 2
"""The filters' priorities, lower first: a cut drops all before the loss filter runs."""

_DROP_ALL = "1,6 0 0 2"
"""``ret #2``: drop."""

_LD_RANDOM = (-0x1000 + 56) & 0xFFFFFFFF
"""``SKF_AD_OFF + SKF_AD_RANDOM``: the offset of a load of a random 32-bit number."""


def _loss_bytecode(pct: float) -> str:
    """Drop a packet with probability ``pct`` %: ``ld rand; jge #threshold, keep; ret #2; keep: ret #-1``."""
    threshold = round(pct / 100 * 2**32)
    if threshold >= 2**32:
        return _DROP_ALL
    ld_w_abs, jge_k, ret_k = 0x20, 0x35, 0x06
    return (f"4,{ld_w_abs} 0 0 {_LD_RANDOM},{jge_k} 1 0 {threshold},"
            f"{ret_k} 0 0 2,{ret_k} 0 0 {0xFFFFFFFF}")


_live: set[str] = set()
"""The namespaces of this process not yet deleted, for the interpreter-exit cleanup."""

_serials = itertools.count()


class CommandError(subprocess.CalledProcessError):
    """A command that failed; its message names the command and its stderr."""

    def __str__(self) -> str:
        err = self.stderr.decode(errors="replace") if isinstance(self.stderr, bytes) else self.stderr
        detail = f": {err.strip()}" if err and err.strip() else ""
        return f"command {' '.join(map(str, self.cmd))!r} exited with {self.returncode}{detail}"


def _run(argv: Sequence[str], *, check: bool = True, **kw: Any) -> subprocess.CompletedProcess[Any]:
    """``subprocess.run`` capturing text output by default, a failure raised as ``CommandError``."""
    kw.setdefault("capture_output", True)
    kw.setdefault("text", True)
    kw.setdefault("timeout", _COMMAND_TIMEOUT)
    done = subprocess.run(list(argv), check=False, **kw)
    if check and done.returncode != 0:
        raise CommandError(done.returncode, done.args, done.stdout, done.stderr)
    return done


def _namespaces() -> list[str]:
    """The names of all named network namespaces (``ip netns list`` prints ``name (id: N)``)."""
    return [line.split()[0] for line in _run(["ip", "netns", "list"]).stdout.splitlines() if line.strip()]


def _delete_namespace(namespace: str) -> None:
    """Delete ``namespace``, first killing whatever still runs in it.

    A namespace lives on, with its links, while a process is in it; ``ip netns
    delete`` only removes its name. So its processes are killed first (they are
    the test's own: nothing else runs in a namespace named for a test process).
    """
    pids = _run(["ip", "netns", "pids", namespace], check=False).stdout.split()
    for pid in pids:
        with contextlib.suppress(ProcessLookupError, ValueError):
            os.kill(int(pid), signal.SIGKILL)
    _run(["ip", "netns", "delete", namespace])
    _live.discard(namespace)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, someone else's
        return True
    return True


def remove_stale() -> list[str]:
    """Delete the namespaces left by test processes that are gone (killed before cleaning
    up); the names deleted. Namespaces of live processes, this one's included, are left."""
    stale = [ns for ns in _namespaces()
             if (m := _NAMESPACE.fullmatch(ns)) and int(m[1]) != os.getpid() and not _pid_alive(int(m[1]))]
    for namespace in stale:
        with contextlib.suppress(CommandError):  # another process removing it at the same time
            _delete_namespace(namespace)
    return stale


@atexit.register
def _remove_live() -> None:
    """Best effort at interpreter exit for a ``Hosts`` never closed (its test died oddly)."""
    for namespace in list(_live):
        with contextlib.suppress(Exception):
            _delete_namespace(namespace)


@dataclasses.dataclass(frozen=True)
class LinkProfile:
    """A link's quality in each direction: data is delayed by ``delay_ms`` ± ``jitter_ms`` [ms]
    (uniform) and packets lost with probability ``loss_pct`` [%].

    Made in two parts (see the module's docstring): the loss by ``Link.set_profile``,
    the delay and jitter by ``Hosts.relay``. The jitter varies the delay but never
    reorders a connection's bytes (TCP would hide a reordering but as delay).
    """

    delay_ms: float
    jitter_ms: float = 0.0
    loss_pct: float = 0.0

    def __post_init__(self) -> None:
        if self.delay_ms < 0 or self.jitter_ms < 0 or not 0 <= self.loss_pct <= 100:
            raise ValueError(f"not a link profile: {self}")


LAN = LinkProfile(delay_ms=1.0, jitter_ms=0.5, loss_pct=0.1)
"""A busy wired LAN, per direction."""

POOR = LinkProfile(delay_ms=20.0, jitter_ms=10.0, loss_pct=2.0)
"""A poor operator link (a loaded Wi-Fi or a long route), per direction."""


_libc = ctypes.CDLL(None, use_errno=True)
_CLONE_NEWNET = 0x40000000


@dataclasses.dataclass(frozen=True)
class Host:
    """One host: a network namespace with ``lo`` up and its links' interfaces."""

    name: str
    namespace: str

    def argv(self, cmd: Sequence[str]) -> list[str]:
        """``cmd`` run in this host (for ``subprocess`` or ``support.Proc``)."""
        return ["ip", "netns", "exec", self.namespace, *cmd]

    def run(self, cmd: Sequence[str], **kw: Any) -> subprocess.CompletedProcess[Any]:
        """``subprocess.run`` of ``cmd`` in this host: by default checked (a failure raises
        ``CommandError``), its output captured as text, at most 10 s; ``kw`` overrides."""
        return _run(self.argv(cmd), **kw)

    def socket(self, family: int = socket.AF_INET, type: int = socket.SOCK_STREAM, proto: int = 0) -> socket.socket:
        """A new socket of this host, for the test process itself to use.

        A socket belongs to the network namespace of the thread that made it, for
        good; so a short-lived thread enters the namespace (``setns``) and makes it.
        """
        made: list[socket.socket | BaseException] = []

        def make() -> None:
            try:
                fd = os.open(f"/var/run/netns/{self.namespace}", os.O_RDONLY | os.O_CLOEXEC)
                try:
                    if _libc.setns(fd, _CLONE_NEWNET) != 0:
                        err = ctypes.get_errno()
                        raise OSError(err, f"setns into {self.namespace}: {os.strerror(err)}")
                finally:
                    os.close(fd)
                made.append(socket.socket(family, type, proto))
            except BaseException as e:  # raised again in the calling thread
                made.append(e)

        thread = threading.Thread(target=make, name=f"setns-{self.name}")
        thread.start()
        thread.join()
        if isinstance(made[0], BaseException):
            raise made[0]
        return made[0]


class Link:
    """A veth pair between hosts ``a`` and ``b``: ``10.77.<index>.1/24`` on ``a``, ``.2`` on ``b``."""

    def __init__(self, a: Host, b: Host, index: int) -> None:
        self.a, self.b, self.index = a, b, index
        # Inside each namespace, named for the peer; "v<index>-" keeps it unique when cut to 15 chars.
        self._ends = {a.name: (a, f"v{index}-{b.name}"[:15], f"10.77.{index}.1"),
                      b.name: (b, f"v{index}-{a.name}"[:15], f"10.77.{index}.2")}
        self.profile: LinkProfile | None = None
        """The profile last set by ``set_profile`` (``None``: none); its delay is for relays."""
        self.loss_pct = 0.0
        """The loss in force [%] (while not cut)."""
        self.is_cut = False
        self._has_clsact = False

    def _create(self) -> None:
        (a, if_a, ip_a), (b, if_b, ip_b) = self._ends.values()
        # Made right in the two namespaces, so the names never meet in the root namespace.
        _run(["ip", "link", "add", if_a, "netns", a.namespace, "type", "veth",
              "peer", "name", if_b, "netns", b.namespace])
        for host, interface, ip in ((a, if_a, ip_a), (b, if_b, ip_b)):
            _run(["ip", "-n", host.namespace, "addr", "add", f"{ip}/24", "dev", interface])
            _run(["ip", "-n", host.namespace, "link", "set", interface, "up"])

    def _end(self, host: Host | str) -> tuple[Host, str, str]:
        name = host.name if isinstance(host, Host) else host
        try:
            return self._ends[name]
        except KeyError:
            raise ValueError(f"host {name!r} is not on the link {self.a.name}-{self.b.name}") from None

    def address(self, host: Host | str) -> str:
        """The IPv4 address of ``host`` (one of the two ends) on this link."""
        return self._end(host)[2]

    def interface(self, host: Host | str) -> str:
        """The name of this link's interface in ``host``'s namespace."""
        return self._end(host)[1]

    def _tc(self, *args: str) -> None:
        """``tc <args[0]> <args[1]> dev <interface> <args[2:]>`` on both ends."""
        for host, interface, _ in self._ends.values():
            host.run(["tc", *args[:2], "dev", interface, *args[2:]])

    def _set_filter(self, pref: int, protocol: str, bytecode: str | None) -> None:
        """Set (or with ``None`` remove) the ingress filter ``pref`` on both ends."""
        if bytecode is None:
            if self._has_clsact:
                self._tc("filter", "del", "ingress", "pref", str(pref))
            return
        if not self._has_clsact:  # the ingress (and egress) hook for filters; made once
            self._tc("qdisc", "add", "clsact")
            self._has_clsact = True
        self._tc("filter", "replace", "ingress", "pref", str(pref), "handle", "1", "protocol", protocol,
                 "bpf", "da", "bytecode", bytecode)

    def loss(self, pct: float) -> None:
        """Lose ``pct`` % of the IPv4 packets each way, at random (0: none); a cut stays cut."""
        if not 0 <= pct <= 100:
            raise ValueError(f"loss {pct} %: not in 0..100")
        if pct != self.loss_pct:
            self._set_filter(_LOSS_PREF, "ip", _loss_bytecode(pct) if pct else None)
            self.loss_pct = pct

    def set_profile(self, profile: LinkProfile | None) -> None:
        """Put ``profile``'s loss on the link (``None``: no loss) and keep the profile as ``profile``.
        Its delay and jitter are the relays' (``Hosts.relay``): this does not touch them."""
        self.loss(profile.loss_pct if profile is not None else 0.0)
        self.profile = profile

    def cut(self) -> None:
        """Drop every packet on the link, both ways, silently (see the module's docstring)."""
        if not self.is_cut:
            self._set_filter(_CUT_PREF, "all", _DROP_ALL)
            self.is_cut = True

    def restore(self) -> None:
        """End a cut: the link carries packets again, with the loss it had before."""
        if self.is_cut:
            self._set_filter(_CUT_PREF, "all", None)
            self.is_cut = False


class RelayError(RuntimeError):
    """A relay that did not start; the message has its stderr."""


class Relay:
    """A ``linkem`` relay running in a host (made by ``Hosts.relay``), stopped with the ``Hosts``."""

    def __init__(self, host: Host, listen: str, to: str, profile: LinkProfile,
                 proc: subprocess.Popen[bytes], stderr: IO[bytes]) -> None:
        self.host, self.listen, self.to, self.profile = host, listen, to, profile
        self.proc = proc
        """The relay process (``ip netns exec`` execs it: its pid is the relay's)."""
        self._stderr = stderr

    def stderr(self) -> str:
        """What the relay wrote on stderr so far."""
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace")

    def _wait_ready(self, timeout: float) -> None:
        assert self.proc.stdout is not None
        deadline = time.monotonic() + timeout
        out = b""
        with selectors.DefaultSelector() as selector:
            selector.register(self.proc.stdout, selectors.EVENT_READ)
            while b"\n" not in out:
                left = deadline - time.monotonic()
                if left <= 0 or not selector.select(left):
                    raise RelayError(f"relay {self.listen} -> {self.to} in {self.host.name}: "
                                     f"not ready after {timeout:g} s; stderr:\n{self.stderr()}")
                chunk = os.read(self.proc.stdout.fileno(), 4096)
                if not chunk:
                    self.proc.wait()
                    raise RelayError(f"relay {self.listen} -> {self.to} in {self.host.name}: "
                                     f"exited with {self.proc.returncode}; stderr:\n{self.stderr()}")
                out += chunk
        if out.decode(errors="replace").strip() != READY:
            raise RelayError(f"relay {self.listen} -> {self.to}: unexpected output {out!r}")

    def stop(self) -> None:
        """End the relay (the kernel closes its connections); once stopped, nothing."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for stream in (self.proc.stdout, self._stderr):
            if stream is not None and not stream.closed:
                stream.close()


class Hosts:
    """A topology of hosts, links and relays for one test, deleted on leaving the context."""

    def __init__(self) -> None:
        self._prefix = f"{PREFIX}-{next(_serials)}"
        self.hosts: dict[str, Host] = {}
        self.links: list[Link] = []
        self.relays: list[Relay] = []

    @staticmethod
    def available() -> str | None:
        """``None`` if hosts, links, cuts and losses can be made here; else why not, as a
        sentence for ``pytest.skip``."""
        return _probe()

    def __enter__(self) -> Hosts:
        remove_stale()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def __getitem__(self, name: str) -> Host:
        return self.hosts[name]

    def _host(self, host: Host | str) -> Host:
        return self.hosts[host if isinstance(host, str) else host.name]

    def add_host(self, name: str) -> Host:
        """A new host ``name``: lowercase letters and digits, at most 10, starting with a letter."""
        if not _HOST_NAME.fullmatch(name):
            raise ValueError(f"host name {name!r}: 1 to 10 lowercase letters or digits, a letter first")
        if name in self.hosts:
            raise ValueError(f"host {name!r} exists already")
        host = Host(name, f"{self._prefix}-{name}")
        _run(["ip", "netns", "add", host.namespace])
        _live.add(host.namespace)
        self.hosts[name] = host
        _run(["ip", "-n", host.namespace, "link", "set", "lo", "up"])
        return host

    def link(self, a: Host | str, b: Host | str, subnet_index: int) -> Link:
        """A link between hosts ``a`` and ``b`` on subnet ``10.77.<subnet_index>.0/24``, both ends up."""
        ha, hb = self._host(a), self._host(b)
        if ha.name == hb.name:
            raise ValueError(f"a link needs two hosts, not {ha.name!r} twice")
        if not 0 <= subnet_index <= 255 or any(link.index == subnet_index for link in self.links):
            raise ValueError(f"subnet index {subnet_index}: one in 0..255 not used by another link")
        link = Link(ha, hb, subnet_index)
        link._create()
        self.links.append(link)
        return link

    def relay(self, host: Host | str, listen: str, to: str, profile: LinkProfile) -> Relay:
        """A relay in ``host``: it listens on ``listen`` (``HOST:PORT``) and forwards each
        connection to ``to``, every chunk either way after ``profile``'s delay ± jitter
        (``linkem.py``); returned once it listens. Its loss is the link's (``Link.set_profile``)."""
        h = self._host(host)
        for address in (listen, to):
            parse_address(address)  # a ValueError here rather than a relay failing to start
        package_dir = Path(__file__).resolve().parent
        stderr = tempfile.TemporaryFile()
        proc = subprocess.Popen(
            h.argv([sys.executable, "-m", f"{__package__}.linkem", "--listen", listen, "--to", to,
                    "--delay-ms", f"{profile.delay_ms:g}", "--jitter-ms", f"{profile.jitter_ms:g}"]),
            cwd=package_dir.parent, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=stderr)
        relay = Relay(h, listen, to, profile, proc, stderr)
        self.relays.append(relay)
        try:
            relay._wait_ready(_RELAY_START_TIMEOUT)
        except BaseException:
            relay.stop()
            self.relays.remove(relay)
            raise
        return relay

    def close(self) -> None:
        """Stop every relay, delete every host (their links with them); all are tried, the first
        failure raised."""
        for relay in self.relays:
            relay.stop()
        self.relays.clear()
        errors: list[CommandError] = []
        for host in self.hosts.values():
            try:
                _delete_namespace(host.namespace)
            except CommandError as e:
                errors.append(e)
        self.hosts.clear()
        self.links.clear()
        if errors:
            raise errors[0]


@functools.cache
def _probe() -> str | None:
    """``Hosts.available``: tried once per process, on a throwaway host pair."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    missing = [tool for tool in ("ip", "tc") if shutil.which(tool) is None]
    if missing:
        return f"{' and '.join(missing)} (iproute2) not installed"
    step = "network namespaces and veth links"
    try:
        with Hosts() as hosts:  # a Hosts of its own: names no other one uses
            link = hosts.link(hosts.add_host("a"), hosts.add_host("b"), 0)
            step = "a cut (a tc clsact qdisc with a bpf filter)"
            link.cut()
            step = "a loss (a bpf filter loading a random number)"
            link.loss(LAN.loss_pct)
    except CommandError as e:
        return f"cannot make {step} here: {e}"
    except (OSError, subprocess.SubprocessError) as e:
        return f"cannot run ip or tc here: {e}"
    return None
