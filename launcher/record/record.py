"""``jara-arm record [--arm ID]... -o FILE.mcap [--ros2]``: every sample under ``JARA_ARM/<arm>/`` into a recording
(and with ``--ros2`` a ROS 2 bag beside it, ``launcher/ros2/bag.py``).

One subscriber on ``JARA_ARM/<arm>/**`` (``JARA_ARM/**`` without ``--arm``) takes
every publication, the 1 kHz streams and the call traces included (the servers
of the Common, Middle, Servo/Common and Monitor/Common interfaces publish each
call they answer while a subscriber like this one listens: ``trace/...``).
The subscriber's callback only stamps the sample with its arrival time and
queues it; this command's loop transcodes and writes (``launcher/record/recording.py``)
and shows the size, message count and rate on stderr every second.

The recorder runs at a lower CPU priority (nice +10): on a busy machine it
yields to the services, buffering meanwhile; a sample it could not buffer is
counted, said and makes the exit status 1.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import os
import sys
import threading
import time
from pathlib import Path
from typing import TextIO

import zenoh

from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import ArmKeys, any_arm_every_key, arm_of
from jara_arm.services.runtime.arguments import positive_float
from jara_arm.services.runtime.stop_signals import StopSignals

from ..command import USAGE_ERROR, Command, setup_logging
from ..ros2.bag import BagError, Ros2Bag, bag_path
from ..session import add_client_zenoh_arguments, arm_id, open_session
from .progress import Progress, human_size
from .recording import RecordingError, RecordingWriter, to_json

_CAPACITY = 500_000  #: samples buffered between the callback and the writer (~2 min of 4 arms at full rate)
_BATCH = 2_000  #: samples written between two looks at the clock
_NICE = 10  #: how much lower than the services the recorder runs
_POLL = 0.005  #: [s] sleep of the loop when nothing waits


@dataclasses.dataclass(frozen=True)
class RecordSettings:
    arms: tuple[str, ...] = ()  #: the arms to record; () for every arm
    duration: float | None = None  #: [s] stop after this long; None: until SIGINT/SIGTERM


class Inbox:
    """What the subscriber received, with the arrival times [ns]: the callback only appends (receive
    time is known there alone), the recorder's loop takes; beyond ``capacity`` samples are counted
    as dropped, never waited for (Zenoh's thread must not block)."""

    def __init__(self, capacity: int = _CAPACITY) -> None:
        self.capacity = capacity
        self.items: collections.deque[tuple[int, zenoh.Sample]] = collections.deque()
        self.dropped = 0

    def __call__(self, sample: zenoh.Sample) -> None:
        if len(self.items) >= self.capacity:
            self.dropped += 1
            return
        self.items.append((time.time_ns(), sample))


def publish_time(sample: zenoh.Sample, received: int) -> int:
    """The sample's Zenoh timestamp [ns since the Unix epoch], else ``received``."""
    stamp = sample.timestamp
    if stamp is None:
        return received
    return int(stamp.get_time_as_ntp64().as_nanos())  # the HLC's physical time, from the Unix epoch


def subscriptions(arms: tuple[str, ...]) -> list[str]:
    """The key expressions that cover every key of ``arms`` (of every arm if none)."""
    return [ArmKeys(arm).every_key for arm in arms] if arms else [any_arm_every_key()]


def relayed(key: str) -> bool:
    """``key`` carries the 1 kHz feedback in blocks for the client gateway (``Servo/posFeedbackBlock``): the
    same samples as ``Servo/posFeedback``, which the gateway publishes and is recorded."""
    try:
        return key == ArmKeys(arm_of(key)).pos_feedback_block
    except JaraArmError:
        return False


def drain(inbox: Inbox, writer: RecordingWriter, limit: int = _BATCH, bag: Ros2Bag | None = None) -> int:
    """Write up to ``limit`` waiting samples, not the feedback blocks (:func:`relayed`), and what they make of
    the ROS 2 ``bag`` if there is one; how many were taken."""
    done = 0
    while done < limit and inbox.items:
        received, sample = inbox.items.popleft()
        done += 1
        key = str(sample.key_expr)
        if not relayed(key):
            payload = sample.payload.to_bytes()
            writer.write(key, received, publish_time(sample, received), to_json(payload, sample.encoding))
            if bag is not None:
                bag.take(key, received, payload, sample.encoding)
    return done


#: After the stop (Ctrl-C, SIGTERM, --duration) samples are still taken this long [s]: those on their way
#: then (the trace of the call just answered, say) belong to the run; a loopback or LAN transit is well under it.
LINGER = 0.2


def lower_priority() -> None:
    """Run this process below the services (nice +10): on a busy machine the recorder waits, not them."""
    try:
        os.nice(_NICE)
    except OSError:  # not allowed here: record at the same priority
        pass


def run_record(session: zenoh.Session, writer: RecordingWriter, settings: RecordSettings, stop: threading.Event,
               err: TextIO, tty: bool, bag: Ros2Bag | None = None) -> int:
    """Record until ``stop`` or ``duration``, and the ROS 2 ``bag`` beside if there is one; 0, or 1 if samples
    were dropped. Closes ``writer`` and ``bag``."""
    inbox = Inbox()
    subs = [session.declare_subscriber(key, inbox) for key in subscriptions(settings.arms)]
    progress = Progress(err, tty)
    t0 = time.monotonic()
    end = t0 + settings.duration if settings.duration is not None else None
    last = (t0, 0)
    try:
        progress.say(f"recording {', '.join(subscriptions(settings.arms))} to {writer.path} (Ctrl-C stops)")
        while not stop.is_set() and (end is None or time.monotonic() < end):
            if not drain(inbox, writer, bag=bag):
                stop.wait(_POLL)
            now = time.monotonic()
            if now - last[0] >= 1.0:
                rate = (writer.count - last[1]) / (now - last[0])
                last = (now, writer.count)
                dropped = f", {inbox.dropped} dropped" if inbox.dropped else ""
                progress.show(f"{writer.path}: {human_size(writer.size)}, {writer.count} messages, "
                              f"{rate:.0f} msg/s{dropped}")
        if len(inbox.items) > _BATCH:  # behind (nice +10 on a busy machine): say why the exit takes a while
            progress.say(f"stopping: writing the {len(inbox.items)} samples still buffered")
        linger = time.monotonic() + LINGER  # what was on its way when told to stop happened before the stop
        while time.monotonic() < linger:
            if not drain(inbox, writer, bag=bag):
                time.sleep(_POLL)
    finally:
        for sub in subs:
            sub.undeclare()
        while drain(inbox, writer, bag=bag):  # what came before the undeclaration
            pass
        writer.close()
        if bag is not None:
            bag.close()
    progress.done(f"recorded {writer.count} messages on {writer.channels} keys in {time.monotonic() - t0:.1f} s "
                  f"to {writer.path} ({human_size(writer.size)})"
                  + (f"; a ROS 2 bag of {bag.count} messages in {bag.path}" if bag is not None else ""))
    if inbox.dropped:
        progress.say(f"jara-arm record: {inbox.dropped} samples dropped: the recorder fell behind "
                     f"({inbox.capacity} buffered at most)")
        return 1
    return 0


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--arm", action="append", type=arm_id, default=[], metavar="ID",
                        help="an arm to record (repeatable; default: every arm)")
    parser.add_argument("-o", "--output", required=True, metavar="FILE.mcap", help="the file to write")
    parser.add_argument("--duration", type=positive_float, metavar="S", help="stop after S seconds")
    parser.add_argument("--ros2", action="store_true",
                        help="also write a ROS 2 bag (rosbag2, MCAP) of joint_states, tf, robot_description and "
                        "jara_arm/state into the directory FILE_ros2 (ros2 bag info and Foxglove open it)")
    add_client_zenoh_arguments(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """The file opened first (a path that cannot be written: exit 2, nothing joined)."""
    setup_logging("WARNING")
    try:
        writer = RecordingWriter(Path(args.output))
    except RecordingError as exc:
        print(f"{parser.prog}: {exc}", file=sys.stderr)
        return USAGE_ERROR
    try:
        session = open_session(args, parser)
    except SystemExit:
        writer.close()
        raise
    bag: Ros2Bag | None = None
    if args.ros2:
        try:
            bag = Ros2Bag(bag_path(Path(args.output)), session)
        except BagError as exc:
            writer.close()
            session.close()
            print(f"{parser.prog}: {exc}", file=sys.stderr)
            return USAGE_ERROR
    signals = StopSignals()
    lower_priority()
    with session:
        return run_record(session, writer, RecordSettings(tuple(dict.fromkeys(args.arm)), args.duration),
                          signals.stop, sys.stderr, sys.stderr.isatty(), bag)


COMMAND = Command(
    "record", arguments=_arguments, run=_run,
    help="record every sample of the arms into an MCAP file",
    description="Subscribe to JARA_ARM/<arm>/** and write every sample (the 1 kHz streams and the traces "
    "of the Common and Middle calls with their replies included) into an MCAP file: a channel per key, "
    "JSON messages, a JSON Schema per channel from schema/. Shows size, count and rate every second; "
    "stops on SIGINT/SIGTERM or after --duration.")
