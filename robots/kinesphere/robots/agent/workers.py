"""A fleet host on every core: its robots dealt to worker processes, each a fleet host of its own.

Why: a control loop is one thread, and the interpreter runs one thread at a time, so a fleet
host in one process uses one core however many the machine has. ``kinesphere fleet`` (and
``agent --robot``) therefore starts ``--workers N`` processes (default: one per core), each
running its share of the robots with its own loop, Zenoh session and physics, and watches them.
Every robot keeps what makes it a robot (keys, liveliness token, state stream, acks, lease,
watchdog, e-stop latch); the workers talk to nobody but Zenoh, as separate agents do.

A worker that dies takes its own robots, and their liveliness tokens, with it; the others run
on, and the parent names the robots that went and exits non-zero once stopped. Nothing restarts
a worker: a robot that comes back should be seen coming back, and it would have forgotten an
e-stop it had latched. SIGTERM or SIGINT to the parent stops every worker (the supervisor of
``kinesphere.procs``: each in its own session, SIGTERM then SIGKILL, none left behind; a
worker whose parent is killed is sent SIGTERM by the kernel).

The shares: the robots by platform, dealt in turn, so each worker holds a like mix (like bodies
follow their trajectories together, ``follow.py``, and the loads even out). A worker is the
parent's own command line plus ``--worker K/N:DIGEST``: it deals the robots again and refuses
to run when they are not the ones the parent dealt (the fleet file changed in between).
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
import signal
import threading
from collections.abc import Sequence
from typing import TYPE_CHECKING

from kinesphere.errors import KinesphereError
from kinesphere.procs import Supervisor

if TYPE_CHECKING:  # the command line reads default_workers for --help: no Zenoh, no MuJoCo
    from kinesphere.robots.agent.fleet import RobotSpec

log = logging.getLogger(__name__)

POLL_S = 0.2
"""How often the parent looks for workers that died."""
_WORKER = re.compile(r"(\d+)/(\d+):([0-9a-f]{12})")


def default_workers() -> int:
    """One worker per core."""
    return os.cpu_count() or 1


def deal(robots: Sequence[RobotSpec], workers: int) -> list[list[RobotSpec]]:
    """``robots`` in ``workers`` shares (module text); a share is never empty, so there are
    at most as many shares as robots."""
    n = max(1, min(workers, len(robots)))
    ordered = sorted(robots, key=lambda r: r.platform)  # stable: file order within a platform
    return [ordered[k::n] for k in range(n)]


def digest(robots: Sequence[RobotSpec]) -> str:
    """A short fingerprint of the robots a parent dealt (ids, platforms, groups, in order)."""
    text = "\n".join(f"{r.robot_id}\t{r.platform}\t{','.join(r.groups)}" for r in robots)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def worker_flag(k: int, n: int, robots: Sequence[RobotSpec]) -> str:
    """``--worker``'s value for share ``k`` (1-based) of ``n``."""
    return f"{k}/{n}:{digest(robots)}"


def share(robots: Sequence[RobotSpec], flag: str) -> tuple[int, int, list[RobotSpec]]:
    """The share ``--worker K/N:DIGEST`` names: (K, N, its robots)."""
    m = _WORKER.fullmatch(flag)
    if m is None or not 1 <= int(m[1]) <= int(m[2]):
        raise KinesphereError("malformed", f"--worker {flag!r}: expected K/N:DIGEST (a fleet "
                              "host starts its workers with it)")
    k, n = int(m[1]), int(m[2])
    if m[3] != digest(robots):
        raise KinesphereError("malformed", "the robots are not those the fleet host dealt to its "
                              "workers (was the fleet file edited meanwhile?); start it again")
    shares = deal(robots, n)
    if k > len(shares):
        raise KinesphereError("malformed", f"--worker {flag!r}: {len(robots)} robots make "
                              f"only {len(shares)} shares")
    return k, n, shares[k - 1]


def check_listen(listen: Sequence[str] | None, workers: int) -> None:
    """Workers cannot all listen on one fixed port: refuse ``--listen`` with a port unless
    there is one worker."""
    if workers < 2:
        return
    for endpoint in listen or ():
        port = endpoint.rsplit(":", 1)[-1].split("#", 1)[0]
        if port.isdigit() and int(port) != 0:
            raise KinesphereError(
                "malformed", f"--listen {endpoint}: {workers} workers cannot all listen on port "
                f"{port}; give port 0 (any free port, e.g. tcp/0.0.0.0:0), or --workers 1")


def run_workers(command_line: Sequence[str], robots: Sequence[RobotSpec], workers: int,
                stop: threading.Event) -> int:
    """Start one worker per share (``command_line`` with ``--worker``), watch them until
    ``stop`` is set or none is left, stop them. 0 when every worker ran until stopped, else 1."""
    shares = deal(robots, workers)
    n = len(shares)
    failed: dict[str, int] = {}
    with Supervisor(None) as sup:
        for k, robots_k in enumerate(shares, 1):
            child = sup.spawn(f"worker {k}/{n}",
                              [*command_line, "--worker", worker_flag(k, n, robots)])
            log.info("fleet host: worker %d/%d (pid %d): %s", k, n, child.pid,
                     ", ".join(r.robot_id for r in robots_k))
        while len(failed) < n and not stop.wait(POLL_S):
            for (name, child), robots_k in zip(sup.children.items(), shares, strict=True):
                code = child.proc.poll()
                if code is not None and name not in failed:
                    failed[name] = code
                    log.error("fleet host: %s exited with code %d; its robots are gone: %s "
                              "(the other workers run on)", name, code,
                              ", ".join(r.robot_id for r in robots_k))
        for name, code in sup.stop_all().items():
            if name not in failed and code not in (0, -signal.SIGTERM):
                failed[name] = code if code is not None else -1
                log.error("fleet host: %s stopped with code %s", name, code)
    if failed:
        log.error("fleet host: %d of %d workers failed", len(failed), n)
    return 1 if failed else 0
