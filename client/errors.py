"""The client's one error root, :class:`ArmError`, and what it distinguishes."""

from __future__ import annotations

from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import JaraArmError


class ArmError(JaraArmError, RuntimeError):
    """Anything the arm did not do as asked. ``code``: the RETURN_ID it answered, None when it did not."""

    def __init__(self, message: str, code: ReturnCode | None = None) -> None:
        super().__init__(message)
        self.code = code


class Refused(ArmError):
    """The service answered with a RETURN_ID other than OK: ``code`` and its ``comment`` say why."""

    code: ReturnCode

    def __init__(self, op: str, code: ReturnCode, comment: str) -> None:
        super().__init__(f"{op}: {code.name} ({int(code)}): {comment}", code)
        self.op = op
        self.comment = comment


class NoAnswer(ArmError):
    """No answer within the timeout, or nobody serves the operation (the service is not running)."""


class MotionFailed(ArmError):
    """An accepted motion did not reach its end: discarded by a stop, an alarm or a lost service.
    ``alarms``: the active alarms when it was found out (the 0x420 WARNING names the motion)."""

    def __init__(self, message: str, motion: int, alarms: tuple[str, ...]) -> None:
        super().__init__(message)
        self.motion = motion
        self.alarms = alarms


class StateTimeout(ArmError):
    """A wait for a state (``Arm.wait_state``) ran out: ``state`` is the last one read."""

    def __init__(self, state: int, timeout: float) -> None:
        super().__init__(f"the state did not come within {timeout:g} s (last 0x{state:02x})")
        self.state = state


__all__ = ["ArmError", "MotionFailed", "NoAnswer", "Refused", "StateTimeout"]
