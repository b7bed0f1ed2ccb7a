"""Resolve spatial commands into joint targets by asking the databank over Zenoh.

Why a cache: an operator streams the same command at 30 Hz and phrases repeat, so each
distinct command costs one round trip per databank version, after which it is answered from
memory in the control loop itself (no thread hop, no network). The cache is keyed by the
parts and tagged with the catalogue ``version``; the catalogue is re-read periodically and
whenever a reply fails, and a new version empties the cache. While the databank is
unreachable cached poses keep working (they are the best knowledge there is). The databank
also puts on ``{p}/ecl/{platform}/changed`` after every record, which triggers a re-read.

The cache is bounded in bytes (:data:`CACHE_BYTES`, each answer charged its encoded size and
its key, reckoned once on the worker), least recently used first out: fractional sizes make the
keys unbounded in number.

Why a worker thread: a Zenoh ``get`` blocks and must never run in the control loop or in a
Zenoh callback. Requests are coalesced (only the newest pending one matters: an operator who
moved on does not want the old pose), and the answer is handed back with its ticket so the
loop can drop answers that a newer command has overtaken.

Unreachable means no queryable answered (``get`` ended without replies), Zenoh's timeout, or
an ``unavailable`` error; the worker then probes the catalogue every ``probe_s`` until it
answers again, so recovery needs no restart and no new command.

A request the databank may answer with its nested solver (several parts, or a cut limb such
as ``right_upper_arm`` by the catalogue's vocabulary) waits up to ``solve_timeout_s`` instead:
a first solve on a cold databank compiles the body's model, which takes longer than a lookup.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import zenoh

from kinesphere import zconfig
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.laban import Direction
from kinesphere.lru import Lru
from kinesphere.protocol import (
    Catalogue,
    Pose,
    SpatialCommand,
    check_spatial,
    encode,
)
from kinesphere.query import get_one, pose_query
from kinesphere.zconfig import undeclare, wait_matching

log = logging.getLogger(__name__)
T = TypeVar("T")

PartsKey = tuple[tuple[str, str, str, float, bool], ...]
PoseAnswer = Pose | KinesphereError
Callback = Callable[[int, PoseAnswer], None]
SOLVE_TIMEOUT_S = 5.0
"""How long a request that may need the databank's nested solver waits for its answer."""
CACHE_BYTES = 4 * 1024 * 1024
"""Budget of the pose cache (a pose of a 26-joint NAO is ~1 KB encoded: thousands fit)."""
ENTRY_BYTES = 128
"""Charged per cached pose on top of its encoded size and key (dict slot, objects)."""


PartKey = tuple[str, str, str, float, bool]
CANONICAL_ENTRIES = 4096
"""Spellings of parts remembered with their canonical key (names are at most 64 characters:
about 1 MB at most), the first remembered forgotten first."""
_CANONICAL: Lru[tuple[str, str, str, float, bool], PartKey] = Lru(CANONICAL_ENTRIES)
"""Written by control loops only; agents' loops in threads of one process may race on it,
which can only forget a spelling early (every value is a function of its key)."""


def parts_key(parts: Sequence[SpatialCommand]) -> PartsKey:
    """Canonical cache key: directions by slug, sizes as floats, exact flags; raises on
    invalid parts. A spelling already seen costs a dictionary look-up: a command stream
    repeats the same few, and this runs before every command's first step."""
    key = []
    for p in parts:
        spelled = (p.limb, p.origin, p.direction, p.size, p.exact)
        canonical = _CANONICAL.peek(spelled)
        if canonical is None:
            check_spatial(p)
            canonical = (p.limb, p.origin, Direction.parse(p.direction).slug, float(p.size),
                         p.exact)
            _CANONICAL.put(spelled, canonical)
        key.append(canonical)
    return tuple(key)


def _charge(key: PartsKey, pose: Pose) -> int:
    return ENTRY_BYTES + len(encode(pose)) + sum(len(a) + len(b) + len(c) + 16
                                                 for a, b, c, _, _ in key)


Charged = tuple[Pose, int]
"""A cached pose and its charge (:func:`_charge`), reckoned before the cache's lock is taken."""


