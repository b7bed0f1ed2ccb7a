"""ROS 2's Zenoh middleware (``rmw_zenoh_cpp``, Jazzy) on the wire, spoken without ROS.

kinesphere is Zenoh-native, and so is rmw_zenoh: a ROS 2 topic is a Zenoh key, a message is
its CDR bytes, and the ROS graph (``ros2 topic list``, ``ros2 node list``) is a set of
liveliness tokens. This module is that format and nothing else; :mod:`kinesphere.ros2node`
declares the Zenoh entities that use it. The layout follows rmw_zenoh_cpp's
``liveliness_utils.cpp``, ``attachment_helpers.cpp`` and ``qos.cpp``:

- data key ``<domain>/<topic without leading slash>/<dds type>/<RIHS01 hash>``, e.g.
  ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...``;
- graph token ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<NN|MP|MS|SS|SC>/<enclave>/
  <namespace>/<node>[/<topic>/<dds type>/<hash>/<qos>]`` with every ``/`` inside a field
  written ``%`` (so the root namespace ``/`` is ``%``);
- every sample carries an attachment: zenoh-ext serialisation of i64 sequence number, i64
  source timestamp in ns and the 16-byte publisher gid as a sequence (LEB128 length ``0x10``,
  then the bytes), 33 bytes, as Jazzy writes it since 0.2.4 (rmw_zenoh#605); rmw_zenoh
  subscribers drop samples without one.

Humble's rmw_zenoh (0.1.x) writes the same format with ``TypeHashNotSupported`` where Jazzy
writes the hash (Humble has no type hashes): ``distro="humble"`` makes keys and tokens that way.
The messages kinesphere uses have the same layout in both distributions (the test suite checks
rosbags' Humble store against its Jazzy one), so their CDR is the same.

CDR and the RIHS01 type hashes come from ``rosbags`` (its Jazzy type store) and gids from
``xxhash``, the optional extra ``kinesphere[ros2]``: only code that talks to ROS 2 imports
them, through :func:`typestore` and :func:`gid_of`, which name the extra when it is missing.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from enum import StrEnum
from functools import cache
from typing import TYPE_CHECKING, Any, Final

from zenoh import ZBytes

from kinesphere.errors import KinesphereError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

ADMIN_SPACE: Final = "@ros2_lv"
"""First chunk of every ROS graph liveliness token."""
SLASH: Final = "%"
"""How a ``/`` inside a token field is written (a bare ``%`` is the root namespace)."""
MAX_DOMAIN: Final = 232
"""Largest ROS domain id (the DDS port arithmetic rmw_zenoh keeps for compatibility)."""
MAX_NAME: Final = 255
"""Characters in a ROS name (node, namespace, topic) this module builds or accepts."""
MAX_PAYLOAD: Final = 4 * 1024 * 1024
"""Bytes of one CDR message accepted from the wire (a URDF is the largest we read)."""
MAX_SEQUENCE: Final = 4096
"""Elements of any sequence field accepted from the wire (joints, axes, trajectory points)."""
GID_SIZE: Final = 16
"""``RMW_GID_STORAGE_SIZE`` since Jazzy."""
GID_LENGTH: Final = bytes([GID_SIZE])
"""The gid's sequence length as zenoh-ext writes it (LEB128 of 16 is one byte, ``0x10``)."""
ATTACHMENT_SIZE: Final = 8 + 8 + len(GID_LENGTH) + GID_SIZE
EXTRA_HINT: Final = "ROS 2 support needs the ros2 extra: pip install 'kinesphere[ros2]'"
ROS_DISTROS: Final = ("jazzy", "humble")
"""The ROS 2 distributions whose rmw_zenoh this module speaks; the first is the default."""
HUMBLE_HASH: Final = "TypeHashNotSupported"
"""What Humble's rmw_zenoh writes where Jazzy writes the RIHS01 hash (``rmw_publisher_data.cpp``
of the humble branch)."""

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/(msg|srv|action)/([A-Z][A-Za-z0-9]*)$")


class EntityKind(StrEnum):
    """The entity a graph token announces."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


# --- names ---------------------------------------------------------------------------------


def ros_name(text: str) -> str:
    """``text`` made a valid ROS name token: other characters become ``_``, a leading digit
    gets a ``_`` before it (robot ``baxter-1`` is ROS ``baxter_1``)."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", text)[:MAX_NAME] or "_"
    return f"_{name}"[:MAX_NAME] if name[0].isdigit() else name


