"""Bodies and targets from the databank, fetched off the frame loop.

The view must never wait on the network while it draws: a body (``{p}/ecl/{platform}/body``)
or a target pose (the pose or compound query a robot itself makes for a command) is asked for
once on a worker thread, and the frame loop picks the answer up on a later frame. Answers are
cached per request, in a bounded table; failures are remembered (with the error, for the
panel) and retried after :data:`RETRY_S`.

A body is checked and built into a :class:`BodyGeometry` on the worker too, once per content (the
digest of its text and meshes, computed here: a sender's ``version`` could name another
body's): the same body under another platform name, or fetched again after a retry, is not
parsed again, and a refused one is logged once and remembered (:data:`MAX_BODIES`).
"""

from __future__ import annotations

import hashlib
import logging
import queue
import threading
import time
from collections.abc import Callable, Hashable, Sequence
from typing import Final, Generic, TypeVar

import zenoh

from kinesphere.clients.view.body import BodyGeometry
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.lru import Lru
from kinesphere.protocol import BodyModel, CompoundRequest, Pose, SpatialCommand, encode
from kinesphere.query import get_one

log = logging.getLogger(__name__)
T = TypeVar("T")
RETRY_S: Final = 2.0
MAX_ANSWERS: Final = 512
TIMEOUT_S: Final = 2.0
MAX_BODIES: Final = 64
"""Bodies (built or refused) remembered by content."""


class Answers(Generic[T]):
    """``get(request)``: the answer, None while it is being fetched, or the error it gave."""

    def __init__(self, fetch: Callable[[Hashable], T], name: str) -> None:
        self._fetch = fetch
        self._done: Lru[Hashable, tuple[T | KinesphereError, float]] = Lru(MAX_ANSWERS)
        """request -> its answer and when it came"""
        self._asked: set[Hashable] = set()
        self._lock = threading.Lock()
        self._jobs: queue.SimpleQueue[Hashable | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def get(self, request: Hashable) -> T | KinesphereError | None:
        with self._lock:
            done = self._done.peek(request)
            if done is None:
                self._ask(request)
                return None
            answer, at = done
            if isinstance(answer, KinesphereError) and time.monotonic() - at > RETRY_S:
                self._done.pop(request)
                self._ask(request)
            return answer

    def peek(self, request: Hashable) -> T | KinesphereError | None:
        """What :meth:`get` would return, without asking for anything."""
        with self._lock:
            done = self._done.peek(request)
        return None if done is None else done[0]

    def _ask(self, request: Hashable) -> None:
        if request not in self._asked:
            self._asked.add(request)
            self._jobs.put(request)

    def _run(self) -> None:
        while (request := self._jobs.get()) is not None:
            try:
                answer: T | KinesphereError = self._fetch(request)
            except KinesphereError as exc:
                answer = exc
            except Exception as exc:  # a bug must not end the thread
                log.exception("fetching %r failed", request)
                answer = KinesphereError("internal", repr(exc))
            with self._lock:
                self._asked.discard(request)
                self._done.put(request, (answer, time.monotonic()))

    def close(self) -> None:
        self._jobs.put(None)
        self._thread.join(timeout=TIMEOUT_S + 1.0)


PartKey = tuple[tuple[str, str, str, float], ...]


def part_key(parts: Sequence[SpatialCommand]) -> PartKey:
    """A hashable stand-in for a command's parts (msgspec Structs are not hashable)."""
    return tuple((p.limb, p.origin, p.direction, p.size) for p in parts)


def pose_request(session: zenoh.Session, keys: Keys, platform: str, parts: Sequence[SpatialCommand]
                 ) -> Pose:
    """The pose ``platform``'s databank answers for ``parts`` (as the robot asks it)."""
    if len(parts) == 1:
        p = parts[0]
        key = keys.pose(platform, p.limb, p.origin, p.direction, p.size)
        return get_one(session, key, Pose, timeout=TIMEOUT_S)
    payload = encode(CompoundRequest(parts=list(parts)))
    return get_one(session, keys.compound(platform), Pose, payload, timeout=TIMEOUT_S)


def digest(model: BodyModel) -> str:
    """What identifies a body's content: its text and every mesh file it carries."""
    h = hashlib.sha256(model.eurdf.encode())
    for name in sorted(model.meshes):
        h.update(b"\0" + name.encode() + b"\0")
        h.update(hashlib.sha256(model.meshes[name]).digest())
    return h.hexdigest()


class Bodies:
    """:class:`BodyGeometry` by content, built once; refusals remembered and logged once."""

    def __init__(self, most: int = MAX_BODIES) -> None:
        self.most = most
        self._known: Lru[str, BodyGeometry | KinesphereError] = Lru(most)
        self.built = 0
        """Bodies parsed (accepted or refused) since start."""

    def body(self, model: BodyModel) -> BodyGeometry:
        key = digest(model)
        known = self._known.get(key)
        if known is None:
            self.built += 1
            try:
                known = BodyGeometry(model)
            except KinesphereError as exc:
                known = KinesphereError(exc.code, f"body of {model.platform} refused: "
                                        f"{exc.message}")
                log.warning("%s", known.message)
            else:
                if known.missing:
                    log.warning("body of %s: %d mesh(es) not sent with it, not drawn (%s)",
                                model.platform, len(known.missing), ", ".join(known.missing[:3]))
            self._known.put(key, known)
        if isinstance(known, KinesphereError):
            raise known
        if known.platform != model.platform:  # the same content under another name
            known = known.renamed(model.platform)
        return known


class Databank:
    """Bodies by platform and target poses by ``(platform, parts)``, fetched in the background."""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self.built = Bodies()

        def body(platform: Hashable) -> BodyGeometry:
            assert isinstance(platform, str)
            model = get_one(session, keys.body(platform), BodyModel, timeout=TIMEOUT_S,
                            no_answer=f"no databank sends the body of {platform!r}")
            return self.built.body(model)

        def pose(request: Hashable) -> Pose:
            assert isinstance(request, tuple)
            platform, parts = request
            return pose_request(session, keys, platform, [SpatialCommand(*p) for p in parts])

        self.bodies: Answers[BodyGeometry] = Answers(body, "view-bodies")
        self.poses: Answers[Pose] = Answers(pose, "view-poses")

    def close(self) -> None:
        self.bodies.close()
        self.poses.close()