def _charged(key: PartsKey, kept: Charged) -> int:
    return kept[1]


@dataclass
class _Request:
    ticket: int
    key: PartsKey
    callback: Callback


class Resolver:
    """Pose and compound queries for one platform, cached per databank version."""

    def __init__(
        self,
        session: zenoh.Session,
        platform: str,
        keys: Keys | None = None,
        timeout_s: float = 1.0,
        refresh_s: float = 2.0,
        probe_s: float = 0.25,
        ready_s: float = 2.0,
        cache_bytes: int = CACHE_BYTES,
        solve_timeout_s: float = SOLVE_TIMEOUT_S,
    ) -> None:
        self.session = session
        self.platform = platform
        self.keys = keys or Keys()
        self.timeout_s = timeout_s
        self.solve_timeout_s = max(solve_timeout_s, timeout_s)
        self.refresh_s = refresh_s
        self.probe_s = probe_s
        self.ready_s = ready_s
        self.version: str | None = None
        self.catalogue: Catalogue | None = None
        self.reachable: bool | None = None  # None until the first answer or failure
        self.last_error = ""
        self.queries = 0  # round trips made for poses (cache misses), for tests and benches
        self._cache: Lru[PartsKey, Charged] = Lru(max(1, cache_bytes // ENTRY_BYTES),
                                                  cache_bytes, _charged)
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._pending: _Request | None = None
        self._stale = False
        self._closing = False
        self._woken = threading.Event()
        """Set by a catalogue match, or by :meth:`close`: what ends :meth:`wait_ready`."""
        self._changed: Any = None
        self._catalogue: zenoh.Querier | None = None
        self._thread = threading.Thread(target=self._run, name=f"resolver-{platform}", daemon=True)

    def start(self) -> None:
        self._changed = self.session.declare_subscriber(
            self.keys.changed(self.platform), self._on_changed
        )
        self._thread.start()

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait until a databank queryable for this platform is known to the session, or the
        resolver closes (False then, unless one is known).

        Declarations travel asynchronously: a ``get`` right after joining finds no route and
        ends at once without replies, which would read as an outage. A robot stopped while it
        waits (no databank up) stops at once, not at the end of ``ready_s``.
        """
        if self._catalogue is None:
            self._catalogue = self.session.declare_querier(
                self.keys.catalogue(self.platform), timeout=self.timeout_s,
                consolidation=zenoh.ConsolidationMode.NONE,
            )
        return wait_matching(self._catalogue, timeout_s, wake=self._woken)

    def _on_changed(self, sample: zenoh.Sample) -> None:
        """A record happened: forget now (a command right behind must miss the cache), and let
        the worker re-read the catalogue for the new version."""
        with self._wake:
            self._cache.clear()
            self.version = None
            self._stale = True
            self._wake.notify()

    def close(self) -> None:
        with self._wake:
            self._closing = True
            self._wake.notify()
        self._woken.set()
        if self._thread.is_alive():
            self._thread.join(timeout=self.timeout_s + 1.0)
        undeclare(self._changed, self._catalogue)
        self._changed = self._catalogue = None

    # --- called from the control loop -------------------------------------------------------

    def cached(self, key: PartsKey) -> Pose | None:
        """The answer for ``key`` if this databank version already gave it."""
        with self._lock:
            hit = self._cache.get(key)
        return None if hit is None else hit[0]

    def __len__(self) -> int:
        return len(self._cache)

    @property
    def cache_bytes(self) -> int:
        """Budget of the pose cache (a smaller one applies from the next answer cached)."""
        return self._cache.max_bytes

    @cache_bytes.setter
    def cache_bytes(self, budget: int) -> None:
        with self._lock:
            self._cache.max_bytes = budget
            self._cache.most = max(1, budget // ENTRY_BYTES)

    @property
    def cached_bytes(self) -> int:
        """Bytes charged by the poses cached now."""
        return self._cache.bytes

    def submit(self, ticket: int, key: PartsKey, callback: Callback) -> None:
        """Resolve ``key`` in the worker; ``callback(ticket, pose or error)`` runs there.

        A request still waiting is replaced (its callback is never called).
        """
        with self._wake:
            self._pending = _Request(ticket, key, callback)
            self._wake.notify()

    # --- the worker ---------------------------------------------------------------------------

    def _run(self) -> None:
        self.wait_ready(self.ready_s)
        next_check = 0.0
        while True:
            with self._wake:
                while not self._closing and self._pending is None and not self._stale:
                    timeout = next_check - time.monotonic()
                    if timeout <= 0:
                        break
                    self._wake.wait(timeout)
                if self._closing:
                    return
                request, self._pending = self._pending, None
                stale, self._stale = self._stale, False
            if request is not None:
                answer = self._resolve(request.key)
                try:
                    request.callback(request.ticket, answer)
                except Exception:  # the loop's inbox append cannot fail; never kill the worker
                    log.exception("resolver callback failed")
            if request is None or stale or not self.reachable or time.monotonic() >= next_check:
                self.refresh()
                next_check = time.monotonic() + (self.refresh_s if self.reachable else self.probe_s)

    def refresh(self) -> bool:
        """Read the catalogue; a new version empties the cache. Returns reachability."""
        try:
            cat = self._query(self.keys.catalogue(self.platform), None, Catalogue, self._catalogue)
        except KinesphereError as exc:
            if exc.code == "unavailable":
                self._unreachable(exc)
            else:  # it answered, with an error (e.g. it does not serve this platform)
                log.warning("catalogue of %s: %s", self.platform, exc)
                self._reached()
            return bool(self.reachable)
        if cat.version != self.version:
            if self.version is not None:
                log.info("databank %s changed version %s -> %s; cache cleared",
                         self.platform, self.version, cat.version)
            with self._lock:
                self._cache.clear()
            self.version = cat.version
        self.catalogue = cat
        self._reached()
        return True

    def resolve(self, key: PartsKey) -> PoseAnswer:
        """Blocking resolution of ``key`` (cache first); errors are returned, not raised."""
        hit = self.cached(key)
        return hit if hit is not None else self._resolve(key)

    def _resolve(self, key: PartsKey) -> PoseAnswer:
        if self.version is None:
            self.refresh()  # learn the version first, so the answer is cached under it
        version = self.version
        timeout = self.solve_timeout_s if self._may_solve(key) else self.timeout_s
        try:
            ask, payload = pose_query(self.keys, self.platform,
                                      [SpatialCommand(*p) for p in key])
            pose = self._query(ask, payload, Pose, timeout=timeout)
        except KinesphereError as exc:
            if exc.code == "unavailable":
                self._unreachable(exc)
            else:
                self._reached()
            return exc
        self._reached()
        self.queries += 1
        if version is not None and version == self.version:
            kept = (pose, _charge(key, pose))
            with self._lock:
                self._cache.put(key, kept)
        return pose

    def _may_solve(self, key: PartsKey) -> bool:
        """Whether the databank may answer ``key`` with its nested solver (see the module)."""
        if len(key) > 1:
            return True
        cat = self.catalogue
        return cat is not None and any(w.end and w.word == key[0][0] for w in cat.vocabulary)

    def _query(self, key: str, payload: bytes | None, type_: type[T],
               querier: zenoh.Querier | None = None, timeout: float | None = None) -> T:
        """One ``get`` (the first answer wins; other replicas may answer too), no retry: the
        worker's schedule does the retrying. Nobody answering because this robot reached no
        router at all is said so (with the command that starts one), not blamed on the
        databank."""
        try:
            return get_one(querier if querier is not None else self.session, key, type_,
                           payload, timeout=self.timeout_s if timeout is None else timeout,
                           no_answer=f"no databank answers {key}")
        except KinesphereError as exc:
            alone = zconfig.alone(self.session) if exc.code == "unavailable" else ""
            if alone:
                raise KinesphereError("unavailable", f"{exc.message}: {alone}") from None
            raise

    def _unreachable(self, exc: KinesphereError) -> None:
        if self.reachable or self.last_error != exc.message:
            log.warning("databank unreachable for %s: %s", self.platform, exc.message)
        self.reachable = False
        self.last_error = exc.message

    def _reached(self) -> None:
        if not self.reachable:
            log.info("databank reachable for %s", self.platform)
        self.reachable = True
        self.last_error = ""