def check_node_name(name: str) -> str:
    """A node name: one token of letters, digits and ``_``, not starting with a digit."""
    if not isinstance(name, str) or len(name) > MAX_NAME or not _TOKEN.match(name):
        raise KinesphereError(
            "malformed", f"ROS node name {name!r}: use letters, digits and _, no leading digit"
        )
    return name


def check_namespace(namespace: str) -> str:
    """An absolute namespace, ``/`` or ``/a/b``; a missing leading ``/`` is added."""
    if not isinstance(namespace, str):
        raise KinesphereError("malformed", f"ROS namespace must be text, got {namespace!r}")
    ns = namespace if namespace.startswith("/") else f"/{namespace}"
    if ns != "/":
        _check_tokens(ns, "namespace")
    return ns


def resolve(namespace: str, name: str) -> str:
    """The absolute topic of ``name`` seen from ``namespace`` (ROS name resolution without
    ``~`` and substitutions): ``resolve("/ns", "joy") == "/ns/joy"``, absolute names stay."""
    if not isinstance(name, str) or not name:
        raise KinesphereError("malformed", f"ROS topic name must be non-empty text, got {name!r}")
    ns = check_namespace(namespace)
    topic = name if name.startswith("/") else f"{ns.rstrip('/')}/{name}"
    _check_tokens(topic, "topic")
    return topic


def _check_tokens(path: str, what: str) -> None:
    tokens = path[1:].split("/")
    if len(path) > MAX_NAME or not all(_TOKEN.match(t) for t in tokens):
        raise KinesphereError(
            "malformed",
            f"ROS {what} {path!r}: '/'-separated tokens of letters, digits and _, "
            f"none empty or starting with a digit, at most {MAX_NAME} characters",
        )


def check_domain(domain: int) -> int:
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= MAX_DOMAIN:
        raise KinesphereError("malformed", f"ROS domain id must be 0..{MAX_DOMAIN}, got {domain!r}")
    return domain


def mangle(name: str) -> str:
    """A name as one token field: every ``/`` written ``%``."""
    return name.replace("/", SLASH)


# --- types ---------------------------------------------------------------------------------


def check_type(ros_type: str) -> tuple[str, str, str]:
    """``pkg/msg/Name`` split in three, or ``malformed``."""
    m = _TYPE.match(ros_type) if isinstance(ros_type, str) else None
    if m is None:
        raise KinesphereError("malformed", f"ROS type {ros_type!r}: expected pkg/msg/Name")
    return m.group(1), m.group(2), m.group(3)


def dds_type_name(ros_type: str) -> str:
    """The type name rmw_zenoh puts in keys: ``sensor_msgs::msg::dds_::JointState_``."""
    pkg, kind, name = check_type(ros_type)
    return f"{pkg}::{kind}::dds_::{name}_"


@cache
def typestore() -> Typestore:
    """rosbags' Jazzy type store with sequences bounded by :data:`MAX_SEQUENCE`."""
    try:
        from rosbags.typesys.store import Typestore
        from rosbags.typesys.stores import ros2_jazzy
    except ImportError:
        raise KinesphereError("unavailable", EXTRA_HINT) from None
    return Typestore(ros2_jazzy, max_sequence_length=MAX_SEQUENCE)


def check_distro(distro: str) -> str:
    if distro not in ROS_DISTROS:
        raise KinesphereError("malformed", f"ROS 2 distribution {distro!r}; valid: "
                              f"{', '.join(ROS_DISTROS)}")
    return distro


@cache
def type_hash(ros_type: str, distro: str = "jazzy") -> str:
    """The RIHS01 hash of a type (``RIHS01_`` and 64 hex digits), as rmw_zenoh keys carry it;
    for Humble, :data:`HUMBLE_HASH`."""
    check_type(ros_type)
    store = typestore()
    if ros_type not in store.fielddefs:
        raise KinesphereError("malformed", f"ROS type {ros_type!r} is not in the Jazzy type store")
    return HUMBLE_HASH if check_distro(distro) == "humble" else store.hash_rihs01(ros_type)


def message_class(ros_type: str) -> Any:
    """The rosbags dataclass of ``ros_type`` (construct messages with it)."""
    type_hash(ros_type)  # checks the name
    return typestore().types[ros_type]


def serialize(message: object, ros_type: str) -> bytes:
    """CDR bytes (little endian, with the 4-byte encapsulation header) of a message."""
    return bytes(typestore().serialize_cdr(message, ros_type, little_endian=True))


