"""``jara-arm plot``: its options and its run.

Apart from ``plot.py``: ``jara-arm`` imports every command's module when it starts, and only plot is to
pay for matplotlib's import.
"""

from __future__ import annotations

import argparse
import sys

from jara_arm.client import Arm
from jara_arm.robots import ROBOTS
from jara_arm.schema.keys import DEFAULT_ARM
from jara_arm.services.runtime.arguments import non_negative_float, positive_float
from jara_arm.services.runtime.stop_signals import StopSignals

from ..command import USAGE_ERROR, Command, setup_logging
from ..session import add_client_zenoh_arguments, arm_id, open_session


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--arm", type=arm_id, metavar="ID",
                        help=f"the arm (default: {DEFAULT_ARM} live, the recording's only arm with --from)")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--seconds", type=positive_float, metavar="S",
                        help="live: take the feedback for S seconds (default: until Ctrl-C)")
    source.add_argument("--from", dest="recording", metavar="FILE.mcap",
                        help="read the feedback from a recording of `jara-arm record`")
    parser.add_argument("--start", type=non_negative_float, default=0.0, metavar="S",
                        help="window start [s] after the first sample (default: 0)")
    parser.add_argument("--end", type=non_negative_float, metavar="S",
                        help="window end [s] after the first sample (default: the last sample)")
    parser.add_argument("--robot", choices=list(ROBOTS), metavar="NAME",
                        help=f"the arm's robot model ({', '.join(ROBOTS)}; default: from getManipInfo)")
    parser.add_argument("-o", "--output", required=True, metavar="FILE.png",
                        help="the joint figure's file")
    parser.add_argument("--path", dest="path_output", metavar="FILE.png",
                        help="the Cartesian path figure's file (default: the -o name + _path.png)")
    parser.add_argument("--size", default="1600x1200", metavar="WxH",
                        help="size of each figure [px] (default: 1600x1200)")
    parser.add_argument("--no-show", dest="show", action="store_false",
                        help="only write the files, even where there is a screen")
    add_client_zenoh_arguments(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """The options checked first (exit 2, nothing read or written), then the samples from the
    recording or from a session on the network, then the figures."""
    setup_logging("WARNING")
    # Here, not at the top: matplotlib and Pinocchio take half a second to import, which only plot pays.
    from .plot import PlotDataError, PlotInputError, PlotSettings, collect_live, read_recording, render

    try:
        settings = PlotSettings.check(arm=args.arm, recording=args.recording, seconds=args.seconds,
                                      start=args.start, end=args.end, output=args.output,
                                      path_output=args.path_output, size=args.size, robot=args.robot,
                                      show=args.show)
    except PlotInputError as exc:
        print(f"{parser.prog}: {exc}", file=sys.stderr)
        return USAGE_ERROR
    try:
        if settings.recording is not None:
            feedback = read_recording(settings.recording, settings.arm, sys.stderr)
        else:
            session = open_session(args, parser)
            signals = StopSignals()
            with session:
                client = Arm(session, settings.arm or DEFAULT_ARM, timeout=2.0)
                try:
                    feedback = collect_live(session, client, settings.seconds, signals.stop, sys.stderr)
                finally:
                    client.close()
    except PlotDataError as exc:
        print(f"{parser.prog}: {exc}", file=sys.stderr)
        return 1
    return render(feedback, settings, sys.stderr)


COMMAND = Command(
    "plot", arguments=_arguments, run=_run,
    help="plot an arm's joint traces and Cartesian path to PNG (live or from a recording)",
    description="Joint positions, velocities and accelerations against time, with the joint limits, "
    "and the control point's path in 3D, from the arm's Servo/posFeedback: live (for --seconds, or "
    "until Ctrl-C) or from a recording (--from). Written as two PNG files, shown on screen if there is "
    "one.", epilog="examples: jara-arm plot --seconds 5 -o run.png; "
    "jara-arm plot --from run.mcap --start 2 --end 4.5 -o ptp.png --size 1920x1080")
