"""What ``rmw_zenoh`` (ROS 2's Zenoh middleware, ``rmw_zenoh_cpp`` 0.2+, Jazzy) puts on the wire, so that a ROS 2
node reads our topics with no bridge: data keys, liveliness tokens, QoS text, GIDs and attachments.

From ros2/rmw_zenoh (``docs/design.md``, ``src/detail/liveliness_utils.cpp``, ``attachment_helpers.cpp``):

* **Data key** ``<domain>/<topic without its leading and trailing "/">/<DDS type>/<RIHS01 hash>``, the DDS type
  being ``pkg::msg::dds_::Name_``. The payload is CDR with its 4-byte encapsulation header (``messages.py``).
* **Attachment** of every sample: the sequence number (int64), the source timestamp [ns] (int64) and the
  publisher's GID (16 bytes, length-prefixed), in Zenoh's own serialization (``zenoh.ext.z_serialize``):
  33 bytes.
* **Liveliness tokens** ``@ros2_lv/<domain>/<zid>/<nid>/<id>/<NN|MP|MS|SS|SC>/<enclave>/<namespace>/<node>``,
  then for a topic ``/<topic>/<type>/<hash>/<qos>``; every name with its ``/`` turned into ``%`` (an empty
  namespace is ``/``, hence ``%``). ``ros2 node list`` and ``ros2 topic list`` are read from these.
* **QoS** in a token: reliability, durability, ``history,depth``, ``deadline s,ns``, ``lifespan s,ns``,
  ``liveliness,lease s,ns``, separated by ``:``; each left empty where it is rmw_zenoh's default (reliable,
  volatile, keep last 42, infinite, automatic).
* **GID** of an entity: XXH3-128 of its liveliness key, the low 64 bits then the high 64, little-endian.

Pure functions and values: no session here (``bridge.py`` declares them).
"""

from __future__ import annotations

import dataclasses
import enum

import xxhash
from zenoh.ext import Int64, z_serialize

from jara_arm.schema.keys import ROS2_ADMIN_SPACE as ADMIN_SPACE  # the admin space of every token
#: ROS 2 domain ids (``ROS_DOMAIN_ID``).
DOMAINS = range(0, 233)


class Rmw2Error(ValueError):
    """A name or value ROS 2 would not take; the message says which and why."""


class Entity(enum.StrEnum):
    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


class Reliability(enum.IntEnum):  # rmw_qos_reliability_policy_e
    RELIABLE = 1
    BEST_EFFORT = 2


class Durability(enum.IntEnum):  # rmw_qos_durability_policy_e
    TRANSIENT_LOCAL = 1
    VOLATILE = 2


@dataclasses.dataclass(frozen=True)
class QoS:
    """The QoS of a publisher (keep last ``depth``)."""

    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE
    depth: int = 10

    def text(self) -> str:
        """As in a liveliness token (``qos_to_keyexpr``): the defaults left empty."""
        rel = "" if self.reliability is Reliability.RELIABLE else str(int(self.reliability))
        dur = "" if self.durability is Durability.VOLATILE else str(int(self.durability))
        depth = "" if self.depth == 42 else str(self.depth)
        return f"{rel}:{dur}:,{depth}:,:,:,,"


#: A sensor stream (``joint_states``, ``tf``): as ROS 2's default publisher (keep last 10, reliable).
STREAM = QoS()
#: A latched value (``robot_description``): transient local, keep last 1, as robot_state_publisher's.
LATCHED = QoS(durability=Durability.TRANSIENT_LOCAL, depth=1)


def check_name(name: str, what: str) -> str:
    """``name`` if it is a ROS 2 name (``/`` separated tokens of letters, digits and ``_``, not starting with a
    digit), else Rmw2Error naming ``what``."""
    parts = name.strip("/").split("/")
    for part in parts:
        if not part or part[0].isdigit() or not all((c.isascii() and c.isalnum()) or c == "_" for c in part):
            raise Rmw2Error(f"{what} {name!r}: ROS 2 names are '/'-separated tokens of letters, digits and '_', "
                            "each starting with a letter or '_'")
    return name


def check_domain(domain: int) -> int:
    if domain not in DOMAINS:
        raise Rmw2Error(f"ROS domain {domain}: ROS 2 takes {DOMAINS.start} .. {DOMAINS.stop - 1}")
    return domain


