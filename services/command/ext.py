"""``Ext``: the command service's model-specific operations, outside the JARA_ARM IDL.

Served at ``JARA_ARM/<arm>/Ext/<op>`` with the IDL's reply rules (``RETURN_ID``,
``VALUE_ERR`` naming the field). The values live in the same :class:`Settings`
as the Middle ones (``CommandMiddle`` owns them), so that every motion's
``MotionSettings`` snapshot carries them.
"""

from __future__ import annotations

from jara_arm.schema.codec import Reply
from jara_arm.services.runtime.rpc import ok

from .middle import CommandMiddle


class CommandExt:
    """The Ext interface; runs on its own RPC thread, changing the settings through ``middle``."""

    def __init__(self, middle: CommandMiddle) -> None:
        self._middle = middle

    def setBlendDistance(self, distance: float) -> Reply:
        """For the motions accepted from now on; queued ones keep the distance they were accepted with."""
        self._middle.change_settings(lambda s: s.with_blend_distance(distance))
        return ok()

    def getBlendDistance(self) -> Reply:
        return ok(distance=self._middle.settings.blend_distance)
