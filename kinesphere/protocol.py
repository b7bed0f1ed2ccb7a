"""Every message that crosses Zenoh: msgspec Structs, MessagePack maps keyed by field name.

The single source of truth for the wire (``docs/protocol.md`` explains it to peers written
without kinesphere). Unknown fields are ignored so newer peers may add fields; a change that
breaks older peers bumps ``PROTOCOL_VERSION``. Top-level messages carry ``v`` and a ``type``
tag, so :func:`decode_any` can read anything on ``kinesphere/**``. Decoding raises only
KinesphereError: ``incompatible_version`` or ``malformed`` naming the bad field. Checks that
have their own code (size out of range, unknown names) are left to the receiver.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Any, Final, SupportsBytes, TypeVar, get_args

import msgspec

from kinesphere.errors import ERROR_CODES, KinesphereError
from kinesphere.sizes import parse_size

PROTOCOL_VERSION: Final = 1
COMPOUND: Final = "compound"
"""limb, origin and direction of a :class:`Pose` that joins several parts."""
NO_ID: Final = -1
"""``Pose.k_id`` when no single VSAM row applies (compound poses)."""

# Bounds on everything that comes off the wire: a peer cannot make a receiver hold or loop over
# more than these (docs/protocol.md, "Bounds").
MAX_NAME: Final = 64
"""Characters in any name: platform, limb, origin, direction, robot id, group, sender, session."""
MAX_PARTS: Final = 16
"""Spatial commands in one Command or CompoundRequest."""
MAX_JOINTS: Final = 256
"""Entries in a joint map (``Pose.joints``, ``RecordRequest.joints``)."""
MAX_TTL_MS: Final = 60_000
"""Largest command watchdog; a robot never moves on one message for longer than a minute."""
MAX_HEADING: Final = 1000.0
"""Largest ``Command.heading`` magnitude in radians (any yaw, wound many times)."""
MAX_DIRECTIONS: Final = 27
"""Laban's 26 pulls and place-middle."""
MAX_SIZES: Final = 64
"""Stored sizes of one direction in a catalogue's ``tips``."""
MAX_INT: Final = 2**63 - 1
"""Every integer on the wire fits SQLite's and C's int64."""
MAX_PAYLOAD: Final = 64 * 1024
"""Bytes in one message; a larger payload is ``malformed`` before anything decodes it."""
MAX_LARGE_PAYLOAD: Final = 1024 * 1024
"""Bytes in a :class:`Catalogue`, and characters of a body's eURDF text (tens of KiB)."""
MAX_MESHES: Final = 256
"""Mesh files one :class:`BodyModel` carries."""
MAX_MESH_BYTES: Final = 4 * 1024 * 1024
"""Bytes of one mesh file in a :class:`BodyModel`."""
MAX_BODY_PAYLOAD: Final = 16 * 1024 * 1024
"""Bytes in a :class:`BodyModel`: its text and the mesh files it carries."""

Vec3 = Annotated[list[float], msgspec.Meta(min_length=3, max_length=3)]
Fraction = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
Degrees = Annotated[float, msgspec.Meta(ge=0.0, le=180.0)]
SignedFraction = Annotated[float, msgspec.Meta(ge=-1.0, le=1.0)]
NonNegInt = Annotated[int, msgspec.Meta(ge=0, le=MAX_INT)]
Int = Annotated[int, msgspec.Meta(ge=-MAX_INT, le=MAX_INT)]
Name = Annotated[str, msgspec.Meta(max_length=MAX_NAME)]
ANONYMOUS: Final = "anonymous"
"""Who a command without ``sender`` is, in ``RobotState.estop_by`` and ``lease_holder``."""
OVERFLOW: Final = "*overflow*"
"""Who holds the e-stop latch of every sender past those a robot names (``estop_by``,
``FleetEstop.sender``): no release clears it, only restarting the robot's agent. Never a
sender's name behind access control (``*`` is not in a key)."""
MAX_TEXT: Final = 1024
"""Longest free text (``detail``) in characters; producers cut theirs to it."""
Text = Annotated[str, msgspec.Meta(max_length=MAX_TEXT)]
JointMap = Annotated[dict[Name, float], msgspec.Meta(max_length=MAX_JOINTS)]
Names = Annotated[list[Name], msgspec.Meta(max_length=MAX_JOINTS)]
Floats = Annotated[list[float], msgspec.Meta(max_length=MAX_JOINTS)]