def mangle(name: str) -> str:
    """A ROS name as one chunk of a token (``mangle_name``)."""
    return name.replace("/", "%")


def dds_type(ros_type: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs::msg::dds_::JointState_``."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def data_key(domain: int, topic: str, ros_type: str, type_hash: str) -> str:
    """The key expression of ``topic``'s samples."""
    return f"{domain}/{topic.strip('/')}/{dds_type(ros_type)}/{type_hash}"


@dataclasses.dataclass(frozen=True)
class Node:
    """A ROS 2 node as rmw_zenoh announces it: its session's Zenoh id and its entity ids."""

    domain: int
    zid: str  # str(session.zid())
    nid: int  # the node's entity id in its session
    namespace: str  # "/" or "/arm0"
    name: str
    enclave: str = "/"

    def _head(self, entity: Entity, eid: int) -> str:
        return "/".join([ADMIN_SPACE, str(self.domain), self.zid, str(self.nid), str(eid), entity.value,
                         mangle(self.enclave), mangle(self.namespace), mangle(self.name)])

    def token(self) -> str:
        """The node's own liveliness key (``NN``)."""
        return self._head(Entity.NODE, self.nid)

    def publisher_token(self, eid: int, topic: str, ros_type: str, type_hash: str, qos: QoS) -> str:
        """The liveliness key of its publisher ``eid`` of ``topic`` (absolute, as ``/arm0/joint_states``)."""
        return "/".join([self._head(Entity.PUBLISHER, eid), mangle(topic), mangle(dds_type(ros_type)),
                         mangle(type_hash), qos.text()])


def gid(token: str) -> bytes:
    """An entity's GID: the XXH3-128 of its liveliness key, low 64 bits first, each little-endian."""
    h = xxhash.xxh3_128_intdigest(token.encode())
    return (h & (2**64 - 1)).to_bytes(8, "little") + (h >> 64).to_bytes(8, "little")


def attachment(sequence: int, timestamp_ns: int, source_gid: bytes) -> bytes:
    """A sample's attachment: sequence number, source timestamp [ns], GID (length-prefixed)."""
    return z_serialize((Int64(sequence), Int64(timestamp_ns), source_gid)).to_bytes()


@dataclasses.dataclass(frozen=True)
class Token:
    """A liveliness key read back (:func:`parse_token`)."""

    domain: int
    zid: str
    nid: str
    id: str
    entity: Entity
    enclave: str
    namespace: str
    node: str
    topic: str = ""
    type: str = ""  # the DDS type
    type_hash: str = ""
    qos: tuple[str, ...] = ()  # the six ':'-separated fields


def parse_token(key: str) -> Token:
    """A liveliness key as rmw_zenoh's graph cache reads it (``Entity::make``); Rmw2Error if it would not."""
    parts = key.split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE or any(not p for p in parts):
        raise Rmw2Error(f"not an rmw_zenoh liveliness token (9 or 13 non-empty chunks under {ADMIN_SPACE}): {key!r}")
    try:
        entity = Entity(parts[5])
    except ValueError:
        raise Rmw2Error(f"entity {parts[5]!r}: one of {', '.join(e.value for e in Entity)}") from None
    demangle = [p.replace("%", "/") for p in parts]
    token = Token(int(parts[1]), parts[2], parts[3], parts[4], entity, demangle[6], demangle[7], demangle[8])
    if entity is Entity.NODE:
        return token
    if len(parts) != 13:
        raise Rmw2Error(f"a {entity.value} token has 13 chunks, this one {len(parts)}: {key!r}")
    qos = tuple(parts[12].split(":"))
    if len(qos) != 6 or [len(q.split(",")) for q in qos[2:]] != [2, 2, 2, 3]:
        raise Rmw2Error(f"QoS {parts[12]!r}: 'rel:dur:hist,depth:dl_s,dl_ns:ls_s,ls_ns:liv,lease_s,lease_ns'")
    return dataclasses.replace(token, topic=demangle[9], type=demangle[10], type_hash=demangle[11], qos=qos)


__all__ = ["ADMIN_SPACE", "DOMAINS", "Durability", "Entity", "LATCHED", "Node", "QoS", "Reliability", "Rmw2Error",
           "STREAM", "Token", "attachment", "check_domain", "check_name", "data_key", "dds_type", "gid", "mangle",
           "parse_token"]
