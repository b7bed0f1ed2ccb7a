"""The view's frame loop: the fleet as Zenoh reports it, drawn with viser at a fixed rate.

Each frame reads a snapshot of the fleet, adds a drawing for every new live robot whose body
has arrived, removes those whose liveliness went away, poses every body at its latest state
(only joints that moved are sent) and the ghost at its target while it moves, and refreshes
the captions. States arrive at 50 Hz or more per robot; the frame rate (30 Hz by default)
bounds what goes to the browsers whatever the size of the fleet. The side panel lists every
robot in words, a few times per second. The panel is Markdown, which viser renders with raw
HTML: every piece of text from the network (ids, names, statuses, details, a command's words)
goes in as literal text (:func:`literal`), so a name like ``<iframe srcdoc=...>`` shows as
written and runs nothing.
"""

from __future__ import annotations

import errno
import logging
import re
import socket
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import viser
import zenoh

from kinesphere.clients.options import ViewOptions
from kinesphere.clients.view.body import Array, BodyGeometry
from kinesphere.clients.view.fleet import Fleet, Robot
from kinesphere.clients.view.gate import Gate, guarding
from kinesphere.clients.view.resolve import Databank, part_key
from kinesphere.clients.view.scene import SPACING_M, Drawing
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.protocol import Pose, Status
from kinesphere.words import command_words, label_names

log = logging.getLogger(__name__)
PANEL_PERIOD_S: Final = 0.25
SILENT_S: Final = 1.0
"""A robot whose last state is older than this is marked silent."""


@dataclass
class FrameStats:
    """What the loop did, for the benchmark and the log."""

    frames: int = 0
    frames_sent: int = 0
    """Joint and base frames sent to the scene."""
    robot_updates: int = 0
    """Robots re-posed (a robot counts once per frame in which it moved)."""
    costs_s: list[float] = field(default_factory=list)

    def add(self, cost: float, sent: int, robots: int) -> None:
        self.frames += 1
        self.frames_sent += sent
        self.robot_updates += robots
        if len(self.costs_s) < 100_000:
            self.costs_s.append(cost)


_PUNCTUATION = re.compile(r"([!-%'-/:;=?@\[-`{-~])")
"""ASCII punctuation but ``& < >``, which become entities instead."""


def literal(text: str) -> str:
    """``text`` as literal Markdown: every ASCII punctuation mark backslash-escaped (no
    emphasis, link, image, autolink or heading), ``& < >`` as HTML entities (no tag or
    entity of the sender's), whitespace runs as one space (no block structure)."""
    text = _PUNCTUATION.sub(r"\\\1", " ".join(text.split()))
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def describe(robot: Robot, body: BodyGeometry | None) -> tuple[str, str]:
    """``(status line, command line)`` of a robot in words."""
    st = robot.state
    if st is None:
        return "waiting for its state", ""
    silent = time.monotonic() - robot.state_at > SILENT_S
    status = st.status
    if st.status == Status.ESTOP and st.estop_by:
        status += f" by {st.estop_by}"
    if silent:
        status = f"silent (last said: {status})"
    if st.lease_holder:
        status += f" · lease {st.lease_holder}"
    names = label_names(body.aliases) if body is not None else {}
    words = command_words(robot.command, names) if robot.command is not None else "no command"
    if robot.command is not None and robot.command.estop and st.status != Status.ESTOP:
        words = "E-STOP sent, but this robot reports no latch"  # what was sent is not what it did
    if robot.ack is not None and robot.command is not None and \
            robot.ack.seq == robot.command.seq and robot.ack.sender == robot.command.sender:
        words += f" [{robot.ack.stage}{' ' + robot.ack.code if robot.ack.code else ''}]"
    subs = ", ".join(f"{s.requested} → {s.served}" for s in st.substitutions)
    if subs:
        words += f" (served {subs})"
    return status, words