class Status(StrEnum):
    """Values of ``RobotState.status``; a plain ``str`` on the wire so new ones stay readable."""

    IDLE = "idle"
    MOVING = "moving"
    HOLDING = "holding"
    STOPPED = "stopped"
    ESTOP = "estop"
    CLAMPED = "clamped"
    DATABANK_UNREACHABLE = "databank_unreachable"
    ERROR = "error"


STATUSES: Final = frozenset(Status)


class AckStage(StrEnum):
    """``Ack.stage``: what became of one command at one robot (docs/protocol.md, "Acks").

    A moving command goes ``accepted`` -> ``moving`` -> one of ``reached``, ``clamped``,
    ``blocked`` (or ``superseded`` by a newer command, ``holding`` on deadman/TTL). Commands
    that move nothing are answered once: ``estopped``, ``released``, ``stopped``, ``holding``,
    ``leased`` (a lease-only command). ``rejected`` carries an error ``code``.
    """

    ACCEPTED = "accepted"
    MOVING = "moving"
    REACHED = "reached"
    CLAMPED = "clamped"
    BLOCKED = "blocked"
    SUPERSEDED = "superseded"
    HOLDING = "holding"
    STOPPED = "stopped"
    ESTOPPED = "estopped"
    RELEASED = "released"
    LEASED = "leased"
    REJECTED = "rejected"


class LeaseAction(StrEnum):
    """``Command.lease``: how a command treats the robot's control lease.

    ``""`` (none): a motion command from the holder keeps the lease alive; from anyone when the
    lease is free it acquires it; from anyone else it is refused with ``lease_held``.
    ``acquire`` asks for the lease without moving; ``take`` takes it over from another holder
    (logged, and the previous holder is told); ``release`` gives it back. E-stop ignores leases.
    """

    NONE = ""
    ACQUIRE = "acquire"
    TAKE = "take"
    RELEASE = "release"


# Parts nested inside messages: no version, no tag.
class SpatialCommand(msgspec.Struct, forbid_unknown_fields=False):
    """One ``(l, o, d, s)`` user parameter: move ``limb`` from ``origin`` towards ``direction``.

    ``size`` is a float (1 near, 2 mid, 3 far; fractions interpolate, above the largest stored
    size translates the base). The ECL checks names and size, so decoding accepts any value.
    """

    limb: Name
    origin: Name
    direction: Name
    size: float
    exact: bool = False
    """Only this direction: no substitution by the nearest one the limb has."""


class Substitution(msgspec.Struct, forbid_unknown_fields=False):
    """A part served with another direction than the one asked for (the nearest honest one).

    ``angle`` is the angle in degrees between the requested and the served direction vectors.
    """

    limb: Name
    origin: Name
    requested: Name
    served: Name
    angle: float


class BodyWord(msgspec.Struct, forbid_unknown_fields=False):
    """A word of the body vocabulary (``right_arm``, ``right_elbow``, ``left_leg``) as one
    body answers it (:mod:`kinesphere.vocabulary`).

    ``label`` is the eURDF label that answers (``limb_11``, ``distal_12``, ``c_1``), ``""``
    when the body has no such part; ``end`` a joint location where the part ends when it is
    a cut limb (the upper arm: ``limb_11`` up to ``distal_12``); ``note`` says why, for
    people (``the only arm``, ``no left leg``), ``""`` when the word is the body's own name.
    """

    word: Name
    label: Name
    end: Name = ""
    note: Text = ""


Words = Annotated[list[BodyWord], msgspec.Meta(max_length=2 * MAX_PARTS)]
"""The words of one command answered through the vocabulary (a limb and an origin per part)."""
MAX_VOCABULARY: Final = 64
"""Words in a catalogue's vocabulary (kinesphere's has 36)."""


class BodyJoint(msgspec.Struct, forbid_unknown_fields=False):
    """An actuated joint: limits in rad (m if prismatic), velocity limit in rad/s (m/s)."""

    name: str
    lower: float
    upper: float
    velocity: float


