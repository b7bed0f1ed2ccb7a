"""Zenoh's log lines about refused sessions and messages, turned into one ``access denied``
line each, in bounded memory and at a bounded rate.

Zenoh 1.x reports an access-control denial only as two TRACE lines (``... is unauthorized to
Put (ingress) on KEY`` then ``Msg intercepted!``) and a refused TLS handshake (no certificate,
another CA, plain TCP) as a warning that names no peer. :class:`DenialFilter` reads those
lines and reports ``access denied: Put (ingress) on KEY by CN=... (...)`` or ``access denied:
TLS handshake refused (peer sent no certificates) from 10.0.0.7:40312``.

Whoever is denied chooses what to send, so the reports are bounded: one (identity, action,
key) at most once per second (repeats are counted into its next line), one identity (its
certificate name, else its session) at most :data:`BURST` lines per :data:`WINDOW_S`, and
every table is pruned, oldest first, past a fixed size.
"""

from __future__ import annotations

import logging
import queue
import re
import threading
import time
from collections.abc import Callable
from typing import Final

from kinesphere.lru import Lru
from kinesphere.ratelog import RateLog

INTERCEPTOR = "zenoh::net::routing::interceptor"
TLS_TARGET = "zenoh_link_tls::unicast"
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_LINE = re.compile(
    r"^\S+\s+(?P<level>TRACE|DEBUG|INFO|WARN|ERROR)\s+(?P<thread>.*?ThreadId\(\d+\))\s+"
    r"(?P<target>[\w:]+): (?P<msg>.*)$"
)
_DENIED = re.compile(
    r"(?:Using cached result: )?(?P<zid>[0-9a-f]+)(?: on (?P<subject>\S+))? is unauthorized to "
    r"(?P<action>.+?) on (?P<key>\S+)$"
)
_SUBJECT = re.compile(r"^(?P<zid>[0-9a-f]+) on (?P<subject>\S+) is (?:un)?authorized to ")
_REFUSED = re.compile(r"^(?P<reason>.+?)\. Hint: increase the system open file limit\.$")
"""How Zenoh's TLS listener words a failed handshake (the hint is Zenoh's, not ours)."""
NOT_REFUSALS: Final = frozenset({"tls handshake eof"})
"""A peer that closed before any handshake (a port probe, a health check): not a denial."""
SUPPRESS_S: Final = 1.0
"""Repeats of one (identity, action, key) denial within this window are counted, not logged."""
BURST: Final = 10
WINDOW_S: Final = 10.0
"""One identity gets at most BURST lines per WINDOW_S; the next line counts the rest."""
TOTAL_BURST: Final = 100
"""All identities together get at most this many lines per WINDOW_S (sessions without a
certificate are told apart only by their session ids, which they choose)."""
MAX_ENTRIES: Final = 1024
"""Entries of each table (sessions' subjects, pending lines, recent denials, peers)."""
MAX_QUEUED: Final = 256
"""Refused handshakes waiting for their peer's lookup; more are counted, not named."""
PEER_WAIT_S: Final = 1.0
"""How long a refusal waits for the closed connection that names its peer."""
CLAIM_BEFORE_S: Final = 0.2
"""A connection closed this long before its refusal was read still counts (the log pipe
may lag behind the kernel's notice)."""

_PROPERTY = re.compile(r"^(\w+)\((.*)\)$")
_NAMES = {"CertCommonName": "CN", "Username": "user", "Interface": "interface",
          "Transport": "link"}

def describe_subject(subject: str, zid: str) -> str:
    """``Interface(lo)+CertCommonName(op)+...+<zid>`` -> ``CN=op (interface=lo, ...)``."""
    props: dict[str, str] = {}
    for part in subject.split("+"):
        m = _PROPERTY.match(part)
        if m:
            props[_NAMES.get(m[1], m[1])] = m[2]
    who = next((f"{k}={props.pop(k)}" for k in ("CN", "user") if k in props), "no certificate")
    rest = ", ".join([f"{k}={v}" for k, v in props.items()] + [f"zid={zid}"])
    return f"{who} ({rest})"


def _identity(who: str) -> str:
    """What the per-identity budget counts: the certificate or user name, else the session."""
    name, _, rest = who.partition(" (")
    return who if name == "no certificate" else name


