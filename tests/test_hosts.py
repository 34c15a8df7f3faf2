"""The multi-host harness itself (``hosts.py``): links carry pings, cuts silence them, netem delays them,
and nothing is left behind. Skipped where namespaces (or netem, or ping) cannot be had."""

from __future__ import annotations

import re
import shutil
import subprocess
from collections.abc import Iterator

import pytest

from .hosts import PREFIX, CommandError, Hosts, Link, NetemProfile, remove_stale


def _skip_unless_available(*, netem: bool = False) -> None:
    reason = Hosts.available(netem=netem)
    if reason is not None:
        pytest.skip(reason)
    if shutil.which("ping") is None:
        pytest.skip("ping (iputils-ping) not installed")


@pytest.fixture
def hosts() -> Iterator[Hosts]:
    _skip_unless_available()
    with Hosts() as h:
        yield h


def ping(hosts: Hosts, src: str, link: Link, dst: str) -> subprocess.CompletedProcess[str]:
    """One ping from host ``src`` to host ``dst``'s address on ``link``, waiting 1 s for the answer."""
    return hosts[src].run(["ping", "-n", "-c", "1", "-W", "1", link.address(dst)], check=False)


def rtt_ms(done: subprocess.CompletedProcess[str]) -> float:
    m = re.search(r"time=([\d.]+) ms", done.stdout)
    assert done.returncode == 0 and m, f"no answer:\n{done.stdout}{done.stderr}"
    return float(m[1])


def test_linked_hosts_ping_each_other(hosts: Hosts) -> None:
    hosts.add_host("robot")
    hosts.add_host("ctl")
    link = hosts.link("robot", "ctl", 1)
    assert (link.address("robot"), link.address("ctl")) == ("10.77.1.1", "10.77.1.2")
    rtt_ms(ping(hosts, "robot", link, "ctl"))
    rtt_ms(ping(hosts, "ctl", link, "robot"))


def test_cut_silences_the_link_until_restored(hosts: Hosts) -> None:
    a, b = hosts.add_host("a"), hosts.add_host("b")
    link = hosts.link(a, b, 2)
    rtt_ms(ping(hosts, "a", link, "b"))
    link.cut()
    lost = ping(hosts, "a", link, "b")
    assert lost.returncode != 0, lost.stdout
    assert "1 received" not in lost.stdout
    link.restore()
    rtt_ms(ping(hosts, "a", link, "b"))


def test_netem_delays_both_ways() -> None:
    _skip_unless_available(netem=True)
    with Hosts() as hosts:
        hosts.add_host("a")
        hosts.add_host("b")
        link = hosts.link("a", "b", 3)
        link.netem(20.0)
        assert link.profile == NetemProfile(delay_ms=20.0)
        # 20 ms out through a's qdisc, 20 ms back through b's
        assert rtt_ms(ping(hosts, "a", link, "b")) >= 40.0
        link.cut()
        link.restore()  # back to the profile, not to no delay
        assert rtt_ms(ping(hosts, "a", link, "b")) >= 40.0
        link.clear()
        assert rtt_ms(ping(hosts, "a", link, "b")) < 40.0


def _namespaces() -> list[str]:
    return subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=True).stdout.split()


def test_namespaces_are_deleted_on_exit() -> None:
    _skip_unless_available()
    with pytest.raises(RuntimeError), Hosts() as hosts:
        names = [hosts.add_host(n).namespace for n in ("x", "y")]
        hosts.link("x", "y", 4)
        assert set(names) <= set(_namespaces())
        assert all(n.startswith(PREFIX) for n in names)
        raise RuntimeError("a test failing inside")
    assert not set(names) & set(_namespaces())


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