def _taken_message(host: str, port: int, extra: str = "") -> str:
    return (f"port {port} on {host} is in use{extra}: stop what holds it (another kinesphere "
            "view?) or serve on another with --port N; a bookmarked page keeps its port, so "
            "the view never moves to another by itself")


def _taken(host: str, port: int) -> str:
    """Why the view cannot serve on ``host:port`` ("" when it can): viser would quietly move
    to the next free port, and an operator's bookmarked page would show nothing."""
    if port == 0:
        return ""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except OSError as exc:
        return f"cannot serve on {host}:{port}: {exc.strerror or exc}"
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the web server does
        try:
            probe.bind(address)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                return _taken_message(host, port)
            return f"cannot serve on {host}:{port}: {exc.strerror or exc}"
    return ""


class FleetView:
    """A viser server showing every robot under ``keys.prefix`` seen on ``session``."""

    def __init__(self, session: zenoh.Session, keys: Keys, host: str = ViewOptions.host,
                 port: int = ViewOptions.port, fps: float = ViewOptions.fps,
                 allow_origins: Sequence[str] = ()) -> None:
        if not fps > 0:
            raise KinesphereError("malformed", f"--fps must be > 0, got {fps}")
        self.period = 1.0 / fps
        self.gate = Gate(host, allow_origins, f"viser-v{viser.__version__}")
        busy = _taken(host, port)
        if busy:
            raise KinesphereError("unavailable", busy)
        with guarding(self.gate):
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if port and self.server.get_port() != port:  # taken meanwhile: viser moved on
            got = self.server.get_port()
            self.server.stop()
            raise KinesphereError("unavailable", _taken_message(host, port, f" (the view "
                                  f"would have served on {got} instead)"))
        self.server.scene.set_up_direction("+z")
        self.server.gui.configure_theme(control_width="large", show_share_button=False)
        self.server.gui.main_panel.dock_right()  # beside the robots, never over them
        self.server.scene.add_grid("/floor", width=20.0, height=20.0, cell_size=0.5,
                                   plane="xy", position=(0.0, 0.0, 0.0))
        self._aim(self.server.initial_camera, 1)
        self.fleet = Fleet(session, keys)
        self.databank = Databank(session, keys)
        self.drawings: dict[str, Drawing] = {}
        self.stats = FrameStats()
        button = self.server.gui.add_button("Frame all robots")
        button.on_click(lambda _: self.frame_all())
        self._panel = self.server.gui.add_markdown("*waiting for robots...*")
        self._panel_text = ""
        self._panel_at = 0.0
        self._stop = threading.Event()

    @property
    def port(self) -> int:
        return self.server.get_port()

    # --- the loop ---------------------------------------------------------------------------

    def run(self, stop: threading.Event | None = None, duration: float | None = None) -> None:
        """Draw frames until :meth:`close`, ``stop`` is set, or ``duration`` seconds pass."""
        end = None if duration is None else time.monotonic() + duration
        next_at = time.monotonic()
        while not self._stop.is_set() and not (stop is not None and stop.is_set()):
            now = time.monotonic()
            if end is not None and now >= end:
                break
            if now < next_at:
                self._stop.wait(next_at - now)
                continue
            next_at = max(next_at + self.period, now)  # no burst to catch up after a stall
            self.frame()

    def frame(self) -> int:
        """Draw one frame; returns how many scene frames were sent."""
        t0 = time.perf_counter()
        robots = self.fleet.snapshot()
        sent = moved = 0
        with self.server.atomic():
            for rid in [r for r in self.drawings if r not in robots]:
                self.drawings.pop(rid).remove()
            for rid, robot in robots.items():
                drawing = self.drawings.get(rid) or self._draw(robot)
                if drawing is not None and robot.state is not None:
                    n = self._move(drawing, robot)
                    sent += n
                    moved += n > 0
        self._refresh_panel(robots)
        self.stats.add(time.perf_counter() - t0, sent, moved)
        return sent

    def _draw(self, robot: Robot) -> Drawing | None:
        """A new drawing once the robot's platform and body are known."""
        if robot.state is None:
            return None
        platform = robot.state.platform
        body = self.databank.bodies.get(platform)  # checked and built on the worker, once
        if body is None or isinstance(body, KinesphereError):
            return None
        used = {d.slot for d in self.drawings.values()}
        slot = next(i for i in range(len(used) + 1) if i not in used)
        drawing = self.drawings[robot.robot_id] = Drawing(self.server, robot.robot_id, body, slot)
        self._aim(self.server.initial_camera, self._row())  # for browsers that connect later
        log.info("drawing %s (%s) in slot %d", robot.robot_id, platform, slot)
        return drawing

    def _move(self, drawing: Drawing, robot: Robot) -> int:
        st = robot.state
        assert st is not None
        body = drawing.body
        try:
            q = body.q_from(st.joint_names, st.q)
        except ValueError:  # a state whose joints do not match: skip it, keep drawing
            return 0
        x, y, yaw = st.base_pose
        sent = drawing.move(q, (x, y, yaw))
        drawing.show_target(*self._target(robot, body, q))
        status, words = describe(robot, body)
        drawing.caption(f"{robot.robot_id}: {status}\n{words}")
        return sent

    def _target(self, robot: Robot, body: BodyGeometry, q: Array
                ) -> tuple[Array | None, tuple[float, float]]:
        """The ghost's joints and base displacement while the robot moves to a target."""
        st, motion = robot.state, robot.motion
        if st is None or motion is None or st.status != Status.MOVING:
            return None, (0.0, 0.0)
        pose = self.databank.poses.get((body.platform, part_key(motion.parts)))
        if not isinstance(pose, Pose):
            return None, (0.0, 0.0)
        target = q.copy()
        index = {n: i for i, n in enumerate(body.joint_names)}
        for name, value in pose.joints.items():
            if name in index:
                target[index[name]] = value
        shift = (0.0, 0.0) if pose.translation is None else \
            (pose.translation[0], pose.translation[1])
        return target, shift

    def _refresh_panel(self, robots: dict[str, Robot]) -> None:
        now = time.monotonic()
        if now - self._panel_at < PANEL_PERIOD_S:
            return
        self._panel_at = now
        lines = [f"**{len(robots)} robot(s)**", ""]
        for rid in sorted(robots):
            robot = robots[rid]
            drawing = self.drawings.get(rid)
            status, words = describe(robot, drawing.body if drawing else None)
            platform = robot.state.platform if robot.state else "?"
            drawn = "" if drawing else f" ({self._why_undrawn(platform)})"
            lines.append(f"- **{literal(rid)}** ({literal(platform)}){literal(drawn)}: "
                         f"{literal(status)}  \n  {literal(words)}")
            if robot.state is not None and robot.state.detail:
                lines.append(f"  \n  *{literal(robot.state.detail)}*")
        text = "\n".join(lines)
        if text != self._panel_text:
            self._panel.content = text
            self._panel_text = text

    def _why_undrawn(self, platform: str) -> str:
        got = self.databank.bodies.peek(platform)
        if isinstance(got, KinesphereError) and got.code == "invalid_eurdf":
            return got.message
        return "no body yet"

    def _row(self) -> int:
        return max((d.slot for d in self.drawings.values()), default=0) + 1

    @staticmethod
    def _aim(camera: Any, n: int) -> None:
        """Look at a row of ``n`` slots from the front (the robots face the viewer)."""
        mid = (n - 1) * SPACING_M / 2
        camera.position = (1.8 + 1.2 * n, mid, 1.6)
        camera.look_at = (0.0, mid, 0.6)

    def frame_all(self) -> None:
        """Point every connected browser's camera at the whole row of robots."""
        for client in self.server.get_clients().values():
            self._aim(client.camera, self._row())

    def close(self) -> None:
        self._stop.set()
        self.fleet.close()
        self.databank.close()
        self.server.stop()
