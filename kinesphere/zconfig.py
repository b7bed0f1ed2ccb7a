"""Zenoh session configuration shared by every kinesphere process and test.

Multicast scouting is off unless asked for: with it on, a session joins whatever other Zenoh
process runs on the machine or LAN (another test run, another team's robot). Processes find
each other through explicit ``connect`` endpoints instead. Gossip scouting stays on: it travels
only over links a session already has, so it cannot reach strangers, and without it two peers
connected to the same hub peer never see each other's data (peers do not route for peers).

Sessions hold threads and sockets: close them (use :func:`session`) before the interpreter
exits. A peer that vanishes is noticed after the link lease (10 s by default, ``lease_ms``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import socket
import threading
import time
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any, ParamSpec, Protocol

import zenoh

from kinesphere.cliargs import OPERATOR, ZenohDefaults
from kinesphere.endpoints import DEFAULT_ENDPOINT as DEFAULT_ENDPOINT
from kinesphere.endpoints import LOOPBACK_ANY_PORT as LOOPBACK_ANY_PORT
from kinesphere.endpoints import LOOPBACK_HOST as LOOPBACK_HOST
from kinesphere.errors import KinesphereError

MODES = ("peer", "client", "router")
_ZENOH_LISTEN = json.loads(zenoh.Config().get_json("listen/endpoints"))
"""Zenoh's own listen endpoints per mode (every interface): what nobody chose."""


class Undeclarable(Protocol):
    """Anything Zenoh lets you undeclare: subscribers, queryables, publishers, tokens..."""

    def undeclare(self) -> object: ...


class Closable(Protocol):
    def close(self) -> object: ...


def undeclare(*entities: Undeclarable | None) -> None:
    """Undeclare each entity (None is skipped); typed, unlike Zenoh's stubs."""
    for entity in entities:
        if entity is not None:
            entity.undeclare()


def close_session(s: Closable | None) -> None:
    """Close a session (None is skipped); closing undeclares everything it declared."""
    if s is not None:
        s.close()


def _zmsg(exc: Exception) -> str:
    """Zenoh's message without the Rust source location it appends."""
    return str(exc).split(" at /", 1)[0]


def _set(config: zenoh.Config, key: str, value: Any) -> None:
    try:
        config.insert_json5(key, json.dumps(value))
    except zenoh.ZError as exc:
        msg = f"zenoh config {key} = {value!r}: {_zmsg(exc)}"
        raise KinesphereError("malformed", msg) from None


def session_config(
    mode: str | None = None,
    listen: Sequence[str] | None = None,
    connect: Sequence[str] | None = None,
    config_file: str | Path | None = None,
    scouting: bool | None = None,
    *,
    gossip: bool | None = None,
    lease_ms: int | None = None,
) -> zenoh.Config:
    """A Zenoh config: ``config_file`` (JSON5) if given, then every argument that is not None.

    Defaults without a file: mode ``peer``, Zenoh's own listen endpoints (all interfaces,
    random port), no connect endpoints, multicast scouting off, gossip on, 10 s lease.
    ``scouting=None`` keeps a file's explicit multicast setting and turns it off otherwise.
    Endpoints look like ``tcp/127.0.0.1:7447``. Bad values raise KinesphereError("malformed").
    """
    if config_file is not None:
        try:
            config = zenoh.Config.from_file(str(config_file))
        except zenoh.ZError as exc:
            raise KinesphereError(
                "malformed", f"zenoh config file {config_file}: {_zmsg(exc)}"
            ) from None
    else:
        config = zenoh.Config()
    if mode is not None:
        if mode not in MODES:
            raise KinesphereError("malformed", f"zenoh mode {mode!r}; valid: {', '.join(MODES)}")
        _set(config, "mode", mode)
    elif config.get_json("mode") in (None, "null"):
        _set(config, "mode", "peer")
    if listen is not None:
        _set(config, "listen/endpoints", list(listen))
    if connect is not None:
        _set(config, "connect/endpoints", list(connect))
    if scouting is None:
        scouting = json.loads(config.get_json("scouting/multicast/enabled")) is True
    _set(config, "scouting/multicast/enabled", scouting)
    if gossip is not None:
        _set(config, "scouting/gossip/enabled", gossip)
    if lease_ms is not None:
        if lease_ms <= 0:
            raise KinesphereError("malformed", f"lease_ms must be > 0, got {lease_ms}")
        _set(config, "transport/link/tx/lease", lease_ms)
    return config