class LimbEntry(msgspec.Struct, forbid_unknown_fields=False):
    """A ``(limb, origin)`` pair of the VSAM with the directions and sizes that have poses.

    ``tips``: where each stored direction's poses point, one ``[x, y, z]`` (tip - origin, body
    frame, metres) per stored size, so a client substitutes by the databank's own rule
    (:mod:`kinesphere.substitution`); empty from older databanks.
    """

    limb: str
    origin: str
    directions: list[str]
    sizes: list[Int]
    tips: Annotated[dict[Name, Annotated[list[Vec3], msgspec.Meta(max_length=MAX_SIZES)]],
                    msgspec.Meta(max_length=MAX_DIRECTIONS)] = {}


class Drive(msgspec.Struct, forbid_unknown_fields=False):
    """Base motion, in one of two forms.

    Version 1: along a middle horizontal ``direction`` at ``speed`` x the base's maximum.
    Continuous: ``forward`` and ``left`` (body-frame velocity) and ``yaw`` (turn rate,
    positive = counter-clockwise, to the left), each a fraction -1..1 of the platform's limits;
    used when any of them is non-zero. ``diff``/``skid`` bases follow forward and yaw only.
    Senders fill both forms (the horizontal nearest their heading) so version-1 robots still
    drive.
    """

    direction: Name = ""
    speed: Fraction = 0.0
    forward: SignedFraction = 0.0
    left: SignedFraction = 0.0
    yaw: SignedFraction = 0.0

    @property
    def is_continuous(self) -> bool:
        return bool(self.forward or self.left or self.yaw)


class Message(msgspec.Struct, kw_only=True, tag_field="type", forbid_unknown_fields=False):
    """Base of every top-level message: ``v`` first, a missing ``v`` reads as the current one."""

    v: int = PROTOCOL_VERSION


class Pose(Message, tag="pose", kw_only=True):
    """Answer to a pose (or compound, or record) query: the joint targets for a command.

    ``joints`` holds only the joints the pose moves (rad or m). ``translation`` is the base
    displacement in metres, body frame ``[x, y, z]``, past the largest stored size (or for core
    queries); None when the base stays. ``k_id`` is the ``vsam`` row and ``p_id`` the stored
    pose's size index (the paper's p-id, 1 = near), None when computed (interpolated, beyond,
    compound). A compound pose has limb, origin and direction ``"compound"``, ``k_id``
    :data:`NO_ID` and its inputs in ``parts``.
    """

    platform: Name
    limb: Name
    origin: Name
    direction: Name
    size: float
    joints: JointMap
    translation: Vec3 | None = None
    k_id: Int
    p_id: Int | None = None
    parts: Annotated[list[SpatialCommand], msgspec.Meta(max_length=MAX_PARTS)] = []
    substitutions: list[Substitution] = []
    """Parts served with the nearest direction the limb has; ``direction`` is the served one."""
    words: Words = []
    """Body-vocabulary words of the request this body answered with another name (a one-armed
    robot's ``right_arm``, any ``upper_arm``), and how."""
    measured_angle: Degrees | None = None
    """Degrees between the requested direction and where the served pose points (the tip's
    bearing from the origin, measured by forward kinematics when the databank was built,
    blended between stored sizes; a compound's worst part, a nested answer's worst segment as
    the solver measured it); None when not measured (neutral and core poses, recorded poses,
    databanks built before it was)."""

    @property
    def is_compound(self) -> bool:
        return self.limb == COMPOUND


