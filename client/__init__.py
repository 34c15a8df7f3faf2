"""``jara_arm.client``: a Python API of one arm over Zenoh (clients in other languages need none of it).

=============  ====================================================================================
``arm``        :class:`Arm`: every operation by its IDL name, typed; :func:`rel` for relative targets
``motion``     :class:`Motion`, what a move returns: ``wait()``, ``fate``, ``progress``, ``done``
``errors``     :class:`ArmError`, the package's one error root: ``Refused``, ``NoAnswer``, ``MotionFailed``, ``StateTimeout``
``operations`` the typed methods, generated from ``jara_arm.schema`` (``python -m jara_arm.client.generate``)
=============  ====================================================================================
"""

from .arm import Arm, rel
from .errors import ArmError, MotionFailed, NoAnswer, Refused, StateTimeout
from .motion import Fate, Motion

__all__ = ["Arm", "ArmError", "Fate", "Motion", "MotionFailed", "NoAnswer", "Refused", "StateTimeout", "rel"]
