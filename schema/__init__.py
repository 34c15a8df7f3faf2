"""The wire contract of JARA_ARM over Zenoh: the single source of truth.

Types (:mod:`.types`), codes (:mod:`.codes`), the operation table
(:mod:`.operations`), key expressions (:mod:`.keys`), messages
(:mod:`.messages`), the encodings (:mod:`.encoding`) and the codec
(:mod:`.codec`). ``jara_arm.schema.json`` beside this file is generated from
them for clients in other languages.
"""

from .codec import Encoding, Reply, decode_reply, decode_request, encode_reply, encode_request
from .codes import AlarmCode, AlarmType, ReturnCode, StateBit
from .errors import JaraArmError, UnknownOperationError, WireError
from .keys import ArmKeys, Service
from .operations import COMMON, EXT, MIDDLE, OP, Interface, Operation, operation

__all__ = [
    "AlarmCode", "AlarmType", "ArmKeys", "COMMON", "EXT", "Encoding", "Interface", "JaraArmError", "MIDDLE",
    "OP", "Operation", "Reply", "ReturnCode", "Service", "StateBit", "UnknownOperationError",
    "WireError", "decode_reply", "decode_request", "encode_reply", "encode_request", "operation",
]
