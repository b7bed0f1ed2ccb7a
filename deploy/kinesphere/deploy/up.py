"""``kinesphere up``: a whole local system from one command, the demo operators see first.

A ``kinesphere router`` child on a free loopback port is the hub and serves nothing else
(:mod:`kinesphere.deploy.hub`); the databank, one agent per robot, the ``kinesphere play``
processes and the supervisor's own session join it as Zenoh clients (multicast scouting off,
nobody else listens). So any of them can be killed -9 and the others keep talking: with the
databank dead, commands and e-stops still reach every robot. Every wait has a deadline and
names what did not happen; every exit path stops the children.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager

import msgspec
import numpy as np
from rich.console import Console
from rich.live import Live

from kinesphere.deploy.hub import client_args, start_hub
from kinesphere.deploy.plan import PlannedPhrase, UpOptions
from kinesphere.deploy.table import robot_table, state_dict, wide_console
from kinesphere.deploy.watch import Alive, StateRecorder, is_settled, watch_alive
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import DEFAULT_PREFIX, Keys
from kinesphere.procs import ChildFailed, Supervisor
from kinesphere.protocol import RobotState
from kinesphere.signals import handle_signals
from kinesphere.zconfig import close_session, undeclare

log = logging.getLogger(__name__)

SETTLE_TIMEOUT_S = 15.0
SETTLED_QD = 0.005
"""Joint speed (rad/s or m/s) under which ``up`` calls a robot at rest."""


def peak_states(recorder: StateRecorder) -> dict[str, RobotState]:
    """Each robot at the recorded moment farthest (in joint space) from where it started.

    The final pose of a phrase that returns to neutral says little; this shows the reach.
    """
    out: dict[str, RobotState] = {}
    with recorder.changed:
        for rid, t in recorder.tracks.items():
            if not t.qs:
                out[rid] = t.last
                continue
            q = np.asarray(t.qs)
            i = int(np.argmax(np.linalg.norm(q - q[0], axis=1)))
            out[rid] = msgspec.structs.replace(
                t.last, q=t.qs[i], qd=[], base_pose=t.bases[i], status="peak",
                detail=f"farthest from start, at {t.times[i]:.1f} s")
    return out


class _Stop(Exception):
    """SIGTERM/SIGHUP turned into an exception so every ``finally`` runs."""


class _Signals:
    """SIGINT, SIGTERM and SIGHUP noted by the handler and acted on where ``up`` looks
    (:meth:`check`: every poll of a wait, 0.2 s apart, and the end of each phase).

    A handler that raises (Python's own for Ctrl-C) raises wherever the main thread is: in
    the fork hooks that run while a child starts, which print the exception and drop it (the
    Ctrl-C was lost and ``up`` ran on), or between a lock's acquire and its ``try``, which
    leaves the lock held. A file being written is finished, not left half-written.
    """

    def __init__(self) -> None:
        self.signum: int | None = None

    def note(self, signum: int, _frame: object) -> None:
        if self.signum is None:  # the first one decides; the rest arrive while stopping
            self.signum = signum

    def check(self) -> None:
        """Raise KeyboardInterrupt for a noted Ctrl-C (exit 130), _Stop for the others."""
        if self.signum == signal.SIGINT:
            raise KeyboardInterrupt
        if self.signum is not None:
            raise _Stop(f"signal {self.signum}")

    @contextmanager
    def noted(self) -> Iterator[_Signals]:
        with handle_signals(self.note, (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)):
            yield self


class Demo:
    """One ``kinesphere up`` run: children, hub session, recorder, and what it writes."""

    def __init__(self, opts: UpOptions, console: Console | None = None) -> None:
        self.opts = opts
        self.keys = Keys(opts.prefix)
        self.console = console or wide_console()
        self.logs = opts.out / "logs"
        self.sup = Supervisor(self.logs)
        self.recorder = StateRecorder(self.keys)
        self.alive: Alive | None = None
        self.endpoint = ""
        self.timings: dict[str, float] = {}
        self._t0 = time.monotonic()
        self._live: Live | None = None
        self._stopped: list[int] | None = None
        self.signals = _Signals()

    # --- phases -----------------------------------------------------------------------------

    def _mark(self, what: str) -> None:
        self.timings[what] = round(time.monotonic() - self._t0, 2)
        self.console.log(f"{what} ({self.timings[what]:.1f} s)")

    def _table(self) -> object:
        a = self.alive
        return robot_table(
            self.recorder.snapshot(),
            alive=sorted(a.robots) if a else (),
            databanks=sorted(a.databanks) if a else (),
        )

    def _poll(self, cond: Callable[[], bool], timeout: float, what: str) -> None:
        """Wait for ``cond`` while checking children and refreshing the table."""
        deadline = time.monotonic() + timeout
        while not cond():
            self.signals.check()
            self.sup.check()
            if time.monotonic() > deadline:
                raise KinesphereError("unavailable", f"timed out after {timeout:.0f} s: {what}")
            self.recorder.wait_for(lambda _s: False, 0.2)
            if self._live is not None:
                self._live.update(self._table())  # type: ignore[arg-type]

    def start(self) -> None:
        o = self.opts
        shutil.rmtree(self.logs, ignore_errors=True)
        self.endpoint, session = start_hub(self.sup, o.start_timeout)
        self._session = session
        self.recorder.start(session)
        self.alive, self._subs = watch_alive(session, self.keys)
        self.console.log(f"hub {self.endpoint} (a router process, serving nothing else); "
                         f"logs in {self.logs}")
        zargs = client_args(self.endpoint)
        prefix = [] if o.prefix == DEFAULT_PREFIX else ["--prefix", o.prefix]
        dbs = [a for spec in o.databanks for a in ("--db", spec)]
        self.sup.spawn("databank",
                       ["databank", "serve", "--replica", "demo", *dbs, *zargs, *prefix])
        viewer = [] if o.headless or not os.environ.get("DISPLAY") else ["--viewer"]
        for r in o.robots:
            self.sup.spawn(
                f"agent-{r.robot_id}",
                ["agent", r.platform, "--id", r.robot_id, *zargs, *prefix, *viewer,
                 *o.extra_agent_args],
            )
        self._wait_started()

    def _wait_started(self) -> None:
        ids = {r.robot_id for r in self.opts.robots}
        alive = self.alive
        assert alive is not None

        def up() -> bool:
            return bool(alive.databanks) and ids <= alive.robots

        try:
            self._poll(up, self.opts.start_timeout, "liveliness of the databank and robots")
            self._poll(lambda: ids <= set(self.recorder.snapshot()), 15.0, "first robot states")
        except KinesphereError as exc:
            missing = [] if alive.databanks else ["databank"]
            missing += [f"agent-{r}" for r in sorted(ids - alive.robots)]
            tails = "\n".join(
                f"--- {name} ({self.sup.children[name].log_path}):\n"
                f"{self.sup.children[name].tail()}"
                for name in missing
            )
            raise KinesphereError(
                "unavailable", f"{exc.message}; not up: {', '.join(missing) or '?'}\n{tails}"
            ) from None
        self._mark(f"{len(ids)} robots and the databank are up")

    def play(self, phrase: PlannedPhrase, index: int) -> None:
        name = f"play-{index}-{phrase.path.stem}"
        args = ["play", str(phrase.path), "--target", phrase.target,
                *client_args(self.endpoint)]
        if self.opts.prefix != DEFAULT_PREFIX:
            args += ["--prefix", self.opts.prefix]
        child = self.sup.spawn(name, args, expect_exit=True)
        self.console.log(f"playing {phrase.path.name} on {phrase.target}")
        self._poll(lambda: not child.alive(), self.opts.phrase_timeout, f"{name} to finish")
        code = child.proc.returncode
        if code != 0:
            raise ChildFailed(f"{name} exited with code {code}:\n{child.tail()}")
        self._mark(f"played {phrase.path.name} on {phrase.target}")

    def settle(self) -> None:
        """Wait until every robot is at rest (a resting status, every joint slower than
        :data:`SETTLED_QD`), so the table, the pictures and the summary show where the
        phrases left them; name any robot still moving after :data:`SETTLE_TIMEOUT_S`."""
        ids = [r.robot_id for r in self.opts.robots]

        def moving() -> list[str]:
            s = self.recorder.snapshot()
            return [r for r in ids if r not in s or not is_settled(s[r], tol=SETTLED_QD)]

        try:
            self._poll(lambda: not moving(), SETTLE_TIMEOUT_S, "robots to come to rest")
            self._mark("robots at rest")
        except KinesphereError:
            self.console.log(f"[yellow]still moving after {SETTLE_TIMEOUT_S:g} s: "
                             f"{', '.join(moving())}; the pictures show them mid-motion")

    def pictures(self) -> dict[str, str]:
        from kinesphere.deploy.pictures import (  # matplotlib and MuJoCo rendering
            pose_sheets,
            trajectory_png,
        )

        out = self.opts.out
        states = self.recorder.snapshot()
        final, peak = out / "final_poses.png", out / "peak_poses.png"
        pose_sheets({final: states, peak: peak_states(self.recorder)})
        files = {"final_poses": str(final), "peak_poses": str(peak)}
        with self.recorder.changed:
            # the base's x and y ride along as two more series (the sweep drives while reaching)
            tracks = {rid: ([*t.last.joint_names, "base x", "base y"], list(t.times),
                            [[*q, b[0], b[1]] for q, b in zip(t.qs, t.bases, strict=True)])
                      for rid, t in self.recorder.tracks.items()}
        for rid, (names, times, qs) in tracks.items():
            files[f"trajectory_{rid}"] = str(
                trajectory_png(rid, names, times, qs, out / f"trajectory_{rid}.png"))
        summary = {
            "endpoint": self.endpoint,
            "timings_s": self.timings,
            "phrases": [{"file": str(p.path), "target": p.target} for p in self.opts.phrases],
            "robots": {rid: state_dict(st) for rid, st in sorted(states.items())},
            "problems": self.recorder.problems(),
            "files": files,
        }
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        self._mark(f"wrote {len(files)} pictures and summary.json to {out}")
        return files

    def shutdown(self) -> list[int]:
        """Stop children, then the hub; returns PIDs that survived (should be none).

        A second Ctrl-C meanwhile is only noted: cleaning up takes at most the grace period.
        """
        if self._stopped is not None:
            return self._stopped
        codes = self.sup.stop_all()
        undeclare(*getattr(self, "_subs", []))
        self.recorder.close()
        close_session(getattr(self, "_session", None))
        left = self._stopped = self.sup.leftovers()
        bad = {n: c for n, c in codes.items() if c not in (0, None) and not n.startswith("play")}
        if bad:
            self.console.log(f"[yellow]exit codes on shutdown: {bad}")
        self._mark("all processes stopped" if not left else f"[red]left behind: {left}")
        return left

    # --- the whole run ----------------------------------------------------------------------

    def run(self) -> int:
        o = self.opts
        o.out.mkdir(parents=True, exist_ok=True)
        left: list[int] = []
        with ExitStack() as stack:
            stack.enter_context(self.signals.noted())
            try:
                self.start()
                if not o.headless and self.console.is_terminal:
                    self._live = stack.enter_context(
                        Live(self._table(), console=self.console, refresh_per_second=4)  # type: ignore[arg-type]
                    )
                for i, phrase in enumerate(o.phrases, 1):
                    self.play(phrase, i)
                    if self._live is None:
                        self.console.print(self._table())
                self.settle()
                self.signals.check()
                if self._live is not None:
                    self._live.stop()
                    self._live = None
                self.console.print(self._table())
                if not o.keep_running:
                    self.shutdown()  # the states are recorded: render on a quiet machine
                self.pictures()
                self.signals.check()
                for rid, seen in self.recorder.problems().items():
                    for status, detail in seen.items():
                        self.console.log(f"[yellow]warning: {rid} reported {status}: {detail}")
                if o.keep_running:
                    self.console.log("running; Ctrl-C to stop")
                    self._poll(lambda: False, float("inf"), "Ctrl-C")
            except ChildFailed as exc:
                raise KinesphereError("unavailable", str(exc)) from None
            except _Stop as exc:
                self.console.log(f"stopping on {exc}")
            finally:
                if self._live is not None:
                    self._live.stop()
                left = self.shutdown()
        if left:
            raise KinesphereError("internal", f"processes left behind: {left}")
        self.console.log(f"done in {time.monotonic() - self._t0:.1f} s")
        return 0