def open_session(config: zenoh.Config | None = None) -> zenoh.Session:
    """Open a session from ``config`` (made by :func:`session_config`; without one, its
    defaults); the caller closes it.

    A session that cannot open (port taken, client without a router) raises
    KinesphereError("unavailable").
    """
    if config is None:
        config = session_config()
    mode = json.loads(config.get_json("mode"))
    connect = json.loads(config.get_json("connect/endpoints"))
    connect = connect.get(mode, []) if isinstance(connect, dict) else connect
    try:
        s = zenoh.open(config)
    except zenoh.ZError as exc:
        why = nobody_at(connect) if "nable to connect" in str(exc) else _zmsg(exc)
        raise KinesphereError("unavailable", f"cannot open zenoh session: {why}") from None
    with _OPENED_LOCK:
        _OPENED[str(s.zid())] = (str(mode), tuple(str(e) for e in connect))
        while len(_OPENED) > MAX_SESSIONS:
            del _OPENED[next(iter(_OPENED))]
    return s


MAX_SESSIONS = 256
"""Sessions whose mode and connect endpoints are remembered (a process opens a few)."""
_OPENED: dict[str, tuple[str, tuple[str, ...]]] = {}
_OPENED_LOCK = threading.Lock()
QUIET_S = 0.3
"""Discovery has settled when nobody new turned up for this long."""
PEER_DISCOVERY_S = 1.0
"""A peer session knows the others no sooner: its links to them form through gossip."""


def _opened(s: zenoh.Session) -> tuple[str, tuple[str, ...]]:
    with _OPENED_LOCK:
        return _OPENED.get(str(s.zid()), ("peer", ()))


def discovery_time(s: zenoh.Session) -> float:
    """How long a session must listen before it may say who exists: :data:`PEER_DISCOVERY_S`
    for a peer (its gossip links take a moment, about half a second on loopback), nothing for
    a client, which hears everyone through its router at once."""
    return 0.0 if _opened(s)[0] == "client" else PEER_DISCOVERY_S


def nobody_at(endpoints: Sequence[str]) -> str:
    """What to say when nothing answers at ``endpoints`` (a session's connect endpoints): that
    nobody listens there, and, for an endpoint a plain router can serve, the command that
    starts one (:func:`kinesphere.hints.router`)."""
    from kinesphere import hints

    if not endpoints:
        return ("this session connects nowhere (no --connect endpoint) and no peer found it: "
                "give --connect with the router's endpoint")
    where = ", ".join(endpoints)
    startable = [e for e in endpoints if hints.can_start_router(e)]
    how = (f": start one with '{hints.router(startable[0])}'" if startable
           else ": is the router running there, and reachable?")
    return f"no Zenoh router answers at {where}{how} (or --connect to where it runs)"


def alone(s: zenoh.Session) -> str:
    """"" while ``s`` has a link to a router or a peer; else why nobody can hear it
    (:func:`nobody_at` its connect endpoints). A peer session opens even when nothing answers
    at its endpoints (it keeps retrying), so a command that heard nobody asks this before
    blaming the robots."""
    info = s.info
    if info.routers_zid() or info.peers_zid():
        return ""
    return nobody_at(_opened(s)[1])


P = ParamSpec("P")


def _closing(
    open_: Callable[P, zenoh.Session],
) -> Callable[P, AbstractContextManager[zenoh.Session]]:
    @contextmanager
    def scoped(*args: P.args, **kwargs: P.kwargs) -> Iterator[zenoh.Session]:
        s = open_(*args, **kwargs)
        try:
            yield s
        finally:
            close_session(s)

    return scoped


session = _closing(open_session)
""":func:`open_session` (same arguments) that closes the session, and all it declared, on exit."""


def _apply_cfg(config: zenoh.Config, pairs: Sequence[str]) -> None:
    """``--cfg KEY:VALUE`` pairs: VALUE is JSON5 text (the first ``:`` splits)."""
    for pair in pairs:
        key, sep, value = pair.partition(":")
        if not sep or not key.strip() or not value.strip():
            raise KinesphereError("malformed", f"--cfg {pair!r}: expected KEY:VALUE")
        try:
            config.insert_json5(key.strip(), value)
        except zenoh.ZError as exc:
            raise KinesphereError("malformed", f"--cfg {pair!r}: {_zmsg(exc)}") from None


