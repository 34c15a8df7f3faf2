"""``Servo/world``: the robot model and the obstacles a servo runs, for viewers.

Nothing of it changes while the servo runs, so it is published every
``WORLD_PERIOD`` (a viewer or a recorder that starts later catches up) from the
service's main thread, never from the loop's, and a get on the key answers it
at once.
"""

from __future__ import annotations

import zenoh

from jara_arm.robots import RobotModel
from jara_arm.robots.model import Obstacle
from jara_arm.schema import codec
from jara_arm.schema.encoding import Encoding
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.messages import SERVO_WORLD, ServoWorld, WorldBox
from jara_arm.services.runtime.entities import Entities
from jara_arm.services.runtime.wire import Publication

#: ``Servo/world`` is published this often [s].
WORLD_PERIOD = 1.0


def servo_world(model: RobotModel, obstacles: tuple[Obstacle, ...]) -> ServoWorld:
    """The message of a servo that runs ``model`` among ``obstacles`` (the model's own and the added ones)."""
    return ServoWorld(model.name, tuple(model.base_position),
                      tuple(WorldBox(tuple(box.position), tuple(box.half_extents)) for box in obstacles))


class WorldPublisher:
    """Publishes one arm's :class:`ServoWorld` on :meth:`publish`; :meth:`answer` is its get's answer."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, world: ServoWorld) -> None:
        self.world = world
        self._entities = Entities()
        self._pub = self._entities.enter_context(Publication(session, keys.servo_world))

    def publish(self) -> None:
        self._pub.put_message(SERVO_WORLD, self.world)

    def answer(self, key: str, _payload: bytes, encoding: Encoding) -> tuple[str, bytes]:
        """The reply to a get on ``Servo/world``, in the request's encoding (JSON to ``{}``)."""
        return key, codec.encode_message(SERVO_WORLD, self.world, encoding)

    def close(self) -> None:
        self._entities.close()
