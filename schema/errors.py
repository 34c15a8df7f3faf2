"""The one error root of the ``jara_arm`` packages, and the one way an operation says no.

A handler that does not do what it was asked raises :class:`Refusal`: its RETURN_ID code and comment
are the reply (``services/runtime/rpc.py``). Every failure to read or write a wire value is a
:class:`WireError`, a ``VALUE_ERR`` refusal that names the offending field (as a path such as
``carPoint.carPos[1][2]``) and says what was wrong.
"""

from __future__ import annotations

from .codes import ReturnCode


class JaraArmError(Exception):
    """Root of every error raised by the ``jara_arm`` packages."""


class Refusal(JaraArmError):
    """An operation not done: ``code`` (RETURN_ID, never OK) and ``comment`` are its reply."""

    def __init__(self, code: ReturnCode, comment: str) -> None:
        super().__init__(comment)
        self.code = code
        self.comment = comment


class WireError(Refusal, ValueError):
    """A wire value is malformed (``VALUE_ERR``); ``field`` names where, ``reason`` says why."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(ReturnCode.VALUE_ERR, f"{field}: {reason}")
        self.field = field
        self.reason = reason


class UnknownOperationError(JaraArmError, KeyError):
    """An operation name that the interface does not define."""

    def __init__(self, interface: str, name: str, valid: list[str]) -> None:
        super().__init__(
            f"{interface} has no operation {name!r}; valid operations: {', '.join(sorted(valid))}"
        )
        self.interface = interface
        self.name = name

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])
