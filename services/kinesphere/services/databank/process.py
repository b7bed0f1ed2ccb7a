"""The databank process (``kinesphere databank serve``): open the databanks and a session, then
:func:`run` serves them with a :class:`~kinesphere.services.databank.service.DatabankService`
until a signal.

Headless: one log line when serving starts, one when it stops. SIGTERM and SIGINT stop it
cleanly (liveliness token and queryables undeclared, databanks let go, session closed) with
exit code 0, so process supervisors see a clean stop.
"""

from __future__ import annotations

import logging
import os
import re
import signal
import socket
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from types import FrameType

import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.platforms.platform import load_platform, platform_folders, platform_names
from kinesphere.services.databank.service import DatabankService
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.store import DATA_DIR
from kinesphere.signals import handle_signals
from kinesphere.zconfig import close_session

log = logging.getLogger("kinesphere.databank")


def shipped_platforms() -> list[str]:
    """Platforms with a databank of their own, sorted: shipped ones (package data) and those
    on the platform search path whose folder holds ``NAME.sqlite``."""
    shipped = {p.stem for p in DATA_DIR.glob("*.sqlite")}
    brought = {n for n, f in platform_folders().items() if (f / f"{n}.sqlite").is_file()}
    return sorted(shipped | brought)


def open_ecls(platforms: Sequence[str] = (), dbs: Sequence[str] = ()) -> dict[str, Ecl]:
    """Open each ``--db`` (``PATH`` or ``PLATFORM=PATH``) and each ``--platform`` not already
    given a databank that way (its shipped databank); every shipped databank when both are
    empty."""
    if not platforms and not dbs:
        platforms = shipped_platforms()
        if not platforms:
            raise KinesphereError(
                "unavailable",
                f"no shipped databanks in {DATA_DIR}: reinstall kinesphere-services, or "
                "serve a databank file with --db PLATFORM=PATH",
            )
    ecls: dict[str, Ecl] = {}
    for spec in dbs:
        ecl = _open_db(spec)
        name = ecl.platform.name
        if name in ecls and ecls[name].db_path != ecl.db_path:
            raise KinesphereError(
                "conflict", f"two databanks for {name}: {ecls[name].db_path} and {ecl.db_path}"
            )
        ecls[name] = ecl
    for platform in platforms:
        plat = load_platform(platform)
        if plat.name not in ecls:
            ecls[plat.name] = Ecl.open(plat)
    return ecls


def _open_db(spec: str) -> Ecl:
    platform, sep, path = spec.partition("=")
    if sep and not Path(spec).exists():
        return Ecl.open(platform, path)
    try:
        return Ecl.open(spec)
    except KinesphereError as exc:
        if exc.code != "unknown_platform":
            raise
        raise KinesphereError(
            exc.code, f"{spec}: {exc.message}; pair the databank with its platform folder: "
            f"--db FOLDER={spec}",
        ) from None


def default_replica_id() -> str:
    """``<host>-<pid>``, made a valid key segment."""
    text = f"{socket.gethostname()}-{os.getpid()}"
    return re.sub(r"[/*$?#\s]", "_", text).lstrip("@") or f"databank-{os.getpid()}"


def run(
    session: zenoh.Session,
    ecls: dict[str, Ecl],
    keys: Keys,
    replica: str,
    writes_enabled: bool = False,
    known_platforms: Iterable[str] = (),
) -> int:
    """Serve until SIGTERM/SIGINT, then close the service and the session; returns 0.

    ``known_platforms`` are known in addition to the shipped ones (see DatabankService).
    """
    stop = threading.Event()
    caught: list[str] = []

    def on_signal(signum: int, frame: FrameType | None) -> None:
        caught.append(signal.Signals(signum).name)
        stop.set()

    with handle_signals(on_signal, (signal.SIGTERM, signal.SIGINT)):
        started = time.monotonic()
        try:
            extra = list(known_platforms)
            known = [*platform_names(), *extra] if extra else None
            svc = DatabankService(session, ecls, keys, replica, writes_enabled,
                                  known_platforms=known)
            with svc:
                log.info(
                    "databank %s serving %s under %s/ (writes %s, zenoh id %s)",
                    replica,
                    ", ".join(f"{n} [{e.version}]" for n, e in sorted(ecls.items())),
                    keys.prefix,
                    "enabled" if writes_enabled else "disabled",
                    session.info.zid(),
                )
                stop.wait()
            log.info(
                "databank %s stopped on %s after %.1f s",
                replica,
                caught[0] if caught else "request",
                time.monotonic() - started,
            )
        finally:
            close_session(session)
    return 0