class DenialFilter:
    """Feed it Zenoh's log lines: denials go to ``report``, other lines to ``passthrough``.

    ``claim(since, timeout)`` names the peers of connections closed since a refusal was
    logged (:meth:`kinesphere.deploy.sockets.ClosedPeers.claim`); it runs on a thread of its
    own (``background``) so that Zenoh's log pipe never waits.
    """

    def __init__(
        self,
        report: Callable[[str], None],
        passthrough: Callable[[str], None],
        clock: Callable[[], float] = time.monotonic,
        claim: Callable[[float, float], list[str]] | None = None,
        background: bool = True,
    ) -> None:
        self.report = report
        self.passthrough = passthrough
        self._claim = claim
        self._background = background
        self._queue: queue.Queue[tuple[str, float]] = queue.Queue(MAX_QUEUED)
        self._worker: threading.Thread | None = None
        self._lock = threading.Lock()
        self._pending: Lru[str, str] = Lru(MAX_ENTRIES)
        """thread -> its last 'unauthorized' line, until Zenoh says the message was dropped"""
        self._repeats = RateLog(logging.getLogger(__name__), every=SUPPRESS_S,
                                max_keys=MAX_ENTRIES, clock=clock)
        """Counts repeats of one (subject, action, key) denial; only its allow() is used."""
        self._subjects: Lru[str, str] = Lru(MAX_ENTRIES)
        """zid -> ACL subject; Zenoh names the subject only when it first evaluates a key."""
        # only its allow() is used: it counts, report() writes
        self._budget = RateLog(logging.getLogger(__name__), every=WINDOW_S, burst=BURST,
                               max_keys=MAX_ENTRIES, clock=clock)
        self._total = RateLog(logging.getLogger(__name__), every=WINDOW_S, burst=TOTAL_BURST,
                              clock=clock)
        self.denials = 0
        self.refusals = 0

    @property
    def held(self) -> int:
        """Denials and refusals not reported one by one (over a budget)."""
        return self._budget.held + self._total.held

    def feed(self, raw: str) -> None:
        line = _ANSI.sub("", raw).rstrip("\n")
        m = _LINE.match(line)
        if m is not None and m["target"] == TLS_TARGET and m["level"] == "WARN":
            refused = _REFUSED.match(m["msg"])
            if refused and refused["reason"] not in NOT_REFUSALS:
                self._tls_refused(refused["reason"])
                return
        if m is None or not m["target"].startswith(INTERCEPTOR):
            if line.strip():
                self.passthrough(line)
            return
        if m["level"] != "TRACE":
            self.passthrough(line)
            return
        thread, msg = m["thread"], m["msg"]
        known = _SUBJECT.match(msg)
        if known:
            self._subjects.put(known["zid"], known["subject"])
        if " is unauthorized to " in msg:
            self._pending.put(thread, msg)
        elif " is authorized to " in msg:
            self._pending.pop(thread)
        elif msg.startswith("Msg intercepted"):
            self._denied(self._pending.pop(thread) or "")

    def _emit(self, identity: str, line: str) -> None:
        ok, held = self._budget.allow(identity)
        if not ok:
            return
        total_ok, total_held = self._total.allow("*")
        if not total_ok:
            return
        if held:
            line += f" (+{held} more denials of {identity} in {WINDOW_S:.0f} s)"
        if total_held:
            line += f" (+{total_held} more denials of anyone in {WINDOW_S:.0f} s)"
        self.report(line)

    def _denied(self, msg: str) -> None:
        self.denials += 1
        d = _DENIED.search(msg)
        if d is None:  # a session that matched no ACL subject: Zenoh does not say the key
            who, action, key = "a session without an ACL subject", "a message", "?"
            subject = who
        else:
            zid = d["zid"]
            subject = d["subject"] or self._subjects.peek(zid) or ""
            who = describe_subject(subject, zid) if subject else f"session {zid}"
            action, key = d["action"], d["key"]
        ok, suppressed = self._repeats.allow((subject, action, key))
        if not ok:
            return
        more = f" (+{suppressed} more)" if suppressed else ""
        self._emit(_identity(who), f"access denied: {action} on {key} by {who}{more}")

    def _tls_refused(self, reason: str) -> None:
        self.refusals += 1
        if self._claim is None:
            self._report_refusal(reason, [])
            return
        if not self._background:
            self._report_refusal(reason, self._claim(time.monotonic() - CLAIM_BEFORE_S, 0.0))
            return
        try:
            self._queue.put_nowait((reason, time.monotonic()))
        except queue.Full:
            self._budget.held += 1  # counted, not named: a flood of handshakes
            return
        with self._lock:
            if self._worker is None:
                self._worker = threading.Thread(target=self._lookups, daemon=True,
                                                name="router-refusals")
                self._worker.start()

    def _lookups(self) -> None:
        """Refusals in order, each naming the peers whose connections closed just after it
        was logged (Zenoh logs the warning, then drops the connection)."""
        assert self._claim is not None
        while True:
            reason, logged = self._queue.get()
            self._report_refusal(reason, self._claim(logged - CLAIM_BEFORE_S, PEER_WAIT_S))

    def _report_refusal(self, reason: str, peers: list[str]) -> None:
        where = ", ".join(peers) or "an unknown peer"
        host = peers[0].rsplit(":", 1)[0] if peers else "unknown"
        self._emit(f"host {host}", f"access denied: TLS handshake refused ({reason}) from "
                   f"{where}")
