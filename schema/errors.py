"""The one error root of the wire schema.

Every failure to read or write a wire value is a :class:`WireError` that names
the offending field (as a path such as ``carPoint.carPos[1][2]``) and says what
was wrong, so that a service can answer ``VALUE_ERR`` with a useful comment.
"""

from __future__ import annotations


class JaraArmError(Exception):
    """Root of every error raised by the ``jara_arm`` packages."""


class WireError(JaraArmError, ValueError):
    """A wire value is malformed; ``field`` names where, ``reason`` says why."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
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
