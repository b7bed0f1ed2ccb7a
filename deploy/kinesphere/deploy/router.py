"""``kinesphere router``: a Zenoh router from the Python package, no separate binary to ship.

Why a router at all: on several machines, every service connects to one router (as a client),
so all traffic crosses one place where TLS is terminated and access control is enforced.

Why the log plumbing: Zenoh 1.x reports an access-control denial only as two TRACE lines
(``... is unauthorized to Put (ingress) on KEY`` then ``Msg intercepted!``), and its logger
writes straight to file descriptor 1. With access control on, the router enables those TRACE
lines, routes fd 1 through a pipe and turns each real denial into one WARNING line
``access denied: ...`` (rate limited per subject/action/key), dropping the allow chatter.
"""

from __future__ import annotations

import json
import logging
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import zenoh

from kinesphere.deploy.acl import add_robots, load_fleet, robot_acl
from kinesphere.errors import KinesphereError
from kinesphere.signals import handle_signals
from kinesphere.zconfig import close_session, listen_where_told, open_session, session_config

log = logging.getLogger("kinesphere.router")

INTERCEPTOR = "zenoh::net::routing::interceptor"
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
SUPPRESS_S = 1.0
"""Repeats of one (subject, action, key) denial within this window are counted, not logged."""


@dataclass
class DenialFilter:
    """Turns Zenoh's ACL trace lines into denial reports; passes other log lines through."""

    report: Callable[[str], None]
    passthrough: Callable[[str], None]
    clock: Callable[[], float] = time.monotonic
    _pending: dict[str, str] = field(default_factory=dict)
    _last: dict[tuple[str, str, str], tuple[float, int]] = field(default_factory=dict)
    _subjects: dict[str, str] = field(default_factory=dict)
    """zid -> ACL subject; Zenoh names the subject only when it first evaluates a key."""
    denials: int = 0

    def feed(self, raw: str) -> None:
        line = _ANSI.sub("", raw).rstrip("\n")
        m = _LINE.match(line)
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
            self._subjects[known["zid"]] = known["subject"]
        if " is unauthorized to " in msg:
            self._pending[thread] = msg
        elif " is authorized to " in msg:
            self._pending.pop(thread, None)
        elif msg.startswith("Msg intercepted"):
            self._denied(self._pending.pop(thread, ""))

    def _denied(self, msg: str) -> None:
        self.denials += 1
        d = _DENIED.search(msg)
        if d is None:  # a session that matched no ACL subject: Zenoh does not say the key
            who, action, key = "a session without an ACL subject", "a message", "?"
            subject = who
        else:
            zid = d["zid"]
            subject = d["subject"] or self._subjects.get(zid, "")
            who = describe_subject(subject, zid) if subject else f"session {zid}"
            action, key = d["action"], d["key"]
        ident = (subject, action, key)
        now = self.clock()
        last, suppressed = self._last.get(ident, (-1e18, 0))
        if now - last < SUPPRESS_S:
            self._last[ident] = (last, suppressed + 1)
            return
        more = f" (+{suppressed} more)" if suppressed else ""
        self._last[ident] = (now, 0)
        self.report(f"access denied: {action} on {key} by {who}{more}")


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


def _pump(read_fd: int, filt: DenialFilter) -> None:
    with os.fdopen(read_fd, "r", encoding="utf-8", errors="replace") as pipe:
        for line in pipe:
            try:
                filt.feed(line)
            except Exception:  # a log line must never take the router down
                log.exception("router log filter")


def capture_zenoh_log(out: IO[str], rust_log: str) -> DenialFilter:
    """Start Zenoh's logger on a pipe that a thread filters into ``log`` and ``out``.

    Python's own stdout moves to a duplicate of fd 1, so prints still reach the terminal.
    """
    saved = os.dup(1)
    read_fd, write_fd = os.pipe()
    os.dup2(write_fd, 1)
    os.close(write_fd)
    sys.stdout = os.fdopen(saved, "w", buffering=1)

    def passthrough(line: str) -> None:
        print(line, file=out, flush=True)

    filt = DenialFilter(report=log.warning, passthrough=passthrough)
    threading.Thread(target=_pump, args=(read_fd, filt), name="zenoh-log", daemon=True).start()
    os.environ["RUST_LOG"] = rust_log
    zenoh.init_log_from_env_or("info")
    return filt


def _acl_enabled(config: zenoh.Config) -> bool:
    try:
        return json.loads(config.get_json("access_control/enabled")) is True
    except (zenoh.ZError, ValueError):
        return False


def router_config(
    config_file: Path | None, listen: Sequence[str] | None, robots: Path | None = None,
    links: Sequence[str] | None = None,
) -> tuple[zenoh.Config, int]:
    """The router's config (the file, ``listen`` and ``links`` over it, loopback when neither
    says where to listen) with the fleet file's robots admitted (:mod:`kinesphere.deploy.acl`),
    and the robot count.

    ``links`` (other routers, over the file's ``connect/endpoints``) joins sites: a router
    keeps retrying a link that is down, so sites may start in any order.
    """
    if config_file is not None and not config_file.is_file():
        raise KinesphereError("malformed", f"router config {config_file}: no such file")
    config = session_config("router", listen=listen or None, connect=links or None,
                            config_file=config_file)
    listen_where_told(config)
    admitted = 0 if robots is None else add_robots(config, load_fleet(robots))
    return config, admitted


def print_acl(robots: Path) -> int:
    """``--print-acl``: the generated per-robot rules, subjects and policies as JSON."""
    print(json.dumps({"access_control": robot_acl(load_fleet(robots))}, indent=2))
    return 0


def run_router(
    config_file: Path | None,
    listen: Sequence[str] | None,
    *,
    robots: Path | None = None,
    links: Sequence[str] | None = None,
    log_denials: bool | None = None,
    stop: threading.Event | None = None,
) -> int:
    """Run a router until SIGINT/SIGTERM (or ``stop``); returns the exit code."""
    config, admitted = router_config(config_file, listen, robots, links)
    acl = _acl_enabled(config)
    if log_denials is None:
        log_denials = acl
    base = os.environ.get("RUST_LOG") or "info"
    if log_denials:
        capture_zenoh_log(sys.stderr, f"{base},{INTERCEPTOR}=trace")
    else:
        os.environ["RUST_LOG"] = base
        zenoh.init_log_from_env_or("info")
    stop = stop or threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        log.info("router: signal %d, shutting down", signum)
        stop.set()

    with handle_signals(on_signal, (signal.SIGINT, signal.SIGTERM)):
        session = open_session(config=config)
        try:
            endpoints = json.loads(config.get_json("listen/endpoints"))
            log.info(
                "router %s up, listening on %s, access control %s%s, denials %s",
                session.zid(),
                endpoints,
                "on" if acl else "off",
                f" ({admitted} robots admitted by id)" if admitted else "",
                "logged" if log_denials else "not logged",
            )
            while not stop.wait(0.5):
                pass
        finally:
            close_session(session)
            log.info("router stopped")
    return 0