class Catalogue(Message, tag="catalogue", kw_only=True):
    """What a platform's ECL can answer, so clients offer only valid commands.

    ``core`` names the core body parts (``c_1``...), ``limbs`` the VSAM ``(limb, origin)`` pairs,
    ``joints`` the actuated joints in eURDF order. ``translation_step`` is metres per size unit
    beyond the largest size, ``directions_for_core`` the directions the base can translate in,
    ``sizes`` every stored size, ``aliases`` maps aliases (``right_arm``) to label names, and
    ``version`` identifies the ECL contents (changes when poses are recorded). ``max_size`` is
    the largest size the ECL answers (``size_out_of_range`` past it; None from older
    databanks), ``base_kind`` the base (``fixed``, ``omni``, ``diff``, ``skid``,
    ``legged``; "" if unknown), ``vocabulary`` how the body answers the words of the body
    vocabulary.
    """

    platform: str
    core: list[str]
    limbs: list[LimbEntry]
    joints: list[BodyJoint]
    translation_step: float | None = None
    can_translate: bool = False
    directions_for_core: list[str] = []
    sizes: list[Int]
    aliases: dict[str, str] = {}
    version: str
    max_size: float | None = None
    base_kind: str = ""
    vocabulary: Annotated[list[BodyWord], msgspec.Meta(max_length=MAX_VOCABULARY)] = []
    """Every word of the body vocabulary as this body answers it (empty from older
    databanks)."""

    def __post_init__(self) -> None:
        if self.can_translate and not (self.translation_step and self.translation_step > 0):
            raise ValueError("can_translate needs a translation_step > 0")


class Command(Message, tag="command", kw_only=True):
    r"""Operator input for one robot (or a group, or all, via their keys).

    ``seq`` grows per ``(sender, session)``; ``session`` is a fresh id per client process, so a
    restarted client starts a new order. ``sent_ns`` is the sender's ``time.time_ns()``.
    ``deadman`` false means the operator let go: the robot holds. The robot holds when no newer
    command arrives within ``ttl_ms`` of receiving this one, and drops a command whose
    ``ttl_ms`` ran out before it could act on it. ``estop`` latches an emergency stop (from
    anyone, lease or not); ``stop`` halts motion in a controlled way. Only a command with
    ``release`` clears a latched e-stop (and moves nothing): a client that keeps streaming
    ordinary commands can never release an e-stop it did not mean to. ``lease`` is a
    :class:`LeaseAction`. Every robot that receives a command answers with :class:`Ack`\ s.
    """

    seq: NonNegInt
    sent_ns: NonNegInt
    parts: Annotated[list[SpatialCommand], msgspec.Meta(max_length=MAX_PARTS)] = []
    drive: Drive | None = None
    deadman: bool
    ttl_ms: Annotated[int, msgspec.Meta(ge=0, le=MAX_TTL_MS)]
    estop: bool = False
    stop: bool = False
    release: bool = False
    sender: Name = ""
    session: Name = ""
    lease: LeaseAction = LeaseAction.NONE
    clock: Name = ""
    """Names the clock ``sent_ns`` is read from (the sender's host, until it reboots): a
    robot learns each clock's offset from its first command and times every later one by it,
    whichever session it belongs to."""
    arrive_ms: Annotated[int, msgspec.Meta(ge=0, le=MAX_TTL_MS)] = 0
    """When the parts' pose is to be reached: ``arrive_ms`` after ``sent_ns`` (a score's
    keyframe time). The robot plans its trajectory to arrive then, or as soon after as its
    limits allow, and says how late in its acks (``Ack.late_ms``); copies of a streamed
    command count down to the same moment, and the same pose due more than 50 ms later is
    the next motion (the one before acks how late it was). 0: as fast as the limits allow."""
    heading: Annotated[float, msgspec.Meta(ge=-MAX_HEADING, le=MAX_HEADING)] | None = None
    """Turn a mobile base to this yaw (rad, the odometry frame of ``RobotState.base_pose``),
    arriving with the parts; a fixed base refuses it (``cannot_translate``). None: keep it."""