def configs_from_args(args: argparse.Namespace) -> list[zenoh.Config]:
    """The configs a command tries in turn, from its ``zenoh`` options (see
    :mod:`kinesphere.cliargs` for the rule); more than one only when its defaults apply and
    have a fallback."""
    d: ZenohDefaults = getattr(args, "zenoh_defaults", OPERATOR)
    file = args.zenoh_config
    listen: list[str] | None = getattr(args, "listen", None)
    mode = args.mode if args.mode is not None or file is not None else d.mode
    plans: list[tuple[Sequence[str] | None, Sequence[str] | None]]
    from_defaults = file is None and args.connect is None and listen is None
    if from_defaults:
        chain = [d] if d.fallback is None else [d, d.fallback]
        plans = [(x.connect, x.listen) for x in chain]
    else:
        if file is None and getattr(args, "zenoh_fixed_listen", False):
            listen = None if d.listen is None else list(d.listen)
        plans = [(args.connect, listen)]
    configs = []
    for connect, listen_eps in plans:
        if mode == "client" and from_defaults:
            listen_eps = None  # a client never listens unless told to
        config = session_config(
            mode,
            listen=None if listen_eps is None else list(listen_eps),
            connect=None if connect is None else list(connect),
            config_file=file,
        )
        if listen_eps is None:
            listen_where_told(config)
        _apply_cfg(config, getattr(args, "cfg", None) or ())
        configs.append(config)
    return configs


def listen_where_told(config: zenoh.Config) -> zenoh.Config:
    """Unless ``config`` names its listen endpoints, listen on loopback only: a peer on any
    port, a router on :data:`DEFAULT_ENDPOINT`; a client nowhere. Returns ``config``.

    Zenoh's own default makes a peer listen on every interface in plain TCP: a process told
    only to connect (to a router with TLS and access control, say) would then accept anyone on
    the network, bypassing both. A peer still listens on loopback so that peers of one machine,
    introduced by gossip, can link directly; peers on other machines need ``--listen`` (or,
    better, a router and client mode), and a router serving other machines a listen endpoint.
    """
    mode = json.loads(config.get_json("mode"))
    if json.loads(config.get_json("listen/endpoints")) == _ZENOH_LISTEN:
        where = {"client": [], "peer": [LOOPBACK_ANY_PORT], "router": [DEFAULT_ENDPOINT]}
        _set(config, "listen/endpoints", where.get(mode, []))
    return config


def timestamped(config: zenoh.Config) -> zenoh.Config:
    """``config`` with Zenoh timestamping on, as rmw_zenoh's session config has it
    (``DEFAULT_RMW_ZENOH_SESSION_CONFIG.json5``: every sample a ROS node puts carries its
    session's HLC timestamp); for the sessions that carry a ROS 2 node. Returns ``config``."""
    _set(config, "timestamping/enabled", True)
    return config


def session_from_args(args: argparse.Namespace, *, ros2: bool = False) -> zenoh.Session:
    """Open the session a command's ``zenoh`` options ask for (the caller closes it);
    ``ros2`` when it carries a ROS 2 node (:func:`timestamped`).

    The one place the "no endpoint given" rule lives: every role's commands call this with the
    namespace that :func:`kinesphere.cliargs.add_zenoh_arguments` filled.
    """
    configs = configs_from_args(args)
    if ros2:
        configs = [timestamped(c) for c in configs]
    for config in configs[:-1]:
        try:
            return open_session(config=config)
        except KinesphereError:
            continue  # e.g. the default port is taken: try the fallback
    return open_session(config=configs[-1])


PROBED_PORTS_FROM = 20_000
"""Where :func:`free_port` starts looking: below the kernel's ephemeral range."""
EPHEMERAL_RANGE = Path("/proc/sys/net/ipv4/ip_local_port_range")
_probes = itertools.count()
"""How many ports this process has probed: each probe looks at the next port."""


def _probed_ports() -> range | None:
    """The ports :func:`free_port` tries: those below the ephemeral range (Linux's default
    32768-60999; elsewhere, where that file is missing, the ranges start at 32768 or 49152),
    or above it when it starts too low; None if neither side has 1,024 ports."""
    try:
        low, high = map(int, EPHEMERAL_RANGE.read_text().split())
    except (OSError, ValueError):
        low, high = 32_768, 60_999
    if low - PROBED_PORTS_FROM >= 1024:
        return range(PROBED_PORTS_FROM, low)
    if 65_535 - high >= 1024:
        return range(high + 1, 65_536)
    return None


