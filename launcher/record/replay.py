"""``jara-arm replay FILE.mcap [--speed X] [--arm ID]...``: a recording published again, in time.

Into a Zenoh network where no arm runs, so that ``echo``, ``plot``, ``view`` and
any subscriber see the run again. Each message goes out on its key, at its
recorded time from the start (divided by the speed factor), re-encoded in the
key's declared encoding (JSON or MessagePack, ``schema/keys.py``) and labelled
with it.

Never replayed: what the services subscribe to (the keys of kind ``subscriber``
in the key table: ``Servo/posCmd``, ``estop``), which would move or stop a real arm; keys outside the key
table. The call traces (``trace/...``) go out as the publications they are,
never as queries. Replay refuses to start while an arm of the recording is
alive on the network (its liveliness tokens ``JARA_ARM/<arm>/alive/*``), and
stops if one appears.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import threading
import time
from pathlib import Path
from typing import TextIO

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import ArmKeys, encoding_of, key_info, parse_alive
from jara_arm.services.runtime.arguments import positive_float
from jara_arm.services.runtime.stop_signals import StopSignals
from jara_arm.services.runtime.wire import label

from ..command import USAGE_ERROR, Command, setup_logging
from ..session import add_client_zenoh_arguments, arm_id, open_session
from .progress import Progress
from .recording import Info, RecordingError, read_messages
from .recording import info as recording_info

_LIVELINESS_TIMEOUT = 2.0  #: [s] to hear of the arms alive on the network
_LATE = 0.0005  #: [s] a message this close to its time goes out without a sleep


@dataclasses.dataclass(frozen=True)
class ReplaySettings:
    speed: float = 1.0  #: recorded time / replay time
    arms: tuple[str, ...] = ()  #: the arms to replay; () for every arm of the recording


def replayed(key: str) -> bool:
    """Whether ``key`` is replayed: a key of the key table that the system publishes (not one its
    services subscribe to: commands, never replayed)."""
    try:
        row = key_info(key)
    except JaraArmError:
        return False
    return not row.kind.startswith("subscriber") and row.encoding.encoding is not None


def plan(info: Info, settings: ReplaySettings) -> tuple[list[str], list[str]]:
    """``(replayed keys, skipped keys)`` of the recording's keys for ``settings.arms``. Raises
    RecordingError for an arm the recording does not hold."""
    missing = [a for a in settings.arms if a not in info.arms]
    if missing:
        raise RecordingError(f"no arm {', '.join(missing)} in the recording (it holds {', '.join(info.arms) or 'none'})")
    arms = set(settings.arms or info.arms)
    mine = [k for k in sorted(info.counts) if any(k.startswith(f"{ArmKeys(a).root}/") for a in arms)]
    return [k for k in mine if replayed(k)], [k for k in mine if not replayed(k)]


def alive_arms(session: zenoh.Session, arms: list[str]) -> dict[str, list[str]]:
    """The services alive now of each of ``arms`` that has any (by their liveliness tokens)."""
    found: dict[str, list[str]] = {}
    for arm in arms:
        for reply in session.liveliness().get(ArmKeys(arm).alive(), timeout=_LIVELINESS_TIMEOUT):
            if reply.ok is not None:
                found.setdefault(arm, []).append(parse_alive(str(reply.ok.key_expr))[1])
    return found


def _refusal(alive: dict[str, list[str]]) -> str:
    arms = "; ".join(f"{arm} ({', '.join(sorted(services))})" for arm, services in sorted(alive.items()))
    return (f"jara-arm replay: refused: arm {arms} is alive on this network; the replay would mix with what it "
            "publishes. Replay into a network where the recorded arms do not run (e.g. a `jara-arm router` "
            "of its own, --connect to it).")


def run_replay(session: zenoh.Session, path: Path, info: Info, settings: ReplaySettings, stop: threading.Event,
               err: TextIO, tty: bool) -> int:
    """Publish the recording at ``path`` (whose :class:`Info` is ``info``); 0 when done or stopped,
    1 if an arm is (or comes) alive or the file turns out damaged."""
    keys, skipped = plan(info, settings)
    arms = sorted(set(settings.arms or info.arms))
    progress = Progress(err, tty)
    if alive := alive_arms(session, arms):
        progress.say(_refusal(alive))
        return 1
    watch = [session.liveliness().declare_subscriber(ArmKeys(a).alive(), zenoh.handlers.RingChannel(16)) for a in arms]
    publishers: dict[str, zenoh.Publisher] = {}
    total = sum(info.counts[k] for k in keys)
    span = max(info.end - info.start, 0.0)
    if skipped:
        progress.say(f"not replayed (commands to the services, or not of the key table): {', '.join(skipped)}")
    progress.say(f"replaying {path}: {total} messages of {', '.join(arms)} over {span / settings.speed:.1f} s "
                 f"(speed {settings.speed:g})")
    sent, shown, status = 0, 0.0, 0
    t0 = time.monotonic()
    try:
        for rec in read_messages(path, keys) if keys else ():
            due = t0 + (rec.t - info.start) / settings.speed
            while (wait := due - time.monotonic()) > _LATE and not stop.is_set():
                stop.wait(min(wait, 0.1))
            if stop.is_set():
                break
            if any(w.try_recv() is not None for w in watch):
                progress.say(_refusal(alive_arms(session, arms) or {a: ["?"] for a in arms}).replace(
                    "refused", "stopped"))
                return 1
            publisher = publishers.get(rec.key)
            if publisher is None:
                publisher = publishers[rec.key] = session.declare_publisher(
                    rec.key, encoding=label(encoding_of(rec.key)),
                    congestion_control=zenoh.CongestionControl.BLOCK)  # a replay may wait; it must not lose
            publisher.put(codec.dumps(rec.value, encoding_of(rec.key)))
            sent += 1
            if (now := time.monotonic()) - shown >= 1.0:
                shown = now
                progress.show(f"{path}: {rec.t - info.start:.1f} / {span:.1f} s, {sent} / {total} messages")
    except RecordingError as exc:
        progress.say(f"jara-arm replay: {exc}")
        status = 1
    finally:
        for publisher in publishers.values():
            publisher.undeclare()
        for w in watch:
            w.undeclare()
    progress.done(f"replayed {sent} / {total} messages in {time.monotonic() - t0:.1f} s")
    return status


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE.mcap", help="a recording of jara-arm record")
    parser.add_argument("--speed", type=positive_float, default=1.0, metavar="X",
                        help="X times the recorded pace (default: 1)")
    parser.add_argument("--arm", action="append", type=arm_id, default=[], metavar="ID",
                        help="an arm to replay (repeatable; default: every arm of the recording)")
    add_client_zenoh_arguments(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """The file read and the arms checked first (exit 2, nothing joined), then the network."""
    setup_logging("WARNING")
    path = Path(args.file)
    settings = ReplaySettings(args.speed, tuple(dict.fromkeys(args.arm)))
    try:
        info = recording_info(path)
        plan(info, settings)
    except RecordingError as exc:
        print(f"{parser.prog}: {exc}", file=sys.stderr)
        return USAGE_ERROR
    session = open_session(args, parser)
    signals = StopSignals()
    with session:
        return run_replay(session, path, info, settings, signals.stop, sys.stderr, sys.stderr.isatty())


COMMAND = Command(
    "replay", arguments=_arguments, run=_run,
    help="publish a recording again, in time, where no arm runs",
    description="Publish the messages of an MCAP recording on their keys at their recorded pace (divided "
    "by --speed), each in its key's encoding, for echo, plot, view or any subscriber. Refuses while "
    "a recorded arm is alive on the network. Never replays what the services subscribe to "
    "(Servo/posCmd, estop); call traces go out as publications, "
    "never as queries.")
