"""The planar base: jerk-limited translations and drives, honest about how the base can move.

The MuJoCo base is three kinematic joints (world x, y, yaw) tracked by position servos, so
anything is possible in simulation; the controller restricts itself to what the real base
can do:

* ``omni`` (holonomic): Ruckig over world ``(x, y, yaw)``. A translation moves in a straight
  line by a displacement given in the body frame at command time; a Drive is Ruckig's
  velocity interface towards ``speed * max_speed`` along the direction. Per-axis limits are
  scaled by the direction's components, so speed, acceleration and jerk are bounded as
  vectors (a diagonal is not sqrt(2) faster).
* ``diff`` / ``skid`` (non-holonomic): Ruckig over ``(s, yaw)``, path length and heading,
  integrated as a unicycle. A translation turns towards the displacement (or away from it,
  driving backwards, when that is the shorter turn), then drives; a Drive maps the forward
  component to linear speed and the lateral one to a yaw rate (left turns left), which is
  what a tank or a two-wheeled robot does with a stick.

``stop`` brakes to rest with the same limits (the fastest jerk-limited stop). A new command
mid-motion starts from the current state, so the base never jumps in velocity.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np
from ruckig import (
    ControlInterface,
    InputParameter,
    OutputParameter,
    Result,
    Ruckig,
    Synchronization,
)

from kinesphere.robots.platform import BaseSpec

_FLOOR = 0.3
"""Smallest per-axis share of a limit. Ruckig needs positive limits on every DoF, and an axis
the motion does not use may still carry velocity from the previous one, which it must brake
in reasonable time; for axis-aligned motions this loosens the vector bound by at most 4 %."""
_WORKING = (Result.Working, Result.Finished)
log = logging.getLogger(__name__)


def update(otg: Ruckig, inp: InputParameter, out: OutputParameter) -> Result | None:
    """``otg.update``, None on failure (the binding raises ValueError on codes it lacks)."""
    try:
        result = otg.update(inp, out)
    except (ValueError, RuntimeError) as exc:
        log.debug("ruckig failed: %s", exc)
        return None
    return result if result in _WORKING else None


def wrap_angle(a: float) -> float:
    """``a`` in (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


class _Otg:
    """A Ruckig instance with its input/output, stepping online (output fed back as input)."""

    def __init__(self, n: int, dt: float, vmax: Sequence[float], amax: Sequence[float],
                 jmax: Sequence[float]) -> None:
        self.n = n
        self.otg = Ruckig(n, dt)
        self.inp = InputParameter(n)
        self.out = OutputParameter(n)
        self.vmax, self.amax, self.jmax = list(vmax), list(amax), list(jmax)
        inp = self.inp
        inp.current_position = [0.0] * n
        inp.current_velocity = [0.0] * n
        inp.current_acceleration = [0.0] * n
        inp.target_position = [0.0] * n
        inp.target_velocity = [0.0] * n
        inp.target_acceleration = [0.0] * n
        self.scale([1.0] * n)
        self.active = False
        self.position = np.zeros(n)
        self.velocity = np.zeros(n)
        self.acceleration = np.zeros(n)

    def scale(self, share: Sequence[float]) -> None:
        """Limits per axis = limit x share (a direction's components, floored)."""
        s = [max(abs(x), _FLOOR) for x in share]
        self.inp.max_velocity = [v * k for v, k in zip(self.vmax, s, strict=True)]
        self.inp.max_acceleration = [a * k for a, k in zip(self.amax, s, strict=True)]
        self.inp.max_jerk = [j * k for j, k in zip(self.jmax, s, strict=True)]

    def go_to(self, target: Sequence[float]) -> None:
        self.inp.control_interface = ControlInterface.Position
        self.inp.synchronization = Synchronization.Phase
        self.inp.target_position = list(target)
        self.active = True

    def go_at(self, velocity: Sequence[float]) -> None:
        self.inp.control_interface = ControlInterface.Velocity
        self.inp.synchronization = Synchronization.Phase
        self.inp.target_velocity = list(velocity)
        self.active = True

    def step(self) -> bool:
        """Advance one cycle; True when the motion just finished."""
        if not self.active:
            return False
        result = update(self.otg, self.inp, self.out)
        if result is None:  # scaled limits below the current state: use the full ones
            self.scale([1.0] * self.n)
            self.inp.synchronization = Synchronization.No
            result = update(self.otg, self.inp, self.out)
        if result is None:  # never seen; never let it take the control loop down either
            log.error("ruckig cannot plan the base from %s; holding", list(self.position))
            self.inp.current_velocity = [0.0] * self.n
            self.inp.current_acceleration = [0.0] * self.n
            self.go_to(list(self.position))
            self.active = False
            self.velocity[:] = 0.0
            self.acceleration[:] = 0.0
            return True
        out = self.out
        self.position[:] = out.new_position
        self.velocity[:] = out.new_velocity
        self.acceleration[:] = out.new_acceleration
        out.pass_to_input(self.inp)
        if result != Result.Finished:
            return False
        if self.inp.control_interface == ControlInterface.Velocity:
            if any(self.inp.target_velocity):
                return False  # cruising: Ruckig extrapolates at the reached velocity
            self.go_to(list(self.position))  # a stop came to rest: hold here
        self.active = False
        self.velocity[:] = 0.0
        self.acceleration[:] = 0.0
        return True


class BaseController:
    """Common face of the planar bases; ``pose`` is the commanded world ``[x, y, yaw]``."""

    def __init__(self, spec: BaseSpec, dt: float) -> None:
        self.spec = spec
        self.dt = dt
        self.pose = np.zeros(3)
        self.twist = np.zeros(3)  # world vx, vy, yaw rate
        self.driving = False

    @property
    def moving(self) -> bool:
        raise NotImplementedError

    def translate(self, displacement: Sequence[float], yaw: float | None = None) -> None:
        """Move by ``displacement`` ``[x, y(, z)]`` metres in the body frame at heading ``yaw``
        (the heading when the command arrived; now when None). ``z`` is ignored."""
        raise NotImplementedError

    def drive(self, direction: Sequence[float], speed: float) -> None:
        """Move continuously along body-frame ``direction`` at ``speed`` (0..1) of the maximum."""
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def step(self) -> None:
        raise NotImplementedError

    def yaw_limits(self) -> tuple[float, float]:
        """Yaw acceleration and jerk: the linear limits scaled by yaw rate / speed."""
        scale = self.spec.max_yaw_rate / max(self.spec.max_speed, 1e-9)
        return self.spec.max_acceleration * scale, self.spec.max_jerk * scale


class OmniBase(BaseController):
    """Holonomic base: Ruckig over world (x, y, yaw)."""

    def __init__(self, spec: BaseSpec, dt: float) -> None:
        super().__init__(spec, dt)
        yaw_acc, yaw_jerk = self.yaw_limits()
        self._otg = _Otg(
            3, dt, [spec.max_speed, spec.max_speed, spec.max_yaw_rate],
            [spec.max_acceleration, spec.max_acceleration, yaw_acc],
            [spec.max_jerk, spec.max_jerk, yaw_jerk],
        )

    @property
    def moving(self) -> bool:
        return self._otg.active

    def _world(self, body: Sequence[float], yaw: float | None = None) -> tuple[float, float]:
        yaw = float(self.pose[2]) if yaw is None else yaw
        c, s = math.cos(yaw), math.sin(yaw)
        return c * body[0] - s * body[1], s * body[0] + c * body[1]

    def _share(self, wx: float, wy: float) -> list[float]:
        norm = math.hypot(wx, wy)
        if norm < 1e-12:
            return [1.0, 1.0, 1.0]
        return [wx / norm, wy / norm, 1.0]

    def translate(self, displacement: Sequence[float], yaw: float | None = None) -> None:
        wx, wy = self._world(displacement, yaw)
        self.driving = False
        self._otg.scale(self._share(wx, wy))
        self._otg.go_to([self.pose[0] + wx, self.pose[1] + wy, self.pose[2]])

    def drive(self, direction: Sequence[float], speed: float) -> None:
        wx, wy = self._world(direction)
        norm = math.hypot(wx, wy)
        if norm < 1e-12 or speed <= 0.0:
            self.stop()
            return
        v = speed * self.spec.max_speed / norm
        self.driving = True
        self._otg.scale(self._share(wx, wy))
        self._otg.go_at([wx * v, wy * v, 0.0])

    def stop(self) -> None:
        self.driving = False
        if not self._otg.active:
            return
        vx, vy = self._otg.velocity[:2]
        self._otg.scale(self._share(vx, vy))
        self._otg.go_at([0.0, 0.0, 0.0])

    def step(self) -> None:
        self._otg.step()
        self.pose[:] = self._otg.position
        self.twist[:] = self._otg.velocity


class DiffBase(BaseController):
    """Non-holonomic base: Ruckig over (path length s, yaw), integrated as a unicycle."""

    def __init__(self, spec: BaseSpec, dt: float) -> None:
        super().__init__(spec, dt)
        yaw_acc, yaw_jerk = self.yaw_limits()
        self._otg = _Otg(
            2, dt, [spec.max_speed, spec.max_yaw_rate],
            [spec.max_acceleration, yaw_acc], [spec.max_jerk, yaw_jerk],
        )
        self._queue: list[tuple[float, float]] = []  # (s, yaw) waypoints still to reach

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

    def _next(self) -> None:
        s, yaw = self._queue.pop(0)
        self._otg.scale([1.0, 1.0])
        self._otg.go_to([s, yaw])

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

    def stop(self) -> None:
        self.driving = False
        self._queue.clear()
        if self._otg.active:
            self._otg.scale([1.0, 1.0])
            self._otg.go_at([0.0, 0.0])

    def step(self) -> None:
        s0, yaw0 = self._otg.position
        done = self._otg.step()
        s1, yaw1 = self._otg.position
        mid = 0.5 * (yaw0 + yaw1)
        ds = s1 - s0
        self.pose[0] += ds * math.cos(mid)
        self.pose[1] += ds * math.sin(mid)
        self.pose[2] = yaw1
        v, w = self._otg.velocity
        self.twist[:] = (v * math.cos(yaw1), v * math.sin(yaw1), w)
        if done and self._queue and not self._otg.active:
            self._next()


def make_base(spec: BaseSpec, dt: float) -> BaseController | None:
    """The controller for ``spec``'s kind; None for a fixed base."""
    if not spec.mobile:
        return None
    if spec.max_speed <= 0 or spec.max_acceleration <= 0 or spec.max_jerk <= 0:
        raise ValueError(f"mobile base {spec.kind!r} needs positive speed, acceleration, jerk")
    return OmniBase(spec, dt) if spec.holonomic else DiffBase(spec, dt)
