"""``kinesphere router``: a Zenoh router from the Python package, no separate binary to ship.

Why a router at all: on several machines, every service connects to one router (as a client),
so all traffic crosses one place where TLS is terminated and access control is enforced.

Why the log plumbing: Zenoh 1.x reports an access-control denial only as two TRACE lines, a
refused TLS handshake as a warning without the peer, and its logger writes straight to file
descriptor 1. With access control on, the router enables those TRACE lines, routes fd 1
through a pipe and turns each real denial or refusal into one WARNING line ``access denied:
...`` (:mod:`kinesphere.deploy.denials`: rate limited per identity, in bounded memory),
dropping the allow chatter.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import IO

import zenoh

from kinesphere.deploy.acl import add_fleet, fleet_acl, load_fleet
from kinesphere.deploy.denials import INTERCEPTOR, DenialFilter
from kinesphere.deploy.sockets import ClosedPeers
from kinesphere.errors import KinesphereError
from kinesphere.signals import handle_signals
from kinesphere.zconfig import close_session, listen_where_told, open_session, session_config

log = logging.getLogger("kinesphere.router")


def _pump(read_fd: int, filt: DenialFilter) -> None:
    with os.fdopen(read_fd, "r", encoding="utf-8", errors="replace") as pipe:
        for line in pipe:
            try:
                filt.feed(line)
            except Exception:  # a log line must never take the router down
                log.exception("router log filter")


def capture_zenoh_log(out: IO[str], rust_log: str, ports: Sequence[int] = ()) -> DenialFilter:
    """Start Zenoh's logger on a pipe that a thread filters into ``log`` and ``out``.

    Python's own stdout moves to a duplicate of fd 1, so prints still reach the terminal.
    ``ports`` are the listen ports where refused TLS peers are looked up.
    """
    saved = os.dup(1)
    read_fd, write_fd = os.pipe()
    os.dup2(write_fd, 1)
    os.close(write_fd)
    sys.stdout = os.fdopen(saved, "w", buffering=1)

    def passthrough(line: str) -> None:
        print(line, file=out, flush=True)

    closed = ClosedPeers(ports)
    claim = closed.claim if closed.start() else None
    filt = DenialFilter(report=log.warning, passthrough=passthrough, claim=claim)
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
    says where to listen) with the fleet file's robots and operators admitted
    (:mod:`kinesphere.deploy.acl`), and how many it admits.

    ``links`` (other routers, over the file's ``connect/endpoints``) joins sites: a router
    keeps retrying a link that is down, so sites may start in any order.
    """
    if config_file is not None and not config_file.is_file():
        raise KinesphereError("malformed", f"router config {config_file}: no such file")
    config = session_config("router", listen=listen or None, connect=links or None,
                            config_file=config_file)
    listen_where_told(config)
    admitted = 0 if robots is None else add_fleet(config, load_fleet(robots))
    return config, admitted


def print_acl(robots: Path) -> int:
    """``--print-acl``: the generated per-robot and per-operator rules, subjects and policies."""
    print(json.dumps({"access_control": fleet_acl(load_fleet(robots))}, indent=2))
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
    endpoints = json.loads(config.get_json("listen/endpoints"))
    if not os.isatty(2 if log_denials else 1):  # a log file: plain text (Zenoh's own colours
        os.environ.setdefault("NO_COLOR", "1")  # are for terminals; NO_COLOR turns them off)
    filt: DenialFilter | None = None
    if log_denials:
        filt = capture_zenoh_log(sys.stderr, f"{base},{INTERCEPTOR}=trace",
                                 endpoint_ports(endpoints))
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
            log.info(
                "router %s up, listening on %s, access control %s%s, denials %s",
                session.zid(),
                endpoints,
                "on" if acl else "off",
                f" ({admitted} robots and operators admitted by name)" if admitted else "",
                "logged" if log_denials else "not logged",
            )
            while not stop.wait(0.5):
                pass
        finally:
            close_session(session)
            if filt is None:
                log.info("router stopped")
            else:
                log.info("router stopped; %d messages denied (%d not logged one by one), "
                         "%d TLS handshakes refused", filt.denials, filt.held, filt.refusals)
    return 0


def endpoint_ports(endpoints: object) -> list[int]:
    """The ports of listen endpoints like ``tls/0.0.0.0:7447`` (a list, or Zenoh's per-mode
    map); where refused TLS peers are looked up."""
    if isinstance(endpoints, dict):
        endpoints = endpoints.get("router", [])
    ports = []
    for ep in endpoints if isinstance(endpoints, list) else []:
        tail = str(ep).split("#", 1)[0].rsplit(":", 1)[-1]
        if tail.isdigit():
            ports.append(int(tail))
    return ports