class RobotState(Message, tag="robot_state", kw_only=True):
    """What a robot publishes at >= 50 Hz.

    ``q`` (rad or m) follows ``joint_names``; ``qd`` (rad/s or m/s) does too, or is empty when
    unknown. ``base_pose`` is ``[x m, y m, yaw rad]`` in the odometry frame. ``stamp_ns`` is the
    robot's ``time.time_ns()``; ``last_command_seq`` is -1 before the first command.
    ``clamped`` names joints held at a limit; ``detail`` explains the status to people.
    ``groups`` are the groups the robot obeys, ``lease_holder`` the sender holding its control
    lease ("" when free), ``estop_by`` who latched its e-stop, ``substitutions`` the parts of
    the current target served with another direction, ``dropped`` how many commands it dropped
    as stale or expired since it started.
    """

    robot_id: Name
    platform: Name
    seq: Int
    stamp_ns: Int
    joint_names: Names
    q: Floats
    qd: Floats
    base_pose: Vec3
    status: Name
    last_command_seq: Int
    detail: Text = ""
    clamped: Names = []
    groups: Annotated[list[Name], msgspec.Meta(max_length=MAX_PARTS)] = []
    lease_holder: Name = ""
    estop_by: Name = ""
    substitutions: Annotated[list[Substitution], msgspec.Meta(max_length=MAX_PARTS)] = []
    dropped: NonNegInt = 0

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        if len(self.q) != n:
            raise ValueError(f"q has {len(self.q)} values for {n} joint_names")
        if self.qd and len(self.qd) != n:
            raise ValueError(f"qd has {len(self.qd)} values for {n} joint_names")


class Error(Message, tag="error", kw_only=True):
    """A failed query, sent with ``query.reply_err``; ``code`` is one of ``ERROR_CODES``."""

    code: str
    message: str

    @classmethod
    def from_exception(cls, exc: KinesphereError) -> Error:
        return cls(code=exc.code, message=exc.message)

    def to_exception(self) -> KinesphereError:
        """The error to raise locally; a code this version does not know becomes ``internal``."""
        if self.code in ERROR_CODES:
            return KinesphereError(self.code, self.message)
        return KinesphereError("internal", f"{self.code}: {self.message}")


class RecordRequest(Message, tag="record_request", kw_only=True):
    """A super-user write: store ``joints`` as the pose for ``(limb, origin, direction, size)``."""

    limb: Name
    origin: Name
    direction: Name
    size: Int  # the ECL checks it is a VSAM size
    joints: JointMap


class CompoundRequest(Message, tag="compound_request", kw_only=True):
    """Join the poses of several parts; a joint set by two parts is a ``conflict`` unless
    ``last_wins``, when the later part wins."""

    parts: Annotated[list[SpatialCommand], msgspec.Meta(max_length=MAX_PARTS)]
    last_wins: bool = False


class Ack(Message, tag="ack", kw_only=True):
    """A robot's answer to one command, put on ``{p}/robot/{id}/ack``.

    ``(sender, session, seq)`` name the command; ``stage`` is an :class:`AckStage`; ``code``
    an error code when ``rejected`` (``lease_held``, ``estopped``, ``stale``, ``expired``,
    ``direction_unavailable``...). ``lease_holder`` is who holds the robot's lease now;
    ``substitutions``, ``words`` and ``measured_angle`` what the command meant on this body.
    """

    robot_id: Name
    sender: Name
    session: Name = ""
    seq: Int
    stage: AckStage
    code: str = ""
    detail: Text = ""
    stamp_ns: Int
    substitutions: Annotated[list[Substitution], msgspec.Meta(max_length=MAX_PARTS)] = []
    lease_holder: Name = ""
    words: Words = []
    """Body-vocabulary words of the command this robot answered with another name, and how."""
    late_ms: NonNegInt = 0
    """For a command with ``arrive_ms``: how much later than asked the robot reaches its
    target, in the sender's milliseconds; planned in ``moving``, as it happened in the final
    stage (``superseded`` before arriving: when it would have arrived, as last planned)."""
    measured_angle: Degrees | None = None
    """Degrees between what was asked and where the pose the robot follows points, as its
    answer (:attr:`Pose.measured_angle`) measured it; the worst part's for several parts; None
    when not measured."""


class BodyModel(Message, tag="body_model", kw_only=True):
    """A platform's body, enough for a client to draw it without local platform files.

    ``eurdf`` is the eURDF text; ``neutral`` the Place-Middle pose; ``base_kind`` as in
    :class:`Catalogue`; ``version`` a hash of the text. ``meshes`` carries the mesh files the
    text names (``<mesh filename>`` as written there -> the file's bytes; a brought robot's
    ``meshes/*.stl``), so a reader never opens a file of its own machine for them.
    """

    platform: Name
    eurdf: Annotated[str, msgspec.Meta(max_length=MAX_LARGE_PAYLOAD)]
    base_kind: Name
    neutral: JointMap
    version: Name
    meshes: Annotated[
        dict[Annotated[str, msgspec.Meta(max_length=256)],
             Annotated[bytes, msgspec.Meta(max_length=MAX_MESH_BYTES)]],
        msgspec.Meta(max_length=MAX_MESHES),
    ] = {}


