"""``Command/settings``: the command's settings, for the alarm monitor (and people: it is JSON).

The alarm monitor checks the control point against the Cartesian soft limits
with the command's base offset and control point offset, so it needs the
settings as they are now: they are published on every change, and again every
``SETTINGS_PERIOD`` so that a monitor that started later catches up.
"""

from __future__ import annotations

import threading
import time

import zenoh

from jara_arm.robots import RobotModel
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.planner import MOTION_SETTINGS
from jara_arm.services.runtime.entities import Entities
from jara_arm.services.runtime.wire import Publication

from .settings import Settings
from .state import StateTracker

#: Settings are published at least this often [s] (4 Hz).
SETTINGS_PERIOD = 0.25


class SettingsPublisher:
    """Publishes a ``MotionSettings`` snapshot on change and every ``SETTINGS_PERIOD``; thread-safe."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, tracker: StateTracker, robot: RobotModel,
                 settings: Settings) -> None:
        self._entities = Entities()
        self._pub = self._entities.enter_context(Publication(session, keys.command_settings))
        self._tracker = tracker
        self._robot = robot
        self._lock = threading.Lock()
        self._settings = settings
        self._at = -float("inf")  # [s] monotonic time of the last publication

    def changed(self, settings: Settings) -> None:
        """A setter replaced the settings: publish them now."""
        with self._lock:
            self._settings = settings
            self._put()

    def republish(self) -> None:
        """Publish again unless a change did within the last half period."""
        with self._lock:
            if time.monotonic() - self._at >= 0.5 * SETTINGS_PERIOD:
                self._put()

    def _put(self) -> None:
        # The joint soft limits are the servo's (from its status), the model's until it spoke.
        limits = self._tracker.soft_limit_joint or self._robot.hard_limits
        self._pub.put_message(MOTION_SETTINGS, self._settings.snapshot(limits))
        self._at = time.monotonic()

    def close(self) -> None:
        # Under the lock: a setter's put() on a query worker holds the publisher borrowed.
        with self._lock:
            self._entities.close()
