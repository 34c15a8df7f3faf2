"""Argument types shared by the services' and the launcher's command lines.

Each raises ``argparse.ArgumentTypeError``, so argparse prints the option, the
value and what it expected, and exits 2.
"""

from __future__ import annotations

import argparse
import math

from jara_arm.robots.model import Obstacle, RobotModelError


def positive_int(text: str) -> int:
    """A whole number of 1 or more (a count)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of 1 or more, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number of 1 or more, got {value}")
    return value


def positive_float(text: str) -> float:
    """A finite number above 0 (seconds, a rate [Hz])."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (value > 0.0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return value


def non_negative_float(text: str) -> float:
    """A finite number of 0 or more (a time from a start [s])."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of 0 or more, got {text!r}") from None
    if not (value >= 0.0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"expected a number of 0 or more, got {text}")
    return value


def obstacle_argument(text: str) -> Obstacle:
    """A box of the world, ``x,y,z,hx,hy,hz`` [m]: centre and half extents (``--obstacle``)."""
    try:
        return Obstacle.parse(text)
    except RobotModelError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
