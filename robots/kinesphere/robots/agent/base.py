"""The planar base: jerk-limited translations and drives, honest about how the base can move.

The MuJoCo base is three kinematic joints (world x, y, yaw) tracked by position servos, so
anything is possible in simulation; the controller restricts itself to what the real base
can do:

* ``omni`` and ``legged`` (holonomic; a walk is abstracted so): Ruckig (``otg.py``) over
  world ``(x, y, yaw)``. A translation moves in
  a straight line by a displacement given in the body frame at command time; a Drive is Ruckig's
  velocity interface towards ``speed * max_speed`` along the direction. Per-axis limits are
  scaled by the direction's components, so speed, acceleration and jerk are bounded as
  vectors (a diagonal is not sqrt(2) faster).
* ``diff`` / ``skid`` (non-holonomic): Ruckig over ``(s, yaw)``, path length and heading,
  integrated as a unicycle. A translation turns towards the displacement (or away from it,
  driving backwards, when that is the shorter turn), then drives; a Drive maps the forward
  component to linear speed and the lateral one to a yaw rate (left turns left), which is
  what a tank or a two-wheeled robot does with a stick.

A continuous drive (``follow``: forward, left, yaw as fractions of the limits) is a body-frame
velocity and a turn rate: ``omni`` follows all three (its world-frame target velocity turns
with the base every step, so "forward while turning" is an arc), ``diff``/``skid`` follow
forward and yaw (arcade) and ignore ``left``.

``stop`` brakes to rest with the same limits (the fastest jerk-limited stop). A new command
mid-motion starts from the current state, so the base never jumps in velocity. What a body is
sent each step is :attr:`BaseController.body_twist`, the body-frame velocity that carries the
base along the planned pose over that step (what a real base's ``cmd_vel`` takes).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from ruckig import Synchronization

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.platform import BaseSpec
from kinesphere.protocol import Drive
from kinesphere.robots.agent.otg import Otg


def wrap_angle(a: float) -> float:
    """``a`` in (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


def yaw_limits(spec: BaseSpec) -> tuple[float, float]:
    """Yaw acceleration and jerk: the linear limits scaled by yaw rate / speed."""
    scale = spec.max_yaw_rate / max(spec.max_speed, 1e-9)
    return spec.max_acceleration * scale, spec.max_jerk * scale


def rotate(x: float, y: float, yaw: float) -> tuple[float, float]:
    """``(x, y)`` rotated by ``yaw`` (body to world; ``-yaw``: world to body)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return c * x - s * y, s * x + c * y


class BaseController:
    """Common face of the planar bases; ``pose`` is the commanded world ``[x, y, yaw]``."""

    def __init__(self, spec: BaseSpec, dt: float, otg: Otg) -> None:
        self.spec = spec
        self.dt = dt
        self._otg = otg
        self.pose = np.zeros(3)
        """Planned world ``[x, y, yaw]``."""
        self.twist = np.zeros(3)
        """Planned world ``[vx, vy, yaw rate]``."""
        self.body_twist = np.zeros(3)
        """Body-frame ``[vx, vy, yaw rate]`` that carried the base along the plan over the last
        step (integrated with the mid-step heading, it lands exactly on :attr:`pose`)."""
        self.driving = False

    @property
    def generator(self) -> Otg:
        """The Ruckig generator of the base (a fleet host's followers take its steps between
        plans, ``follow.py``; :meth:`step` then integrates what they did)."""
        return self._otg

    @property
    def moving(self) -> bool:
        return self._otg.active

    @property
    def stepping(self) -> bool:
        """Whether :meth:`step` has something to do: a motion, or the followers' last step
        of one."""
        return self._otg.came_to_rest or self.moving

    @property
    def followed(self) -> bool:
        """Whether the followers take the steps of the motion under way (or none is)."""
        return self._otg.following or not self.moving

    @property
    def fault(self) -> str:
        """Why the last motion was braked instead of followed ("" when it was not)."""
        return self._otg.fault

    @property
    def remaining(self) -> float:
        """Seconds until the planned motion arrives (0 at rest or cruising)."""
        return self._otg.remaining if self.moving and not self.driving else 0.0

    def turn_to(self, yaw: float, duration: float | None = None) -> None:
        """Turn in place to world heading ``yaw`` (the nearest way round), arriving no sooner
        than ``duration`` seconds from now; the same heading again changes nothing."""
        raise NotImplementedError

    def _heading(self, yaw: float, now: float) -> float:
        """``yaw`` as the equivalent heading nearest ``now`` (a planned yaw is not wrapped)."""
        return now + wrap_angle(yaw - now)

    def reset(self, pose: Sequence[float]) -> None:
        """Start planning from world ``pose`` ``[x, y, yaw]`` (where the body is), at rest."""
        raise NotImplementedError

    def translate(self, displacement: Sequence[float], yaw: float | None = None) -> None:
        """Move by ``displacement`` ``[x, y(, z)]`` metres in the body frame at heading ``yaw``
        (the heading when the command arrived; now when None). ``z`` is ignored."""
        raise NotImplementedError

    def drive(self, direction: Sequence[float], speed: float) -> None:
        """Move continuously along body-frame ``direction`` at ``speed`` (0..1) of the maximum."""
        raise NotImplementedError

    def follow(self, forward: float, left: float, yaw: float) -> None:
        """Move continuously at body-frame velocity ``(forward, left)`` x the maximum speed (a
        vector: a diagonal is no faster than straight), turning at ``yaw`` x the maximum yaw
        rate (positive: to the left); each in -1..1. A diff/skid base ignores ``left``."""
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def step(self) -> None:
        raise NotImplementedError


class OmniBase(BaseController):
    """Holonomic base: Ruckig over world (x, y, yaw)."""

    def __init__(self, spec: BaseSpec, dt: float) -> None:
        yaw_acc, yaw_jerk = yaw_limits(spec)
        super().__init__(spec, dt, Otg(
            3, dt, [spec.max_speed, spec.max_speed, spec.max_yaw_rate],
            [spec.max_acceleration, spec.max_acceleration, yaw_acc],
            [spec.max_jerk, spec.max_jerk, yaw_jerk],
        ))
        self._follow: tuple[float, float, float] | None = None
        """Body-frame (vx, vy, yaw rate) being followed; its world velocity turns with the base
        (set with :meth:`_track`)."""

    def reset(self, pose: Sequence[float]) -> None:
        self.pose[:] = pose
        self._track(None)
        self._otg.reset(pose)

    def _world(self, body: Sequence[float], yaw: float | None = None) -> tuple[float, float]:
        return rotate(float(body[0]), float(body[1]), float(self.pose[2]) if yaw is None else yaw)

    def _share(self, wx: float, wy: float) -> list[float]:
        norm = math.hypot(wx, wy)
        if norm < 1e-12:
            return [1.0, 1.0, 1.0]
        return [wx / norm, wy / norm, 1.0]

    def translate(self, displacement: Sequence[float], yaw: float | None = None) -> None:
        wx, wy = self._world(displacement, yaw)
        self.driving = False
        self._track(None)
        self._otg.scale(self._share(wx, wy))
        self._otg.go_to([self.pose[0] + wx, self.pose[1] + wy, self.pose[2]],
                        Synchronization.Phase)

    def turn_to(self, yaw: float, duration: float | None = None) -> None:
        goal = self._otg.target.copy() if self.moving and not self.driving else self.pose.copy()
        goal[2] = self._heading(yaw, float(self.pose[2]))
        if self.moving and not self.driving and np.allclose(goal, self._otg.target, atol=1e-9):
            return
        if not self.moving and abs(goal[2] - float(self.pose[2])) < 1e-9:
            return
        self.driving = False
        self._track(None)
        self._otg.scale([1.0, 1.0, 1.0])
        self._otg.go_to(goal, Synchronization.Phase, duration)

    def drive(self, direction: Sequence[float], speed: float) -> None:
        wx, wy = self._world(direction)
        norm = math.hypot(wx, wy)
        if norm < 1e-12 or speed <= 0.0:
            self.stop()
            return
        v = speed * self.spec.max_speed / norm
        self.driving = True
        self._track(None)
        self._otg.scale(self._share(wx, wy))
        self._otg.go_at([wx * v, wy * v, 0.0])

    def follow(self, forward: float, left: float, yaw: float) -> None:
        norm = math.hypot(forward, left)
        if norm > 1.0:
            forward, left = forward / norm, left / norm
        vmax = self.spec.max_speed
        follow = (forward * vmax, left * vmax, yaw * self.spec.max_yaw_rate)
        self._track(follow)
        if not any(follow):
            self.stop()
            return
        self.driving = True
        self._aim()

    def _track(self, follow: tuple[float, float, float] | None) -> None:
        """Follow ``follow`` from now on (None: nothing); while it turns, :meth:`step` aims
        again before every step, so no follower may take one."""
        self._follow = follow
        self._otg.followable = follow is None or not follow[2]

    def _aim(self) -> None:
        """Target the followed body-frame velocity in the world frame at today's heading."""
        assert self._follow is not None
        vx, vy, w = self._follow
        wx, wy = rotate(vx, vy, float(self.pose[2]))
        self._otg.scale(self._share(wx, wy))
        self._otg.go_at([wx, wy, w])

    def stop(self) -> None:
        self.driving = False
        self._track(None)
        if not self._otg.active:
            return
        vx, vy = self._otg.velocity[:2]
        self._otg.scale(self._share(vx, vy))
        self._otg.brake()

    def step(self) -> None:
        otg = self._otg
        if otg.active and self._follow is not None and self._follow[2]:
            self._aim()  # turning: the body-frame velocity points elsewhere in the world
        rested = otg.step()  # here, or the followers' (rested: it came to rest)
        if not (otg.active or rested):
            self.body_twist[:] = 0.0  # cheaper than asking whether it already is
            return
        x0, y0, yaw0 = self.pose.tolist()
        self.pose[:] = otg.position
        self.twist[:] = otg.velocity
        x1, y1, yaw1 = self.pose.tolist()
        vx, vy = rotate((x1 - x0) / self.dt, (y1 - y0) / self.dt, -0.5 * (yaw0 + yaw1))
        self.body_twist[:] = (vx, vy, (yaw1 - yaw0) / self.dt)


class DiffBase(BaseController):
    """Non-holonomic base: Ruckig over (path length s, yaw), integrated as a unicycle."""

    def __init__(self, spec: BaseSpec, dt: float) -> None:
        yaw_acc, yaw_jerk = yaw_limits(spec)
        super().__init__(spec, dt, Otg(
            2, dt, [spec.max_speed, spec.max_yaw_rate],
            [spec.max_acceleration, yaw_acc], [spec.max_jerk, yaw_jerk],
        ))
        self._queue: list[tuple[float, float]] = []  # (s, yaw) waypoints still to reach
        self._last = (0.0, 0.0)
        """(s, yaw) where the last step left the generator: what the next one starts from."""

    def reset(self, pose: Sequence[float]) -> None:
        self.pose[:] = pose
        self._queue.clear()
        self._otg.reset([0.0, float(pose[2])])
        self._last = (0.0, float(pose[2]))

    @property
    def moving(self) -> bool:
        return self._otg.active or bool(self._queue)

    def translate(self, displacement: Sequence[float], yaw: float | None = None) -> None:
        dx, dy = float(displacement[0]), float(displacement[1])
        dist = math.hypot(dx, dy)
        self.driving = False
        if dist < 1e-9:
            return
        s, now = self._otg.position
        yaw = float(now) if yaw is None else yaw
        heading = math.atan2(dy, dx)
        if abs(heading) > math.pi / 2 + 1e-9:  # backing up is the shorter turn
            heading = wrap_angle(heading - math.pi)
            dist = -dist
        turned = yaw + heading
        self._queue = [(s + dist, turned)]
        if abs(heading) > 1e-6:
            self._queue.insert(0, (s, turned))
        self._next()

    def _next(self, duration: float | None = None) -> None:
        s, yaw = self._queue.pop(0)
        self._otg.scale([1.0, 1.0])
        self._otg.go_to([s, yaw], Synchronization.Phase, duration)

    def turn_to(self, yaw: float, duration: float | None = None) -> None:
        s, now = self._otg.position
        if self.moving and not self.driving and not self._queue:
            s = float(self._otg.target[0])
        heading = self._heading(yaw, float(now))
        if self.moving and not self.driving and not self._queue and np.allclose(
                self._otg.target, [s, heading], atol=1e-9):
            return
        if not self.moving and abs(heading - float(now)) < 1e-9:
            return
        self.driving = False
        self._queue = [(float(s), heading)]
        self._next(duration)

    def drive(self, direction: Sequence[float], speed: float) -> None:
        fx, fy = float(direction[0]), float(direction[1])
        norm = math.hypot(fx, fy)
        self._queue.clear()
        if norm < 1e-12 or speed <= 0.0:
            self.stop()
            return
        self.driving = True
        self._otg.scale([fx / norm, fy / norm])
        self._otg.go_at([speed * self.spec.max_speed * fx / norm,
                         speed * self.spec.max_yaw_rate * fy / norm])

    def follow(self, forward: float, left: float, yaw: float) -> None:
        self._queue.clear()
        v, w = forward * self.spec.max_speed, yaw * self.spec.max_yaw_rate
        if not (v or w):
            self.stop()
            return
        self.driving = True
        self._otg.scale([1.0, 1.0])
        self._otg.go_at([v, w])

    def stop(self) -> None:
        self.driving = False
        self._queue.clear()
        if self._otg.active:
            self._otg.scale([1.0, 1.0])
            self._otg.brake()

    def step(self) -> None:
        otg = self._otg
        done = otg.step()  # here, or the followers' (done: it came to rest)
        if not (otg.active or done):
            self.body_twist[:] = 0.0  # cheaper than asking whether it already is
            return
        s0, yaw0 = self._last
        s1, yaw1 = otg.position.tolist()
        self._last = (s1, yaw1)
        mid = 0.5 * (yaw0 + yaw1)
        ds = s1 - s0
        x, y, _ = self.pose.tolist()  # plain floats: the same arithmetic, fewer numpy calls
        self.pose[:] = (x + ds * math.cos(mid), y + ds * math.sin(mid), yaw1)
        v, w = otg.velocity.tolist()
        self.twist[:] = (v * math.cos(yaw1), v * math.sin(yaw1), w)
        self.body_twist[:] = (ds / self.dt, 0.0, (yaw1 - yaw0) / self.dt)
        if done and self._queue and not self._otg.active and not self._otg.fault:
            self._next()


def make_base(spec: BaseSpec, dt: float) -> BaseController | None:
    """The controller for ``spec``'s kind; None for a fixed base."""
    if not spec.mobile:
        return None
    if spec.max_speed <= 0 or spec.max_acceleration <= 0 or spec.max_jerk <= 0:
        raise ValueError(f"mobile base {spec.kind!r} needs positive speed, acceleration, jerk")
    return OmniBase(spec, dt) if spec.holonomic else DiffBase(spec, dt)


def drive_base(base: BaseController | None, drive: Drive, platform: str) -> str:
    """Apply ``drive`` to ``base`` and say what it does (the status detail).

    The continuous form wins when any of its fields is non-zero; otherwise the version-1
    ``direction``/``speed`` (an empty direction: the base comes to rest). Raises
    ``malformed`` for a version-1 direction that is not a middle horizontal and
    ``cannot_translate`` for a fixed base.
    """
    if not drive.is_continuous and drive.direction:
        d = Direction.parse(drive.direction)
        if not d.is_translation:
            raise KinesphereError(
                "malformed", f"drive direction {d.slug!r} is not a middle horizontal; valid: "
                + ", ".join(t.slug for t in Direction.translations()))
    if base is None:
        raise KinesphereError("cannot_translate", f"{platform} has a fixed base")
    if drive.is_continuous:
        base.follow(drive.forward, drive.left, drive.yaw)
        ignored = ("" if base.spec.holonomic or not drive.left
                   else f" (left ignored: a {base.spec.kind} base cannot slide)")
        return (f"driving forward {drive.forward:+.2f} left {drive.left:+.2f} "
                f"yaw {drive.yaw:+.2f}{ignored}")
    if not drive.direction:
        base.stop()
        return "drive at rest"
    d = Direction.parse(drive.direction)
    base.drive(d.vector[:2], drive.speed)
    return f"driving {d.slug} at {drive.speed:.2f}"
