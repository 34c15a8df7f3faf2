"""The one error root of the kinematics package."""

from __future__ import annotations

from jara_arm.schema.errors import JaraArmError

__all__ = ["KinematicsError"]


class KinematicsError(JaraArmError, ValueError):
    """A kinematics request that cannot be evaluated (bad shape, unknown joint or frame, ...).

    A ``ValueError`` too, so that callers that only know about bad values catch it.
    """
