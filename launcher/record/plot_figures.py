"""The two figures of ``jara-arm plot``, drawn into a given matplotlib Figure from plain arrays.

* joints: a row per arm axis, columns position / velocity / acceleration against
  time, with the limits as horizontal lines (labelled :data:`HARD`, :data:`SOFT`,
  :data:`SPEED`, :data:`ACCEL`, so that a reader of the Axes finds them);
* path: the control point's path in 3D (the arm base frame), start and end marked.

No pyplot here: the caller makes the Figure (on screen or not) and writes it.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from jara_arm.schema.errors import JaraArmError

from .traces import JointLimits, Traces

#: Labels of the limit lines.
HARD, SOFT, SPEED, ACCEL = "hard limit", "soft limit", "rated speed", "max acceleration"
DPI = 100  #: [px per inch] figures are sized in pixels; this only converts
_LIMIT_STYLE = {HARD: dict(color="tab:red", linestyle="--", linewidth=1.0),
                SOFT: dict(color="tab:orange", linestyle=":", linewidth=1.2),
                SPEED: dict(color="tab:red", linestyle="--", linewidth=1.0),
                ACCEL: dict(color="tab:red", linestyle="--", linewidth=1.0)}
_SIZE = re.compile(r"\s*(\d+)\s*[xX]\s*(\d+)\s*")


class SizeError(JaraArmError, ValueError):
    """A ``--size`` that is not WxH in pixels within :attr:`Size.LOWEST` .. :attr:`Size.HIGHEST`."""


@dataclasses.dataclass(frozen=True)
class Size:
    """A figure's size [px]."""

    width: int
    height: int

    LOWEST = 200  #: [px] smaller cannot hold the 7 x 3 panels' labels
    HIGHEST = 10000  #: [px] larger is a typing mistake (and gigabytes of pixels)

    @classmethod
    def parse(cls, text: str) -> "Size":
        """``1600x1200``; SizeError saying what is expected otherwise."""
        m = _SIZE.fullmatch(text)
        if m is None:
            raise SizeError(f"size {text!r}: expected WIDTHxHEIGHT in pixels, e.g. 1600x1200")
        size = cls(int(m[1]), int(m[2]))
        if not all(cls.LOWEST <= v <= cls.HIGHEST for v in (size.width, size.height)):
            raise SizeError(f"size {text!r}: width and height must be {cls.LOWEST} .. {cls.HIGHEST} px")
        return size

    @property
    def inches(self) -> tuple[float, float]:
        return self.width / DPI, self.height / DPI


def draw_joints(fig: Figure, traces: Traces, limits: JointLimits, prismatic: Sequence[bool], title: str) -> None:
    """Position, velocity and acceleration of every arm axis against time, limits drawn."""
    n = traces.axes
    if limits.axes != n or len(prismatic) != n:
        raise ValueError(f"{n} axes of traces, {limits.axes} of limits, {len(prismatic)} of prismatic")
    fig.set_layout_engine("constrained")  # the panels fill the figure, labels and legend included
    axes = fig.subplots(n, 3, sharex=True, squeeze=False)
    for j in range(n):
        unit = "m" if prismatic[j] else "rad"
        pos, vel, acc = axes[j]
        pos.plot(traces.t, traces.q[:, j], color="tab:blue", linewidth=1.0)
        vel.plot(traces.t_vel, traces.vel[:, j], color="tab:green", linewidth=1.0)
        acc.plot(traces.t_acc, traces.acc[:, j], color="tab:purple", linewidth=0.8)
        _hlines(pos, HARD, (limits.hard[j].lower, limits.hard[j].upper))
        if limits.soft is not None and limits.soft[j] != limits.hard[j]:  # the same lines once
            _hlines(pos, SOFT, (limits.soft[j].lower, limits.soft[j].upper))
        _hlines(vel, SPEED, (-limits.speed[j], limits.speed[j]))
        _hlines(acc, ACCEL, (-limits.accel[j], limits.accel[j]))
        pos.set_ylabel(f"J{j + 1} [{unit}]")
        vel.set_ylabel(f"[{unit}/s]")
        acc.set_ylabel(f"[{unit}/s²]")
        for ax in axes[j]:
            ax.grid(True, linewidth=0.3)
            ax.tick_params(labelsize=7)
    for ax, what in zip(axes[0], ("position", "velocity", "acceleration")):
        ax.set_title(what, fontsize=10)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    handles = {line.get_label(): line for ax in axes.flat for line in ax.get_lines() if _is_limit(line.get_label())}
    fig.legend(list(handles.values()), list(handles.keys()), loc="upper right", fontsize=8, ncols=len(handles))
    fig.suptitle(title, fontsize=11, x=0.01, ha="left")


def _hlines(ax: Axes, label: str, values: tuple[float, float]) -> None:
    for v in values:
        ax.axhline(v, label=label, **_LIMIT_STYLE[label])  # type: ignore[arg-type]


def _is_limit(label: object) -> bool:
    return label in _LIMIT_STYLE


def limit_lines(ax: Axes) -> dict[str, list[float]]:
    """The limit lines drawn on ``ax``: label -> their heights, in drawing order (for tests and readers)."""
    found: dict[str, list[float]] = {}
    for line in ax.get_lines():
        label = line.get_label()
        if _is_limit(label):
            found.setdefault(str(label), []).append(float(np.asarray(line.get_ydata())[0]))
    return found


def draw_path(fig: Figure, points: np.ndarray, title: str, what: str = "control point") -> None:
    """The path ``points`` (M, 3) [m] of ``what`` in 3D, equal scales on the three axes, start and end marked."""
    ax = fig.add_subplot(projection="3d")
    ax.plot(points[:, 0], points[:, 1], points[:, 2], color="tab:blue", linewidth=1.2, label=what)
    ax.scatter(*points[0], color="tab:green", s=60, marker="o", label="start", depthshade=False)
    ax.scatter(*points[-1], color="tab:red", s=60, marker="s", label="end", depthshade=False)
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    half = max(0.55 * float(np.ptp(points, axis=0).max()), 0.01)  # [m] equal scales, at least 2 cm across
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1.0, 1.0, 1.0))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.legend(loc="upper left", fontsize=9)
    fig.suptitle(title, fontsize=11, x=0.01, ha="left")