def free_port(host: str = LOOPBACK_HOST) -> int:
    """A TCP port free right now on ``host``; another process may still take it first.

    Not one the kernel picks (port 0): those come from the ephemeral range, where every
    outgoing connection takes its local port, so one opened between the probe and the
    listener's bind could take it (a full test run saw a router's "Address already in use").
    Outside that range only listeners compete: each process starts at its own place (from
    its pid) and moves one port on per probe, and a port bound now is passed over.
    """
    ports = _probed_ports()
    if ports is None:
        return _kernel_port(host)
    start = os.getpid() * 7919  # a prime: neighbouring pids start far apart
    for _ in range(len(ports)):
        port = ports[(start + next(_probes)) % len(ports)]
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            try:
                sock.bind((host, port))
            except OSError:
                continue
            return port
    return _kernel_port(host)


def _kernel_port(host: str) -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def loopback_endpoint(port: int | None = None) -> str:
    """``tcp/127.0.0.1:<port>``, a free port when none is given."""
    return f"tcp/{LOOPBACK_HOST}:{free_port() if port is None else port}"


def open_hub(mode: str = "peer", attempts: int = 5) -> tuple[zenoh.Session, str]:
    """A session listening on a free loopback port, and the endpoint others connect to.

    Retries with a new port when another process took the probed one meanwhile.
    """
    last: KinesphereError | None = None
    for _ in range(attempts):
        endpoint = loopback_endpoint()
        try:
            config = session_config(mode, listen=[endpoint], connect=[], scouting=False)
            return open_session(config), endpoint
        except KinesphereError as exc:
            last = exc
    assert last is not None
    raise last


def loopback_config(endpoint: str, mode: str = "peer") -> zenoh.Config:
    """Config of a session joining the hub at ``endpoint``, reachable on loopback only."""
    listen = [LOOPBACK_ANY_PORT] if mode == "peer" else []
    return session_config(mode, listen=listen, connect=[endpoint], scouting=False)


@contextmanager
def loopback_hub(mode: str = "peer") -> Iterator[tuple[zenoh.Session, str]]:
    """:func:`open_hub` as a context manager that closes the hub on exit."""
    hub, endpoint = open_hub(mode)
    try:
        yield hub, endpoint
    finally:
        close_session(hub)


@contextmanager
def loopback_pair() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    """Two connected sessions on loopback (a hub and a peer joined to it); both closed on exit."""
    with loopback_hub() as (hub, endpoint), session(config=loopback_config(endpoint)) as peer:
        yield hub, peer


def wait_matching(entity: zenoh.Publisher | zenoh.Querier, timeout: float = 5.0,
                  wake: threading.Event | None = None) -> bool:
    """Wait until a subscriber (publisher) or queryable (querier) matches; False on timeout.

    Declarations travel asynchronously, so a put right after a remote subscribe may be lost;
    tests and start-up code wait here rather than sleeping. ``wake`` is the event the wait
    blocks on (a match sets it): its owner may set it to end the wait early (a component
    closing), and the answer is then whether a match is known.
    """
    matched = threading.Event() if wake is None else wake

    def on_status(status: zenoh.MatchingStatus) -> None:
        if status.matching:
            matched.set()

    def matching() -> bool:
        status: Any = entity.matching_status
        return getattr(status, "matching", status) is True

    listener = entity.declare_matching_listener(on_status)
    try:
        if matching():
            return True
        return matched.wait(timeout) and (wake is None or matching())
    finally:
        undeclare(listener)


def unmatched(entities: Mapping[str, zenoh.Publisher | zenoh.Querier], timeout: float) -> list[str]:
    """The names of ``entities`` still without a match after waiting up to ``timeout`` seconds
    in all (:func:`wait_matching` on each in turn, against one deadline)."""
    deadline = time.monotonic() + timeout
    return [name for name, entity in entities.items()
            if not wait_matching(entity, max(0.0, deadline - time.monotonic()))]


def unseen(session: zenoh.Session, pattern: str, tokens: Collection[str],
           timeout: float) -> list[str]:
    """The liveliness ``tokens`` (keys within ``pattern``) not seen from ``session`` within
    ``timeout`` seconds, sorted.

    A publisher's match says only that *some* subscriber of its key is known here: with a peer
    hub (which routes for nobody) that may be a recorder or a view on the hub while the link to
    the robot is still being opened, so a put goes to them alone. A peer's token reaches this
    session on the same path, after the declarations the peer made before it: seeing it means
    its subscribers are known here too."""
    wanted = set(tokens)
    if not wanted:
        return []
    seen: set[str] = set()
    changed = threading.Condition()

    def on_token(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            with changed:
                seen.add(str(sample.key_expr))
                changed.notify_all()

    sub = session.liveliness().declare_subscriber(pattern, on_token, history=True)
    try:
        with changed:
            changed.wait_for(lambda: wanted <= seen, timeout)
            return sorted(wanted - seen)
    finally:
        undeclare(sub)