class FleetEstop(msgspec.Struct, forbid_unknown_fields=False):
    """One sender's latest e-stop for every robot (put on ``{p}/robot/*/command``), or its
    release of them all: ``engaged`` while in force. ``sent_ns`` is the sender's own clock,
    which orders one sender's e-stops and releases."""

    sender: Name
    engaged: bool
    sent_ns: Int


MAX_FLEET_ESTOPS: Final = 64
"""Senders one robot remembers fleet e-stops of (in force and released)."""


class FleetEstops(Message, tag="fleet_estops", kw_only=True):
    """The fleet e-stops a robot knows of, answered on ``{p}/estop/{holder}`` so that a robot
    that starts, restarts or reconnects while one is in force comes up latched."""

    holder: Name
    estops: Annotated[list[FleetEstop], msgspec.Meta(max_length=MAX_FLEET_ESTOPS)] = []


class Presence(Message, tag="presence", kw_only=True):
    """Where a robot id runs, answered on ``{p}/robot/{id}/presence``: a second agent with the
    same id refuses to start, naming it."""

    robot_id: Name
    platform: Name
    host: Name
    pid: NonNegInt
    started_ns: Int
    zid: Name


AnyMessage = (
    Pose | Catalogue | Command | RobotState | Error | RecordRequest | CompoundRequest | Ack
    | BodyModel | FleetEstops | Presence
)
MESSAGE_TYPES: Final[tuple[type[Message], ...]] = get_args(AnyMessage)

T = TypeVar("T")
Payload = bytes | bytearray | memoryview | SupportsBytes
"""Anything :func:`decode` reads: bytes, or an object with ``__bytes__`` such as ``ZBytes``."""

ENCODER: Final = msgspec.msgpack.Encoder()
_DECODERS: dict[Any, msgspec.msgpack.Decoder[Any]] = {
    t: msgspec.msgpack.Decoder(t)
    for t in (*MESSAGE_TYPES, AnyMessage, SpatialCommand, BodyJoint, LimbEntry, Drive,
              Substitution, BodyWord, FleetEstop)
}


class _Envelope(msgspec.Struct):
    """The fields every message shares, read leniently to explain a failed decode."""

    v: Any = PROTOCOL_VERSION
    type: Any = None


_ENVELOPE: Final = msgspec.msgpack.Decoder(_Envelope)
_LARGE: Final = frozenset({Catalogue, AnyMessage})


def encode(msg: msgspec.Struct) -> bytes:
    """MessagePack bytes of a message (a map keyed by field name)."""
    return ENCODER.encode(msg)


def encode_into(msg: msgspec.Struct, buffer: bytearray) -> bytearray:
    """:func:`encode` into ``buffer``, resized to the message: the same bytes without a new
    object per message (a robot's state, dozens a second, put straight from it)."""
    ENCODER.encode_into(msg, buffer)
    return buffer


def decoder(type_: type[T]) -> msgspec.msgpack.Decoder[T]:
    """The cached decoder for ``type_``; building one per call would cost more than decoding."""
    dec = _DECODERS.get(type_)
    if dec is None:
        dec = _DECODERS[type_] = msgspec.msgpack.Decoder(type_)
    return dec


def _buffer(data: Payload) -> bytes | bytearray | memoryview:
    if isinstance(data, (bytes, bytearray, memoryview)):
        return data
    return bytes(data)


def _name(type_: Any) -> str:
    return getattr(type_, "__name__", None) or "message"


