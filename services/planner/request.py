"""What the planner is asked, decoded once off the wire (``PlanRequest``), and how it refuses (``PlanRefused``).

``Planner/plan`` carries a ``MotionRequest`` (``schema/planner.py``, the wire
contract): the operation's name, its ``in`` parameters in wire form (maps and
lists) and the settings snapshot. The command service must encode the
parameters for that hop (another process); on the planner's side they are
decoded exactly once, by :meth:`PlanRequest.decode` in the plan worker, and the
typed value goes on from there: to the early start's head in the planner's
process and, pickled, to the planning child (``worker.py``), which decodes
nothing.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from jara_arm.schema import codec
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import Refusal, WireError
from jara_arm.schema.operations import MIDDLE
from jara_arm.schema.planner import MotionRequest, MotionSettings


class PlanRefused(Refusal):
    """A motion that is not queued: ``code`` and ``comment`` go back to the client."""


@dataclasses.dataclass(frozen=True)
class PlanRequest:
    """One IDL motion operation as the planner plans it: built by :meth:`decode`, read-only from then on."""

    op: str  # the IDL name of a motion operation (``Operation.motion``)
    #: Its ``in`` parameters by name as Python values of their IDL types (``JointPos`` [rad or m],
    #: ``CarPosWithElbow`` [m, rad], ``angleRatio`` [%]): checked for form, not yet against the robot.
    args: Mapping[str, Any]
    settings: MotionSettings  # the command service's, as they were at acceptance

    @classmethod
    def decode(cls, req: MotionRequest) -> PlanRequest:
        """``req`` with its parameters decoded from their wire form; raises PlanRefused: NOT_IMPLEMENTED for an
        operation that is not a motion, VALUE_ERR naming the field for a malformed parameter."""
        op = MIDDLE.get(req.op)
        if op is None or not op.motion:
            raise PlanRefused(ReturnCode.NOT_IMPLEMENTED, f"{req.op!r} is not a motion operation")
        try:
            args = codec.decode_args(op, req.args)
        except WireError as exc:
            raise PlanRefused(ReturnCode.VALUE_ERR, str(exc)) from None
        return cls(op.name, args, req.settings)


__all__ = ["PlanRefused", "PlanRequest"]
