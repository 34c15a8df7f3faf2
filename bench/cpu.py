"""CPU per service of a running system: ``python bench/cpu.py [--seconds S] [--pid LAUNCHER_PID]``.

Reads ``/proc/<pid>/stat`` (user + system time) of the launcher and of every
process below it, twice, ``S`` seconds apart, and prints each one's share of
one core over that window, named by its service and arm. Without ``--pid`` it
measures every ``jara_arm.launcher up`` on the machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

_TICK = os.sysconf("SC_CLK_TCK")


@dataclasses.dataclass(frozen=True)
class Sample:
    pid: int
    name: str
    ticks: int  # user + system clock ticks so far


def _cmdline(pid: int) -> list[str]:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return [a.decode(errors="replace") for a in f.read().split(b"\0") if a]
    except OSError:
        return []


def _ticks(pid: int) -> int | None:
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return int(fields[11]) + int(fields[12])  # utime, stime (fields 14 and 15 of stat)


def _children(pid: int) -> list[int]:
    out: list[int] = []
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                out += [int(c) for c in f.read().split()]
    except OSError:
        pass
    return out


def name_of(pid: int) -> str:
    """``servo (arm0)``, ``launcher`` ...: what a process of the system is."""
    argv = _cmdline(pid)
    if "up" in argv and any(a.endswith("jara_arm.launcher") or a.endswith("jara-arm") for a in argv):
        return "launcher"
    module = next((a for a in argv if a.startswith("jara_arm.services.")), None)
    arm = argv[argv.index("--arm") + 1] if "--arm" in argv else "?"
    if module:
        return f"{module.rsplit('.', 1)[-1].replace('_', '-')} ({arm})"
    if "demo" in argv:
        return f"demo ({arm})"
    return " ".join(argv[:3]) or str(pid)


def tree(root: int) -> list[tuple[int, str]]:
    """``root`` and every process below it, with their names; a helper process that is not
    a service itself (the planner's planning process) is named after its parent."""
    seen: list[tuple[int, str]] = []
    todo = [(root, "")]
    while todo:
        pid, parent = todo.pop()
        name = name_of(pid)
        if parent and not any(name.startswith(k) for k in ("servo", "planner", "command", "alarm", "demo")):
            name = f"{parent} child"
        seen.append((pid, name))
        todo += [(c, name) for c in _children(pid)]
    return seen


def snapshot(roots: list[int]) -> dict[int, Sample]:
    out = {}
    for root in roots:
        for pid, name in tree(root):
            t = _ticks(pid)
            if t is not None:
                out[pid] = Sample(pid, name, t)
    return out


def launchers() -> list[int]:
    return [int(p) for p in os.listdir("/proc") if p.isdigit() and name_of(int(p)) == "launcher"]


def measure(roots: list[int], seconds: float) -> dict[str, float]:
    """Share of one core per process name over ``seconds`` (names of several arms kept apart)."""
    a = snapshot(roots)
    t0 = time.monotonic()
    time.sleep(seconds)
    b = snapshot(roots)
    wall = time.monotonic() - t0
    shares: dict[str, float] = {}
    for pid, s in b.items():
        before = a[pid].ticks if pid in a else s.ticks
        shares[s.name] = shares.get(s.name, 0.0) + (s.ticks - before) / _TICK / wall
    return shares


def table(shares: dict[str, float]) -> str:
    lines = [f"{'process':<28} {'cores':>6}"]
    lines += [f"{name:<28} {share:6.3f}" for name, share in sorted(shares.items())]
    lines.append(f"{'total':<28} {sum(shares.values()):6.3f}")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=20.0, help="measuring window [s] (default: 20)")
    p.add_argument("--pid", type=int, action="append", help="launcher pid (default: every launcher)")
    args = p.parse_args()
    roots = args.pid or launchers()
    if not roots:
        raise SystemExit("no `jara-arm up` is running")
    print(table(measure(roots, args.seconds)))


if __name__ == "__main__":
    main()