def _version_error(type_: Any, v: object) -> KinesphereError:
    if type(v) is not int:  # "1" or 1.0 is a mistyped field, not another protocol version
        return KinesphereError(
            "malformed",
            f"{_name(type_)} has v = {v!r} ({type(v).__name__}); v must be the integer "
            f"{PROTOCOL_VERSION}",
        )
    return KinesphereError(
        "incompatible_version",
        f"{_name(type_)} has protocol version {v}, this peer speaks {PROTOCOL_VERSION}",
    )


def _explain(buf: bytes | bytearray | memoryview, type_: Any, exc: Exception) -> KinesphereError:
    """Turn a msgspec failure into the error a peer can act on."""
    try:
        env = _ENVELOPE.decode(buf)
    except (msgspec.ValidationError, msgspec.DecodeError, RecursionError):
        env = None
    if env is not None and env.v != PROTOCOL_VERSION:
        return _version_error(type_, env.v)
    tag = getattr(getattr(type_, "__struct_config__", None), "tag", None)
    if env is not None and tag is not None and env.type is not None and env.type != tag:
        return KinesphereError("malformed", f"expected a {tag!r} message, got {env.type!r:.80}")
    if isinstance(exc, msgspec.ValidationError):  # a subclass of DecodeError: test it first
        return KinesphereError("malformed", f"bad {_name(type_)}: {exc}")
    return KinesphereError("malformed", f"bad {_name(type_)}, not MessagePack: {exc}")


def max_payload(type_: Any) -> int:
    """Largest payload :func:`decode` reads as ``type_`` (:data:`MAX_PAYLOAD`,
    :data:`MAX_LARGE_PAYLOAD` for catalogues and any-message taps, :data:`MAX_BODY_PAYLOAD`
    for body models and their meshes)."""
    if type_ is BodyModel:
        return MAX_BODY_PAYLOAD
    return MAX_LARGE_PAYLOAD if type_ in _LARGE else MAX_PAYLOAD


def decode(data: Payload, type_: type[T]) -> T:
    """Decode ``data`` as ``type_``; raises only KinesphereError (malformed, incompatible_version).

    Bounded: a payload over :func:`max_payload` bytes is refused unread, and nesting deeper
    than the decoder's recursion limit (msgspec stops at Python's, about a thousand levels;
    kinesphere messages nest four) is ``malformed`` instead of a RecursionError.
    """
    buf = _buffer(data)
    n, limit = len(buf), max_payload(type_)
    if n == 0:
        raise KinesphereError("malformed", f"{_name(type_)} expected, got an empty payload")
    if n > limit:
        raise KinesphereError(
            "malformed", f"{_name(type_)} payload of {n} bytes exceeds {limit} bytes"
        )
    try:
        msg = decoder(type_).decode(buf)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise _explain(buf, type_, exc) from None
    except RecursionError:
        raise KinesphereError(
            "malformed", f"bad {_name(type_)}: MessagePack nested too deeply"
        ) from None
    v = getattr(msg, "v", PROTOCOL_VERSION)
    if v != PROTOCOL_VERSION:
        raise _version_error(type_, v)
    return msg


def decode_any(data: Payload) -> AnyMessage:
    """Decode any top-level message by its ``type`` tag (for taps, logs and tools)."""
    return decode(data, AnyMessage)  # type: ignore[arg-type]


def error_from_reply(data: Payload) -> KinesphereError:
    """The error carried by a ``reply.err`` payload.

    Kinesphere queryables send an :class:`Error`; Zenoh itself sends plain text (``Timeout``),
    which becomes ``unavailable``.
    """
    buf = _buffer(data)
    try:
        return decode(buf, Error).to_exception()
    except KinesphereError as exc:
        if exc.code == "incompatible_version":
            return exc
        text = bytes(buf).decode("utf-8", "replace") or "empty error reply"
        return KinesphereError("unavailable", text)


def check_size(size: float) -> float:
    """``size`` if finite and >= 0, else KinesphereError("size_out_of_range")."""
    return parse_size(size)


def check_spatial(cmd: SpatialCommand) -> SpatialCommand:
    """Reject empty names (``malformed``) and bad sizes (``size_out_of_range``)."""
    for field in ("limb", "origin", "direction"):
        if not getattr(cmd, field).strip():
            raise KinesphereError("malformed", f"spatial command has an empty {field}")
    check_size(cmd.size)
    return cmd
