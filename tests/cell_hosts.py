"""A secure cell spread over three hosts (network namespaces), as docs/secure_cell.md deploys it.

    operator host ──poor link── controller host ──LAN── cell host
    (a client)                  router, command,        router, servo, planner
                                alarm monitor

Each host runs what the deployment page puts there, each router with a
certificate of its own, every service with the ``service`` identity and the
``lan`` timing profile. The links' delay and jitter come from a TCP relay on
the connecting side and their loss from the kernel (``tests/hosts.py``); a cut
silences a link without a reset, like a pulled cable.

``tests/test_cell_hosts.py`` runs it; ``bench/cell_hosts.py`` keeps it moving
for minutes and counts alarms.
"""

from __future__ import annotations

import json
import signal
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from jara_arm.launcher.secure.certs import init_cell, issue
from jara_arm.schema.roles import Role

from .hosts import LAN, POOR, Host, Hosts, Link
from .support import LAUNCHER, Proc

ARM = "arm0"
ROBOT = "iiwa"
PORT = 7447
TIMING = ["--timing", "lan"]


class CellHosts:
    """The three hosts, their links, the cell's certificates and every process; :meth:`close` ends them."""

    def __init__(self, hosts: Hosts, cell_dir: Path) -> None:
        self.hosts = hosts
        self.cell_host = hosts.add_host("cell")
        self.ctrl_host = hosts.add_host("ctrl")
        self.op_host = hosts.add_host("op")
        self.lan: Link = hosts.link(self.cell_host, self.ctrl_host, 1)
        self.poor: Link = hosts.link(self.ctrl_host, self.op_host, 2)
        cell_ip, ctrl_ip = self.lan.address(self.cell_host), self.lan.address(self.ctrl_host)
        ctrl_op_ip = self.poor.address(self.ctrl_host)
        self.cell = init_cell(cell_dir)
        # Each router is reached on its link address, and through the relay on its host's loopback.
        issue(self.cell, "cell-router", Role.ROUTER, hosts=[cell_ip, "127.0.0.1"])
        issue(self.cell, "ctrl-router", Role.ROUTER, hosts=[ctrl_ip, ctrl_op_ip, "127.0.0.1"])
        issue(self.cell, "alice", Role.OPERATOR)
        issue(self.cell, "olga", Role.OBSERVER)
        self.secure = str(self.cell.root)
        self.procs: list[Proc] = []
        self.lan.set_profile(LAN)
        self.poor.set_profile(POOR)
        # Each router listens on its host's loopback; a relay on the link's address forwards to it with
        # the link's delay (the kernel drops the link's packets): what crosses a link is delayed, and a
        # connection attempt across a cut link goes unanswered, as on a real network.
        hosts.relay(self.cell_host, f"{cell_ip}:{PORT}", f"127.0.0.1:{PORT}", LAN)
        hosts.relay(self.ctrl_host, f"{ctrl_op_ip}:{PORT}", f"127.0.0.1:{PORT}", POOR)
        self.cell_router = self.start(self.cell_host, "router", "--identity", "cell-router",
                                      "--listen", f"tls/127.0.0.1:{PORT}")
        self.ctrl_router = self.start(self.ctrl_host, "router", "--identity", "ctrl-router",
                                      "--listen", f"tls/127.0.0.1:{PORT}", "--connect", f"tls/{cell_ip}:{PORT}")
        self.ctrl_op_ip = ctrl_op_ip
        self.cell_router.wait_for_line("ready")
        self.ctrl_router.wait_for_line("ready")
        self.services = {
            name: self.start(host, "service", name, "--arm", ARM, "--robot", ROBOT, "--mode", "client",
                             "--connect", f"tls/127.0.0.1:{PORT}", *TIMING)
            for host, name in ((self.cell_host, "servo"), (self.cell_host, "planner"),
                               (self.ctrl_host, "alarm-monitor"), (self.ctrl_host, "command"))}

    def start(self, host: Host, *argv: str) -> Proc:
        """``jara-arm ARGV --secure DIR`` in ``host``'s namespace, kept until :meth:`close`."""
        proc = Proc(host.argv([*LAUNCHER, *argv, "--secure", self.secure]))
        self.procs.append(proc)
        return proc

    def client_argv(self, host: Host, *argv: str, identity: str = "alice") -> list[str]:
        """A ``jara-arm`` client command run on ``host``: to the controller's router across the poor link
        from the operator host, to the local router on the others."""
        router = self.ctrl_op_ip if host is self.op_host else "127.0.0.1"
        return host.argv([*LAUNCHER, *argv, "--secure", self.secure, "--identity", identity,
                          "--connect", f"tls/{router}:{PORT}"])

    def call(self, host: Host, op: str, args: dict[str, Any] | None = None, *, servo: bool = False,
             timeout: float = 10.0) -> dict[str, Any]:
        """``jara-arm call OP`` on ``host``; the reply, or {"error": ...} if there was none."""
        argv = ["call", "--arm", ARM, "--timeout", str(timeout), *(["--servo"] if servo else []), op]
        if args is not None:
            argv.append(json.dumps(args))
        done = subprocess.run(self.client_argv(host, *argv), capture_output=True, text=True,
                              timeout=timeout + 30)
        if done.stdout.strip():
            reply: dict[str, Any] = json.loads(done.stdout)
            return reply
        return {"error": done.stderr.strip()}

    def watch_feedback(self, rate: float = 250.0) -> Proc:
        """``jara-arm echo Servo/posFeedback`` on the cell host, as an observer: one JSON line per sample."""
        proc = Proc(self.client_argv(self.cell_host, "echo", "--arm", ARM, "--rate", f"{rate:g}",
                                     "Servo/posFeedback", identity="olga"))
        self.procs.append(proc)
        return proc

    def logs(self) -> str:
        return "\n".join(f"--- {' '.join(p.argv[4:8])}\n" + "\n".join(p.lines[-40:]) for p in self.procs)

    def close(self) -> None:
        for proc in reversed(self.procs):
            proc.stop(signal.SIGINT, timeout=10)


def feedback(lines: Sequence[str]) -> list[tuple[float, list[float]]]:
    """(time [s], joints [rad]) of every ``echo`` line of Servo/posFeedback."""
    out = []
    for line in lines:
        try:
            value = json.loads(line)
            t = value["tm"]["sec"] + value["tm"]["nsec"] * 1e-9
            out.append((t, [float(x) for x in value["pos"]]))
        except (ValueError, KeyError, TypeError):
            continue  # not a sample (a message of echo's own)
    return out
