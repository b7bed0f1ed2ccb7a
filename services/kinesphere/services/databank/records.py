"""Super-user writes (``record``) and keeping replicas in step after them.

A record is validated, written by a fresh copy of the ECL (``Ecl.record`` writes SQL and
reloads), and the copy is swapped in whole, so concurrent pose lookups never see a half-built
ECL and need no lock. Then ``{p}/ecl/{platform}/changed`` is put with the recorded Pose as
payload and the replica id as attachment: agents drop their cached poses of that platform.

Replicas receive each other's ``changed`` too. A replica that sees a peer's record does
nothing if it already serves that pose (the record was sent to every replica), reloads its
databank when the file on disk changed (replicas sharing one file), else re-applies the same
record when its own writes are enabled (so replicas with their own files converge), else it
logs that it now serves older poses. Re-applied records are not announced again.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from kinesphere import hints
from kinesphere.errors import KinesphereError
from kinesphere.protocol import Pose, RecordRequest, decode, encode
from kinesphere.ratelog import RateLog
from kinesphere.services.databank.replies import (
    DEFERRED,
    Deferred,
    EncodedReply,
    error,
    ok,
    request_bytes,
    send,
)
from kinesphere.services.databank.worker import Worker
from kinesphere.services.ecl.ecl import Ecl

log = logging.getLogger(__name__)


@dataclass(eq=False)
class Served:
    """One served platform: its ECL (replaced whole after a record) and its key texts."""

    name: str
    ecl: Ecl
    catalogue_key: str
    compound_key: str
    record_key: str
    changed_key: str


def _forbidden(st: Served) -> KinesphereError:
    return KinesphereError(
        "forbidden",
        f"recording poses is disabled on this databank for {st.name}; "
        f"start it with '{hints.serve_databank(st.name, str(st.ecl.db_path), True)}'",
    )


class PoseRecorder:
    """A databank's writes: record queries and puts, and following other replicas' records.

    All SQL runs on one worker thread with a bounded queue, off Zenoh's threads. ``swap``
    serves a freshly recorded ECL (the service drops its cached answers); ``refused`` logs
    refusals at most once per kind every 10 s.
    """

    def __init__(
        self,
        session: zenoh.Session,
        replica_id: str,
        writes_enabled: bool,
        swap: Callable[[Served, Ecl], None],
        refused: RateLog,
    ) -> None:
        self.session = session
        self.replica_id = replica_id
        self.writes_enabled = writes_enabled
        self._swap = swap
        self._refused = refused
        self._worker = Worker(f"databank-{replica_id}-records")

    def start(self) -> None:
        self._worker.start()

    def stop(self) -> None:
        """Finish the queued records."""
        self._worker.stop()

    # -- record queries and puts ---------------------------------------------------------------
    def on_query(self, st: Served, query: zenoh.Query) -> EncodedReply | Deferred:
        """A record query: refused at once when writes are off, else queued for the worker,
        which answers and drops it (:data:`DEFERRED` tells the caller to keep it)."""
        if not self.writes_enabled:
            return error("forbidden", _forbidden(st).message)
        if not self._worker.submit(lambda: self._answer(st, query)):
            return error("unavailable", f"{st.name}: too many records queued; retry later")
        return DEFERRED

    def _answer(self, st: Served, query: zenoh.Query) -> None:
        with query:
            try:
                answer: EncodedReply = ok(self.record(st, request_bytes(query, "RecordRequest")))
            except KinesphereError as exc:
                if exc.code == "malformed":
                    self._refused((st.name, "record"), "%s record refused: %s", st.name, exc)
                answer = error(exc.code, exc.message)
            except Exception as exc:
                log.exception("record on %s failed", st.name)
                answer = error("internal", f"{type(exc).__name__}: {exc}")
            send(query, st.record_key, answer)

    def put_handler(self, st: Served) -> Callable[[zenoh.Sample], None]:
        """Record puts: no one to answer, so failures are logged (refusals at most every 10 s)."""

        def on_put(sample: zenoh.Sample) -> None:
            if not self.writes_enabled:
                self._refused((st.name, "put"), "%s", _forbidden(st))
                return
            payload = sample.payload.to_bytes()
            if not self._worker.submit(lambda: self._put(st, payload)):
                self._refused((st.name, "put", "busy"),
                              "record put on %s dropped: too many queued", st.name)

        return on_put

    def _put(self, st: Served, payload: bytes) -> None:
        try:
            self.record(st, payload)  # decode refuses payloads over MAX_PAYLOAD
        except KinesphereError as exc:
            self._refused((st.name, "put", exc.code), "record put on %s refused: %s", st.name,
                          exc)

    def record(self, st: Served, payload: bytes) -> Pose:
        """Store a RecordRequest, serve the result at once, announce it; worker thread only."""
        req = decode(payload, RecordRequest)
        pose = self._write(st, req.limb, req.origin, req.direction, req.size, req.joints)
        log.info(
            "recorded %s %s/%s/%s/%d on replica %s (ECL %s)",
            st.name, pose.limb, pose.origin, pose.direction, req.size, self.replica_id,
            st.ecl.version,
        )
        self.session.put(st.changed_key, encode(pose), attachment=self.replica_id.encode())
        return pose

    def _write(
        self, st: Served, limb: str, origin: str, direction: str, size: int,
        joints: dict[str, float],
    ) -> Pose:
        fresh = Ecl.open(st.ecl.platform, st.ecl.db_path)
        pose: Pose = fresh.record(limb, origin, direction, size, joints)
        self._swap(st, fresh)
        return pose

    # -- other replicas' records ---------------------------------------------------------------
    def peer_handler(self, st: Served) -> Callable[[zenoh.Sample], None]:
        """``changed`` from another replica: catch up on the worker thread."""
        me = self.replica_id.encode()

        def on_changed(sample: zenoh.Sample) -> None:
            att = sample.attachment
            origin = att.to_bytes() if att is not None else b""
            if origin == me:
                return
            payload = sample.payload.to_bytes()
            peer = origin.decode("utf-8", "replace")[:64]
            if not self._worker.submit(lambda: self._catch_up(st, payload, peer)):
                self._refused((st.name, "changed", "busy"),
                              "cannot follow %s's record on %s: too many records queued; this "
                              "replica may serve older poses", peer, st.name)

        return on_changed

    def _catch_up(self, st: Served, payload: bytes, peer: str) -> None:
        try:
            pose = decode(payload, Pose)
            if pose.p_id is None or pose.is_compound:
                raise KinesphereError("malformed", "changed carries no stored pose")
            if st.ecl.query(pose.limb, pose.origin, pose.direction, pose.p_id) == pose:
                return  # this replica recorded it too (a record sent to every replica)
            on_disk = Ecl.open(st.ecl.platform, st.ecl.db_path)
            if on_disk.version != st.ecl.version:
                self._swap(st, on_disk)
                log.info("reloaded %s after replica %s recorded (ECL %s)", st.name, peer,
                         on_disk.version)
            elif self.writes_enabled:
                self._write(st, pose.limb, pose.origin, pose.direction, pose.p_id, pose.joints)
                log.info("applied %s's record of %s %s/%s/%s/%d", peer, st.name, pose.limb,
                         pose.origin, pose.direction, pose.p_id)
            else:
                log.warning("replica %s recorded a %s pose this read-only replica does not "
                            "have; it serves older poses until restarted", peer, st.name)
        except KinesphereError as exc:
            self._refused((st.name, "changed", peer), "cannot follow %s's record on %s: %s",
                          peer, st.name, exc)
