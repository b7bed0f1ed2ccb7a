"""Start kinesphere roles as separate processes and stop them without leaving orphans.

Every child is ``sys.executable -m kinesphere.cli ...`` in its own session (so a terminal's
Ctrl-C reaches only the supervisor, which then stops children in order) with stdout and
stderr in a log file, or the supervisor's own (``kinesphere up`` keeps logs, a fleet host's
workers write where it does). Stopping sends SIGTERM to the child's process group, waits a grace
period, then SIGKILLs the group; afterwards ``/proc`` is scanned for anything still in those
groups. On Linux each child also gets ``PR_SET_PDEATHSIG`` so it is told to stop even when the
supervisor itself is SIGKILLed.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

log = logging.getLogger(__name__)

GRACE_S = 5.0
PR_SET_PDEATHSIG = 1


def _pdeathsig() -> Callable[[], None] | None:
    """A preexec_fn asking Linux to SIGTERM the child when its parent dies (None elsewhere)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl  # resolved now, not in the child
    except (OSError, AttributeError):
        return None

    def preexec() -> None:
        prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM))  # a bare syscall: safe after fork

    return preexec


_PREEXEC = _pdeathsig()


class ChildFailed(RuntimeError):
    """A child exited when it should not have; the message carries its log tail."""


@dataclass
class Child:
    name: str
    argv: list[str]
    proc: subprocess.Popen[bytes]
    log_path: Path | None
    """None: the child writes to the supervisor's stdout and stderr."""
    log_file: IO[bytes] | None

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def tail(self, lines: int = 15) -> str:
        if self.log_path is None:
            return ""
        try:
            text = self.log_path.read_text(encoding="utf-8", errors="replace")
        except OSError:
            return ""
        return "\n".join(text.splitlines()[-lines:])


def kinesphere_argv(*args: str) -> list[str]:
    """The command line of a kinesphere sub-command run by this interpreter."""
    return [sys.executable, "-m", "kinesphere.cli", *args]


def group_members(pgids: set[int]) -> list[int]:
    """PIDs of live (non-zombie) processes whose process group is in ``pgids``, via /proc."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rfind(")") + 2 :].split()
        state, pgrp = fields[0], int(fields[2])
        if pgrp in pgids and state not in ("Z", "X"):
            found.append(int(entry))
    return found


class Supervisor:
    """Owns the child processes of one run; a context manager that always stops them."""

    def __init__(self, log_dir: Path | None, env: Mapping[str, str] | None = None) -> None:
        self.log_dir = log_dir
        """Where each child's log goes (``NAME.log``); None: the supervisor's own output."""
        self.env = dict(os.environ if env is None else env)
        self.env.setdefault("PYTHONUNBUFFERED", "1")
        self.children: dict[str, Child] = {}
        self.expected_exit: set[str] = set()
        self._groups: set[int] = set()

    def spawn(self, name: str, args: Sequence[str], *, expect_exit: bool = False) -> Child:
        """Start ``kinesphere ARGS`` as child ``name`` (a name is reused after it stopped)."""
        old = self.children.get(name)
        if old is not None and old.alive():
            raise ValueError(f"child {name!r} is already running")
        log_path: Path | None = None
        log_file: IO[bytes] | None = None
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            log_path = self.log_dir / f"{name}.log"
            log_file = open(log_path, "ab")  # closed in stop()
        argv = kinesphere_argv(*args)
        proc = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=log_file,
            stderr=None if log_file is None else subprocess.STDOUT,
            env=self.env,
            start_new_session=True,
            preexec_fn=_PREEXEC,  # only a prctl syscall, see _pdeathsig
        )
        child = Child(name, argv, proc, log_path, log_file)
        self.children[name] = child
        self._groups.add(proc.pid)
        if expect_exit:
            self.expected_exit.add(name)
        else:
            self.expected_exit.discard(name)
        log.debug("started %s (pid %d): %s", name, proc.pid, " ".join(args))
        return child

    def check(self) -> None:
        """Raise ChildFailed naming the first child that exited unexpectedly."""
        for child in self.children.values():
            code = child.proc.poll()
            if code is not None and child.name not in self.expected_exit:
                where = (f"; last lines of {child.log_path}:\n{child.tail()}"
                         if child.log_path is not None else "")
                raise ChildFailed(f"{child.name} exited with code {code}{where}")

    def wait(self, name: str, timeout: float) -> int:
        """Wait for an expected exit; raises subprocess.TimeoutExpired."""
        return self.children[name].proc.wait(timeout)

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        """Signal a child's whole group (tests use SIGKILL to simulate a crash). After SIGKILL
        the child is reaped before this returns, so its name can be spawned again at once
        (its sockets close, and its peers see it gone, a moment before it can be waited for)."""
        child = self.children[name]
        self.expected_exit.add(name)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(child.pid, sig)
        if sig == signal.SIGKILL:
            child.proc.wait(GRACE_S)

    def stop(self, name: str, grace: float = GRACE_S) -> int | None:
        """SIGTERM the child's group, SIGKILL it after ``grace`` s; returns the exit code."""
        child = self.children[name]
        self.expected_exit.add(name)
        if child.alive():
            with contextlib.suppress(ProcessLookupError):
                os.killpg(child.pid, signal.SIGTERM)
            try:
                child.proc.wait(grace)
            except subprocess.TimeoutExpired:
                log.warning("%s did not stop within %.1f s of SIGTERM: SIGKILL", name, grace)
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(child.pid, signal.SIGKILL)
                child.proc.wait(grace)
        # the leader is gone; anything it left in its group goes too
        for pid in group_members({child.pid}):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        if child.log_file is not None:
            child.log_file.close()
        return child.proc.returncode

    def stop_all(self, grace: float = GRACE_S) -> dict[str, int | None]:
        """Stop every child (all SIGTERMed at once, so the grace periods overlap)."""
        running = [c for c in self.children.values() if c.alive()]
        for child in running:
            self.expected_exit.add(child.name)
            with contextlib.suppress(ProcessLookupError):
                os.killpg(child.pid, signal.SIGTERM)
        deadline = time.monotonic() + grace
        for child in running:
            with contextlib.suppress(subprocess.TimeoutExpired):
                child.proc.wait(max(0.0, deadline - time.monotonic()))
        return {name: self.stop(name, grace) for name in list(self.children)}

    def leftovers(self) -> list[int]:
        """Processes still alive in any group this supervisor started (should be empty)."""
        return group_members(self._groups)

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_all()
