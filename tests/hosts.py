"""Hosts for multi-host tests: Linux network namespaces joined by veth links.

A multi-host test needs machines that reach each other only over a network that
the test can make slow, lossy or cut. On one machine a network namespace stands
for a host: its own interfaces, addresses, routes and sockets, so a process run in
it (``ip netns exec``) sees only that host's network. A veth pair is the cable
between two hosts.

* Delay, jitter and loss come from a netem qdisc on the sending side of each
  end: one direction of a link is shaped by its sender's qdisc, so a profile is set
  on *both* ends and a round trip goes through two of them (a 20 ms delay makes a
  ping's round trip at least 40 ms).
* A cut drops every packet arriving on either end (a classic-BPF filter on the
  ingress hook). The senders see their packets leave, nobody sees them arrive, so
  a TCP connection meets silence, not a reset, as with a pulled cable. A drop on
  the sending side instead would be reported to the sender's own socket (ENOBUFS).
  The cut does not touch the netem profile, which is in force again on
  ``restore()``, and it needs no netem.

The namespaces are named ``ja<pid>-<n>-<host>`` (``n`` counts the ``Hosts`` of
this process), so tests running side by side never share one; addresses and
interface names live inside the namespaces, so they may repeat between tests.
All is deleted on leaving the ``Hosts`` context, at interpreter exit if that was
missed, and by ``remove_stale()`` (called on entering a ``Hosts``) when the test
process that made them was killed.

Requires root, ``ip`` and ``tc`` (iproute2), and for profiles the kernel's netem
qdisc (``sch_netem``): ``Hosts.available()`` tells whether all are here.

    with Hosts() as hosts:
        robot, ctl = hosts.add_host("robot"), hosts.add_host("ctl")
        link = hosts.link(robot, ctl, 1)
        link.netem(LAN)
        proc = Proc(robot.argv([sys.executable, "-m", "..."]))   # support.Proc
        ctl.run(["ping", "-c", "1", link.address(robot)])
        link.cut()
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import functools
import itertools
import os
import re
import shutil
import signal
import subprocess
from collections.abc import Sequence
from types import TracebackType
from typing import Any, overload

PREFIX = f"ja{os.getpid()}"
"""The start of every namespace name that this process makes."""

_NAMESPACE = re.compile(r"ja(\d+)-\S+")
"""A namespace of some test process: the pid of that process in group 1."""

_HOST_NAME = re.compile(r"[a-z][a-z0-9]{0,9}")
"""A host name: short (it is part of interface names), nothing ``ip`` would misread."""

_COMMAND_TIMEOUT = 10.0
"""Seconds for one ``ip`` or ``tc`` command: each is quick; a hang is a failure."""

# Classic BPF, one instruction: `ret #2`, i.e. TC_ACT_SHOT in direct-action mode (drop).
_DROP_ALL = "1,6 0 0 2"

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
class NetemProfile:
    """A network's quality in one direction: each packet is delayed by ``delay_ms`` ± ``jitter_ms``
    [ms] and lost with probability ``loss_pct`` [%].

    With jitter, netem lets a later packet overtake an earlier one (as a poor
    network does); TCP hides that, at the cost of some retransmissions.
    """

    delay_ms: float
    jitter_ms: float = 0.0
    loss_pct: float = 0.0

    def __post_init__(self) -> None:
        if self.delay_ms < 0 or self.jitter_ms < 0 or not 0 <= self.loss_pct <= 100:
            raise ValueError(f"not a network profile: {self}")

    def tc_args(self) -> list[str]:
        """The arguments after ``netem`` in a ``tc qdisc`` command."""
        args = ["delay", f"{self.delay_ms:g}ms"]
        if self.jitter_ms:
            args.append(f"{self.jitter_ms:g}ms")
        if self.loss_pct:
            args += ["loss", f"{self.loss_pct:g}%"]
        return args


LAN = NetemProfile(delay_ms=1.0, jitter_ms=0.5, loss_pct=0.1)
"""A busy wired LAN, per direction."""

POOR = NetemProfile(delay_ms=20.0, jitter_ms=10.0, loss_pct=2.0)
"""A poor network (a loaded Wi-Fi or a long route), per direction."""


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


class Link:
    """A veth pair between hosts ``a`` and ``b``: ``10.77.<index>.1/24`` on ``a``, ``.2`` on ``b``."""

    def __init__(self, a: Host, b: Host, index: int) -> None:
        self.a, self.b, self.index = a, b, index
        # Inside each namespace, named for the peer; "v<index>-" keeps it unique when cut to 15 chars.
        self._ends = {a.name: (a, f"v{index}-{b.name}"[:15], f"10.77.{index}.1"),
                      b.name: (b, f"v{index}-{a.name}"[:15], f"10.77.{index}.2")}
        self.profile: NetemProfile | None = None
        """The netem profile in force on both ends (``None``: none), also while cut."""
        self.is_cut = False

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

    @overload
    def netem(self, profile: NetemProfile, /) -> None: ...
    @overload
    def netem(self, delay_ms: float, jitter_ms: float = 0.0, loss_pct: float = 0.0) -> None: ...

    def netem(self, delay_ms: NetemProfile | float, jitter_ms: float = 0.0, loss_pct: float = 0.0) -> None:
        """Set (or replace) a netem profile on both ends: a profile, or its delay [ms], jitter [ms]
        and loss [%]. While the link is cut it stays cut; the profile applies on ``restore()``."""
        profile = delay_ms if isinstance(delay_ms, NetemProfile) else NetemProfile(delay_ms, jitter_ms, loss_pct)
        self._tc("qdisc", "replace", "root", "netem", *profile.tc_args())
        self.profile = profile

    def clear(self) -> None:
        """Remove the netem profile from both ends (a cut stays)."""
        if self.profile is not None:
            self._tc("qdisc", "del", "root")
            self.profile = None

    def cut(self) -> None:
        """Drop every packet on the link, both ways, silently (see the module's docstring)."""
        if not self.is_cut:
            self._tc("qdisc", "add", "clsact")
            self._tc("filter", "add", "ingress", "pref", "1", "protocol", "all", "bpf", "da",
                     "bytecode", _DROP_ALL)
            self.is_cut = True

    def restore(self) -> None:
        """End a cut: the link carries packets again, under the last profile set by ``netem()`` if any."""
        if self.is_cut:
            self._tc("qdisc", "del", "clsact")  # and with it the drop filter
            self.is_cut = False


class Hosts:
    """A topology of hosts and links for one test, deleted on leaving the context."""

    def __init__(self) -> None:
        self._prefix = f"{PREFIX}-{next(_serials)}"
        self.hosts: dict[str, Host] = {}
        self.links: list[Link] = []

    @staticmethod
    def available(*, netem: bool = True) -> str | None:
        """``None`` if hosts, links and cuts (and netem profiles, if ``netem``) can be made here;
        else why not, as a sentence for ``pytest.skip``."""
        return _probe(netem)

    def __enter__(self) -> Hosts:
        remove_stale()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def __getitem__(self, name: str) -> Host:
        return self.hosts[name]

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
        ha, hb = (self.hosts[h] if isinstance(h, str) else h for h in (a, b))
        if ha.name == hb.name:
            raise ValueError(f"a link needs two hosts, not {ha.name!r} twice")
        if not 0 <= subnet_index <= 255 or any(link.index == subnet_index for link in self.links):
            raise ValueError(f"subnet index {subnet_index}: one in 0..255 not used by another link")
        link = Link(ha, hb, subnet_index)
        link._create()
        self.links.append(link)
        return link

    def close(self) -> None:
        """Delete every host (their links with them); all are tried, the first failure raised."""
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
def _probe(netem: bool) -> str | None:
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
            if netem:
                step = "a netem qdisc (the kernel's sch_netem)"
                link.netem(LAN)
    except CommandError as e:
        return f"cannot make {step} here: {e}"
    except (OSError, subprocess.SubprocessError) as e:
        return f"cannot run ip or tc here: {e}"
    return None