def deserialize(payload: bytes | bytearray | memoryview, ros_type: str,
                max_bytes: int = MAX_PAYLOAD) -> Any:
    """A message from CDR bytes; too large, truncated or garbled input is ``malformed``."""
    if len(payload) > max_bytes:
        raise KinesphereError(
            "malformed", f"{ros_type} of {len(payload)} bytes exceeds the {max_bytes}-byte limit"
        )
    store = typestore()
    from rosbags.serde import SerdeError

    try:
        return store.deserialize_cdr(bytes(payload), ros_type)
    except (SerdeError, ValueError, IndexError, KeyError, TypeError) as exc:
        raise KinesphereError("malformed", f"bad {ros_type} CDR: {exc}") from None


# --- keys ----------------------------------------------------------------------------------


def topic_key(domain: int, topic: str, ros_type: str, *, any_hash: bool = False,
              distro: str = "jazzy") -> str:
    """The data key of an absolute topic; ``any_hash`` puts ``*`` for the hash, which a
    subscriber may use to also hear peers of other distros (Humble writes no hash)."""
    if not topic.startswith("/"):
        raise KinesphereError("malformed", f"topic {topic!r} must be absolute (resolve it)")
    _check_tokens(topic, "topic")
    h = "*" if any_hash else type_hash(ros_type, distro)
    return f"{check_domain(domain)}/{topic.strip('/')}/{dds_type_name(ros_type)}/{h}"


@dataclass(frozen=True)
class Qos:
    """The QoS a token announces: reliable or best effort, volatile or transient local,
    keep-last ``depth`` (0 means rmw_zenoh's default, 42). Deadline, lifespan and liveliness
    are always the defaults (infinite, automatic)."""

    reliable: bool = True
    transient_local: bool = False
    depth: int = 10

    def __post_init__(self) -> None:
        if not 0 <= self.depth <= 10_000:
            raise KinesphereError("malformed", f"QoS depth must be 0..10000, got {self.depth}")

    def keyexpr(self) -> str:
        """rmw_zenoh's compact text: values equal to its defaults (reliable, volatile, keep
        last 42, infinite durations, automatic liveliness) are left empty.
        ``Qos()`` is ``::,10:,:,:,,``; a latched topic ``Qos(transient_local=True, depth=1)``
        is ``:1:,1:,:,:,,``."""
        reliability = "" if self.reliable else "2"  # RMW_QOS_POLICY_RELIABILITY_BEST_EFFORT
        durability = "1" if self.transient_local else ""  # ..._DURABILITY_TRANSIENT_LOCAL
        depth = "" if self.depth in (0, 42) else str(self.depth)
        return f"{reliability}:{durability}:,{depth}:,:,:,,"


LATCHED: Final = Qos(transient_local=True, depth=1)
"""What RViz expects of ``robot_description``: reliable, transient local, depth 1."""


def node_token(domain: int, zid: str, node_id: int, namespace: str, name: str,
               enclave: str = "/") -> str:
    """The graph token of a node (``NN``); its node id and entity id are the same number."""
    return "/".join(_node_fields(domain, zid, node_id, node_id, EntityKind.NODE, namespace, name,
                                 enclave))


def endpoint_token(kind: EntityKind, domain: int, zid: str, node_id: int, entity_id: int,
                   namespace: str, node: str, topic: str, ros_type: str, qos: Qos,
                   enclave: str = "/", distro: str = "jazzy") -> str:
    """The graph token of a publisher (``MP``), subscription (``MS``)... on an absolute topic."""
    if kind is EntityKind.NODE:
        raise KinesphereError("malformed", "an endpoint token needs an endpoint kind")
    if not topic.startswith("/"):
        raise KinesphereError("malformed", f"topic {topic!r} must be absolute (resolve it)")
    _check_tokens(topic, "topic")
    fields = _node_fields(domain, zid, node_id, entity_id, kind, namespace, node, enclave)
    fields += [mangle(topic), mangle(dds_type_name(ros_type)), type_hash(ros_type, distro),
               qos.keyexpr()]
    return "/".join(fields)


