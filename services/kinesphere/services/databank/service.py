"""The databank service: the ECL's network face, answering pose queries over Zenoh.

Every query under ``{p}/ecl/`` goes to *one* Python callback: Zenoh hands a query to every
matching queryable of a session, and a second callback per query (a catch-all next to the
pose queryable) measurably slows the hot path. So the service declares, complete:

- ``{p}/ecl/*/**`` when it serves every *known* platform (the shipped ones, plus any the
  operator names): each concrete platform is then either served here or unknown, and
  unknown ones get ``unknown_platform``. This is the default ``serve`` set-up.
- otherwise ``{p}/ecl/{platform}/**`` per served platform, plus a non-complete catch-all on
  ``{p}/ecl/*/**`` that answers ``unknown_platform`` only for platforms outside the known
  set and stays silent for known ones (another replica may serve them).

*Complete* is what makes replicas work: with the default query target (BEST_MATCHING) Zenoh
routes a query to one complete queryable that covers its key, so a querier gets one answer
(good or bad) however many replicas run, and when a replica dies its declarations vanish
with its link and the next query goes to another. Replicas must agree on the known set.

Hot path: one dict hit on the key text, then ``query.reply`` with a pre-encoded payload.
Records (SQL) run on the :class:`~kinesphere.services.databank.records.PoseRecorder`'s worker
thread, nested solves (an upper arm and its forearm pointed together) on
:class:`~kinesphere.services.databank.solves.Solves`' worker. A pose key with the selector
parameter ``exact=true`` asks for that direction only: no substitution by the nearest one.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import zenoh

from kinesphere.closing import Startable
from kinesphere.errors import KinesphereError, choices, did_you_mean
from kinesphere.keyexpr import EXACT, KEYS, Keys, check_segment
from kinesphere.platforms.platform import platform_names
from kinesphere.protocol import CompoundRequest, check_spatial, decode
from kinesphere.ratelog import RateLog
from kinesphere.services.databank.body import body_model
from kinesphere.services.databank.records import PoseRecorder, Served
from kinesphere.services.databank.replies import (
    DEFAULT_BUDGET,
    DEFERRED,
    CacheBudget,
    Deferred,
    EncodedReply,
    ReplyCache,
    error,
    ok,
    request_bytes,
    send,
)
from kinesphere.services.databank.solves import Solves
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.sizes import parse_size

log = logging.getLogger(__name__)


Routed = EncodedReply | Deferred | None  # None: answered already (wildcards) or silent
EXACT_SUFFIX = EXACT  # the cache key of an exact-only query: the selector itself


def exact_only(parameters: zenoh.Parameters) -> bool:
    """Whether a query's selector parameters ask for the exact direction only (``exact=true``
    or ``exact=1``); other parameters are ignored, so they cannot multiply cached answers."""
    return (parameters.get("exact") or "").lower() in ("true", "1")


def changed_key(keys: Keys, platform: str) -> str:
    """``{p}/ecl/{platform}/changed``: a put after every successful record (``keys.changed``);
    ``platform`` may be ``*`` to watch every platform."""
    return keys.changed(platform)


class DatabankService(Startable):
    """Serve ``ecls`` (platform name -> Ecl) on ``session`` between :meth:`start` and :meth:`close`.

    The caller owns the session and closes it after this service. ``writes_enabled`` lets
    ``record`` queries and puts change the databanks; who may send them is for the Zenoh
    deployment's access control (``{p}/ecl/*/record``). ``known_platforms`` replaces the
    shipped platform names as the set this replica must not call unknown.
    """

    def __init__(
        self,
        session: zenoh.Session,
        ecls: Mapping[str, Ecl],
        keys: Keys = KEYS,
        replica_id: str = "databank",
        writes_enabled: bool = False,
        *,
        known_platforms: Iterable[str] | None = None,
        budget: CacheBudget = DEFAULT_BUDGET,
    ) -> None:
        if not ecls:
            raise KinesphereError("malformed", "a databank service needs at least one platform")
        self.session = session
        self.keys = keys
        self.replica_id = check_segment(replica_id, "replica")
        self.served: dict[str, Served] = {}
        for name, ecl in ecls.items():
            check_segment(name, "platform")
            if ecl.platform.name != name:
                raise KinesphereError(
                    "malformed", f"databank for {ecl.platform.name!r} offered as {name!r}"
                )
            self.served[name] = Served(
                name, ecl, keys.catalogue(name), keys.compound(name), keys.record(name),
                keys.changed(name),
            )
        known = platform_names() if known_platforms is None else known_platforms
        self.known = frozenset(known) | set(self.served)
        self.serves_all_known = self.known == set(self.served)
        self.answers = ReplyCache(budget.answers)
        self.errors = ReplyCache(budget.errors)
        self.compounds = ReplyCache(budget.compounds)
        self.refused = RateLog(log)
        """One warning line per malformed-request kind and platform every 10 s."""
        self._head = f"{keys.prefix}/ecl/"
        self._entities: list[Any] = []
        self.recorder = PoseRecorder(session, self.replica_id, writes_enabled, self.swap,
                                 self.refused)
        self.solves = Solves(self.replica_id)
        self._started = False
        self._lock = threading.Lock()

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> DatabankService:
        """Declare everything; returns self. Declarations reach peers asynchronously."""
        with self._lock:
            if self._started:
                return self
            self._started = True
            self.recorder.start()
            self.solves.start()
            s, add = self.session, self._entities.append
            try:
                if self.serves_all_known:
                    add(s.declare_queryable(f"{self._head}*/**", self._handler(self.served),
                                            complete=True))
                else:
                    for st in self.served.values():
                        add(s.declare_queryable(f"{self._head}{st.name}/**",
                                                self._handler({st.name: st}), complete=True))
                    add(s.declare_queryable(f"{self._head}*/**", self._on_other))
                for st in self.served.values():
                    add(s.declare_subscriber(st.record_key, self.recorder.put_handler(st)))
                    add(s.declare_subscriber(st.changed_key, self.recorder.peer_handler(st)))
                add(s.liveliness().declare_token(self.keys.alive_databank(self.replica_id)))
            except BaseException:
                self._undeclare()
                raise
        return self

    def close(self) -> None:
        """Undeclare everything (the liveliness token first, so clients fail over early),
        finish queued records, and let go of the databanks."""
        with self._lock:
            if not self._started:
                return
            self._started = False
            self._undeclare()
            self.recorder.stop()
            self.solves.stop()
            for st in self.served.values():
                closer = getattr(st.ecl, "close", None)
                if callable(closer):
                    closer()

    def _undeclare(self) -> None:
        for entity in reversed(self._entities):
            try:
                entity.undeclare()
            except zenoh.ZError as exc:  # the session may already be closed
                log.debug("undeclare failed: %s", exc)
        self._entities.clear()

    def ecl(self, platform: str) -> Ecl:
        """The ECL serving ``platform`` right now (replaced after each record)."""
        return self.served[platform].ecl

    def swap(self, st: Served, ecl: Ecl) -> None:
        """Serve ``ecl`` for ``st`` from now on; answers computed before are dropped."""
        st.ecl = ecl
        self.answers.invalidate()
        self.errors.invalidate()
        self.compounds.invalidate()

    # -- the hot path ------------------------------------------------------------------------
    def _handler(self, scope: Mapping[str, Served]) -> Callable[[zenoh.Query], None]:
        get, get_error = self.answers.get, self.errors.get
        route = self._route

        def on_query(query: zenoh.Query) -> None:
            keep = False
            try:
                ke = query.key_expr
                key = str(ke)
                if query.parameters:  # only ``exact`` means anything (see exact_only)
                    key += EXACT_SUFFIX if exact_only(query.parameters) else ""
                answer = get(key) or get_error(key)
                if answer is None:
                    routed = route(scope, query, key)
                    if not isinstance(routed, EncodedReply):
                        keep = routed is DEFERRED
                        return
                    answer = routed
                if answer.ok:
                    query.reply(ke, answer.payload)
                else:
                    query.reply_err(answer.payload)
            except Exception:
                log.exception("query %s failed", query.key_expr)
            finally:
                if not keep:
                    query.drop()  # type: ignore[no-untyped-call]

        return on_query

    def _route(self, scope: Mapping[str, Served], query: zenoh.Query, key: str) -> Routed:
        """Answer a key the cache does not hold (and cache what may be cached)."""
        generation = self.answers.generation  # read before any ECL: see ReplyCache
        failed = self.errors.generation
        if "*" in key or "$" in key:
            self._wildcard(scope, query, key)
            return None
        plain = key.removesuffix(EXACT_SUFFIX)  # the cache keeps exact-only answers apart
        exact = plain != key
        platform, _, rest = plain[len(self._head) :].partition("/")
        st = scope.get(platform)
        if st is None:  # only when this replica serves every known platform
            return self.errors.put(key, self._unknown(platform), failed)
        try:
            if rest.startswith("pose/"):
                pk = self.keys.parse_pose_key(plain)
                part = (pk.limb, pk.origin, pk.direction, parse_size(pk.size), exact)
                if st.ecl.solves([part]):  # a cut limb: the nested solver, off this thread
                    return self.solves.defer(
                        query, lambda: self._pose(st, part, key, generation, failed))
                return self._pose(st, part, key, generation, failed)
            elif rest == "catalogue":
                answer = ok(st.ecl.catalogue())
            elif rest == "body":
                answer = ok(body_model(st.ecl.platform))
            elif rest == "compound":
                return self._compound(st, query, key)
            elif rest == "record":
                return self.recorder.on_query(st, query)
            else:
                answer = self._bad_key(key, platform)
        except KinesphereError as exc:
            answer = error(exc.code, exc.message)
        except Exception as exc:  # a bug: say so, and do not cache it
            log.exception("query %.200s failed", key)
            return error("internal", f"{type(exc).__name__}: {exc}")
        if answer.ok:
            return self.answers.put(key, answer, generation)
        return self.errors.put(key, answer, failed)

    def _pose(self, st: Served, part: tuple[str, str, str, float, bool], key: str,
              generation: int, failed: int) -> EncodedReply:
        """A pose key's answer, cached under ``key`` (errors in the error cache)."""
        try:
            answer = ok(st.ecl.query(*part))
        except KinesphereError as exc:
            return self.errors.put(key, error(exc.code, exc.message), failed)
        return self.answers.put(key, answer, generation)

    def _compound(self, st: Served, query: zenoh.Query, key: str) -> EncodedReply | Deferred:
        generation = self.compounds.generation
        try:
            raw = request_bytes(query, "CompoundRequest")
            hit = self.compounds.get((key, raw))
            if hit is not None:
                return hit
            req = decode(raw, CompoundRequest)
            for part in req.parts:
                check_spatial(part)
        except KinesphereError as exc:
            if exc.code == "malformed":
                self.refused((st.name, "compound"), "%s compound refused: %s", st.name, exc)
            return error(exc.code, exc.message)
        if st.ecl.solves(req.parts):  # nested parts: the solver, off Zenoh's thread
            return self.solves.defer(
                query, lambda: self._joined(st, req, (key, raw), generation))
        return self._joined(st, req, (key, raw), generation)

    def _joined(self, st: Served, req: CompoundRequest, cache_key: tuple[str, bytes],
                generation: int) -> EncodedReply:
        """A compound request's answer; good ones cached under the request's bytes."""
        try:
            answer = ok(st.ecl.compound(req.parts, last_wins=req.last_wins))
        except KinesphereError as exc:
            return error(exc.code, exc.message)
        return self.compounds.put(cache_key, answer, generation)

    def _wildcard(self, scope: Mapping[str, Served], query: zenoh.Query, key: str) -> None:
        """A wildcard key (discovery: ``{p}/ecl/*/catalogue``) gets each matching catalogue."""
        asked = zenoh.KeyExpr(key)
        for st in scope.values():
            if asked.intersects(st.catalogue_key):
                send(query, st.catalogue_key, ok(st.ecl.catalogue()))

    def _bad_key(self, key: str, platform: str) -> EncodedReply:
        return error(
            "malformed",
            f"{key:.200} is not a databank key; under {self._head}{platform:.64}/ query "
            "pose/<limb>/<origin>/<direction>/<size>, compound, catalogue, body or record",
        )

    def _unknown(self, platform: str) -> EncodedReply:
        try:
            check_segment(platform, "platform")
        except KinesphereError as exc:  # too long, say: the name is not echoed whole
            return error(exc.code, exc.message)
        return error(
            "unknown_platform", f"no platform {platform!r}{did_you_mean(platform, self.known)}; "
            f"known platforms: {choices(self.known)}",
        )

    # -- the catch-all, when this replica serves only some known platforms --------------------
    def _on_other(self, query: zenoh.Query) -> None:
        try:
            answer = self.other_answer(str(query.key_expr))
            if answer is not None:
                query.reply_err(answer.payload)
        except Exception:
            log.exception("query %s failed", query.key_expr)
        finally:
            query.drop()  # type: ignore[no-untyped-call]

    def other_answer(self, key: str) -> EncodedReply | None:
        """``unknown_platform`` for a concrete platform outside the known set, else None."""
        if "*" in key or "$" in key:
            return None
        platform = key[len(self._head) :].partition("/")[0]
        if platform in self.known:
            return None  # served here (its own queryable answers) or maybe by another replica
        generation = self.errors.generation
        hit = self.errors.get(platform)
        return hit or self.errors.put(platform, self._unknown(platform), generation)
