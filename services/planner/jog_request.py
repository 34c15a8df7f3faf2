"""A jog's request: ``Ext/jogJoint`` and ``Ext/jogCartesian`` decoded once, as the jogger (``jog.py``) reads them."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

from jara_arm.schema.errors import WireError
from jara_arm.schema.operations import JOG_AXES, JOG_FRAMES, JOG_LEASE_MS, OP


@dataclasses.dataclass(frozen=True)
class JogCommand:
    """One jog call, decoded once (:meth:`decode`)."""

    op: str  # OP.jogJoint or OP.jogCartesian
    joint: int  # jogJoint: the joint's index (0 = J1); -1 for a Cartesian jog
    frame: str  # jogCartesian: "base" or "tool"; "" for a joint jog
    axis: int  # jogCartesian: 0..5 = x, y, z, rx, ry, rz; -1 for a joint jog
    sign: float  # +1 or -1: the direction
    ratio: float  # (0, 1]: the share of the max speed
    lease: float  # [s]

    @classmethod
    def decode(cls, op: str, args: Mapping[str, Any], axis_num: int) -> JogCommand:
        """The jog ``args`` of ``op`` ask for; raises WireError naming the field."""
        ratio = float(args["speedRatio"])
        if not (math.isfinite(ratio) and 0.0 < abs(ratio) <= 100.0):
            raise WireError("speedRatio", f"-100 .. 100 %, not 0 (jogStop ends a jog), got {ratio}")
        lease = int(args["leaseMs"])
        if not JOG_LEASE_MS[0] <= lease <= JOG_LEASE_MS[1]:
            raise WireError("leaseMs", f"{JOG_LEASE_MS[0]} .. {JOG_LEASE_MS[1]} ms, got {lease}")
        sign, share, seconds = math.copysign(1.0, ratio), abs(ratio) / 100.0, lease / 1000.0
        if op == OP.jogJoint:
            axis = int(args["axis"])
            if not 1 <= axis <= axis_num:
                raise WireError("axis", f"1 .. {axis_num} (J1 .. J{axis_num}), got {axis}")
            return cls(op, axis - 1, "", -1, sign, share, seconds)
        if op == OP.jogCartesian:
            frame, name = str(args["frame"]), str(args["axis"])
            if frame not in JOG_FRAMES:
                raise WireError("frame", f"one of {', '.join(JOG_FRAMES)}, got {frame!r}")
            if name not in JOG_AXES:
                raise WireError("axis", f"one of {', '.join(JOG_AXES)}, got {name!r}")
            return cls(op, -1, frame, JOG_AXES.index(name), sign, share, seconds)
        raise WireError("op", f"not a jog: {op!r}")  # pragma: no cover - the service routes only jogs here

    def same_jog(self, other: JogCommand) -> bool:
        """Whether ``other`` renews this jog (the same axis and direction; the speed may differ)."""
        return (self.op, self.joint, self.frame, self.axis, self.sign) == (
            other.op, other.joint, other.frame, other.axis, other.sign)

    def describe(self) -> str:
        sign = "+" if self.sign > 0 else "-"
        if self.joint >= 0:
            return f"J{self.joint + 1} {sign}"
        return f"{self.frame} {JOG_AXES[self.axis]} {sign}"