def _node_fields(domain: int, zid: str, node_id: int, entity_id: int, kind: EntityKind,
                 namespace: str, name: str, enclave: str) -> list[str]:
    if not re.fullmatch(r"[0-9a-f]{1,32}", zid or ""):
        raise KinesphereError("malformed", f"zenoh id {zid!r} is not lowercase hex")
    for what, n in (("node id", node_id), ("entity id", entity_id)):
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise KinesphereError("malformed", f"{what} must be an int >= 0, got {n!r}")
    return [ADMIN_SPACE, str(check_domain(domain)), zid, str(node_id), str(entity_id),
            str(kind), mangle(check_namespace(enclave)), mangle(check_namespace(namespace)),
            check_node_name(name)]


def graph_wildcard(domain: int) -> str:
    """Every graph token of a domain: ``@ros2_lv/<domain>/**``."""
    return f"{ADMIN_SPACE}/{check_domain(domain)}/**"


@dataclass(frozen=True)
class GraphEntity:
    """A graph token read back (what ``ros2 node list`` / ``ros2 topic list`` are made of)."""

    domain: int
    zid: str
    kind: EntityKind
    namespace: str
    node: str
    topic: str = ""
    dds_type: str = ""
    type_hash: str = ""
    qos: str = ""


def parse_token(key: str) -> GraphEntity:
    """Split a graph token, or ``malformed`` naming what is missing."""
    parts = str(key).split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE or not all(parts):
        raise KinesphereError("malformed", f"{key!r} is not a ROS graph token")
    try:
        kind = EntityKind(parts[5])
        domain = int(parts[1])
    except ValueError:
        raise KinesphereError("malformed", f"{key!r}: bad domain or entity kind") from None
    ns, node = parts[7].replace(SLASH, "/"), parts[8]
    if kind is EntityKind.NODE:
        return GraphEntity(domain, parts[2], kind, ns, node)
    if len(parts) != 13:
        raise KinesphereError("malformed", f"{key!r}: an endpoint token has 13 fields")
    return GraphEntity(domain, parts[2], kind, ns, node, parts[9].replace(SLASH, "/"),
                       parts[10].replace(SLASH, "/"), parts[11], parts[12])


# --- attachment ------------------------------------------------------------------------------


def gid_of(token: str) -> bytes:
    """An entity's gid as rmw_zenoh_cpp derives it: XXH3-128 of its graph token, low 64 bits
    then high 64 bits, each little endian (so ``ros2 topic info -v`` and message infos agree)."""
    try:
        import xxhash
    except ImportError:
        raise KinesphereError("unavailable", EXTRA_HINT) from None
    return int(xxhash.xxh3_128_intdigest(token.encode())).to_bytes(GID_SIZE, "little")


@dataclass(frozen=True)
class Attachment:
    """What every rmw_zenoh sample carries beside its payload.

    rmw_zenoh_cpp (``attachment_helpers.cpp``) writes it with zenoh-cpp's serializer: an
    ``int64_t``, an ``int64_t`` and a ``std::array<uint8_t, 16>``, which zenoh-cpp writes as a
    sequence (its length, LEB128, then the elements). Its reader checks that length and throws
    on any other, so the length byte is not optional.
    """

    sequence_number: int
    source_timestamp_ns: int
    gid: bytes

    def encode(self) -> bytes:
        """The 33 bytes (packed directly: 20x quicker than ``z_serialize``, and the test suite
        checks the two agree)."""
        if len(self.gid) != GID_SIZE:
            raise KinesphereError("malformed", f"gid must be {GID_SIZE} bytes")
        return (_I64_PAIR.pack(self.sequence_number, self.source_timestamp_ns) + GID_LENGTH
                + self.gid)

    @classmethod
    def decode(cls, data: ZBytes | bytes | None) -> Attachment:
        """Read an attachment as rmw_zenoh does; a missing one, or one of another size or gid
        length (a peer older than Jazzy 0.2.4 writes another layout), is ``malformed``."""
        if data is None:
            raise KinesphereError("malformed", "sample without the rmw_zenoh attachment")
        raw = data.to_bytes() if isinstance(data, ZBytes) else bytes(data)
        if len(raw) != ATTACHMENT_SIZE or raw[16:17] != GID_LENGTH:
            got = f"{len(raw)} bytes" + (f", gid length {raw[16]}" if len(raw) > 16 else "")
            raise KinesphereError(
                "malformed", f"rmw_zenoh attachment has {got}, not {ATTACHMENT_SIZE} bytes with "
                f"gid length {GID_SIZE} (a peer older than rmw_zenoh 0.2.4?)"
            )
        seq, ts = _I64_PAIR.unpack_from(raw)
        return cls(seq, ts, raw[17:])


_I64_PAIR: Final = struct.Struct("<qq")
