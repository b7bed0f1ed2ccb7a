"""The simulated body: a platform's MuJoCo model stepped in robot time (``--body mujoco``).

Position servos track the joint targets; the planar base is three kinematic joints (x, y, yaw)
whose servos track a target pose this body integrates from the commanded body-frame velocity,
with the mid-step heading (so a plan's own integration lands on the same pose). One
:meth:`MujocoBody.step` is ``dt`` of physics, in as many ``mj_step`` substeps as the model's
timestep needs.

Joint limits are hard stops, as on the real robot. MuJoCo's limit constraint is soft: when the
two arms of a Baxter press into each other, contact forces pushed joints up to 26 mrad past
their limits. So after every step a joint past its range is put back on the limit and its
velocity there is stopped, which is what a mechanical stop does.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from functools import partial

import mujoco
import numpy as np

from kinesphere.platforms.mjcf import BASE_JOINTS, PlatformModel, robot_contacts
from kinesphere.robots.agent.base import rotate, wrap_angle
from kinesphere.robots.agent.body import AT_REST, Body, Reading


class MujocoBody(Body):
    """A platform's MuJoCo model and data, ``dt`` of physics per step."""

    def __init__(self, pm: PlatformModel, dt: float) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"control period must be > 0 s, got {dt}")
        self.pm = pm
        self.platform = pm.platform
        self.dt = dt
        model = pm.model
        self.substeps = max(1, round(dt / model.opt.timestep))
        timestep = dt / self.substeps
        if abs(timestep - model.opt.timestep) > 1e-12:
            model = copy.copy(model)  # platform_model() is cached and shared: never mutate it
            model.opt.timestep = timestep
        self.model = model
        self.data = mujoco.MjData(model)
        template = pm.make_data()
        self.data.qpos[:] = template.qpos
        self.data.ctrl[:] = template.ctrl
        mujoco.mj_forward(model, self.data)
        self._qpos = self.data.qpos
        """A kept view (an MjData never moves its buffers): each ``data.qpos`` makes a new one,
        and :meth:`read` is at every state published."""
        names = self.platform.joint_names
        self._qadr = np.array([pm.qpos_index[j] for j in names], dtype=int)
        self._dadr = np.array([pm.dof_index[j] for j in names], dtype=int)
        self._act = np.array([pm.actuator_index[j] for j in names], dtype=int)
        self._act_slice = _as_slice(self._act)
        self._q_slice = _as_slice(self._qadr)  # a view when contiguous: no copy per step
        self._d_slice = _as_slice(self._dadr)
        self._read_q = _copier(self._qpos, self._q_slice)
        self._read_qd = _copier(self.data.qvel, self._d_slice)
        self._setpoints = (self.data.ctrl[self._act_slice]
                           if isinstance(self._act_slice, slice) else None)
        """The joints' servo targets as a view, kept (an MjData never moves its buffers), when
        the actuators are contiguous (else :meth:`command` assigns by index)."""
        self._span = slice(int(self._qadr.min()), int(self._qadr.max()) + 1) \
            if self._qadr.size else slice(0, 0)
        """The stretch of ``qpos`` holding the joints of P (``HardStops`` keeps a view)."""
        limits = [self.platform.eurdf.limits[j] for j in names]
        self._lower = np.array([lim.lower for lim in limits])
        self._upper = np.array([lim.upper for lim in limits])
        self._stops = list(zip(self._lower.tolist(), self._upper.tolist(), strict=True))
        self._mobile = self.platform.base.mobile
        if self._mobile:
            self._base_q = np.array([pm.qpos_index[j] for j in BASE_JOINTS], dtype=int)
            self._base_act = np.array([pm.actuator_index[j] for j in BASE_JOINTS], dtype=int)
            self._base_slice = _as_slice(self._base_act)
            self._base_target = [float(v) for v in self.data.qpos[self._base_q]]
            self.data.ctrl[self._base_slice] = self._base_target

    def read(self) -> Reading:
        pose = (0.0, 0.0, 0.0)
        if self._mobile:
            x, y, yaw = self._qpos[self._base_q].tolist()
            pose = (x, y, wrap_angle(yaw))
        return Reading(self._read_q(), self._read_qd(), pose)

    def command(self, q: np.ndarray, base_twist: Sequence[float] | np.ndarray) -> None:
        if self._setpoints is not None:
            self._setpoints[:] = q
        else:
            self.data.ctrl[self._act_slice] = q
        if self._mobile and base_twist is not AT_REST:
            vx, vy, w = base_twist.tolist() if isinstance(base_twist, np.ndarray) else base_twist
            if vx or vy or w:  # else the servos hold the target already written
                target = self._base_target
                dt = self.dt
                dyaw = float(w) * dt
                dx, dy = rotate(float(vx) * dt, float(vy) * dt, target[2] + 0.5 * dyaw)
                target[0] += dx
                target[1] += dy
                target[2] += dyaw
                self.data.ctrl[self._base_slice] = target

    def joint_setpoints(self) -> np.ndarray | None:
        """The joints' servo targets as a writable view of ``ctrl`` (what :meth:`command`
        writes for the joints: a fleet host copies a gliding robot's setpoint there itself),
        None when the actuators are not contiguous."""
        return self._setpoints

    def step(self) -> None:
        """The physics, then the hard stops."""
        self.simulate()
        self.hard_stop()

    def hard_stop(self) -> None:
        """This body's hard stops alone (a fleet host's :class:`HardStops` check all bodies
        at once)."""
        q = self.data.qpos[self._q_slice].tolist()  # plain floats: quicker than numpy here
        if any(v < lo or v > hi for v, (lo, hi) in zip(q, self._stops, strict=True)):
            self.stop_at_limits()

    def simulate(self) -> None:
        """The physics alone (MuJoCo releases the GIL in ``mj_step``: bodies step side by
        side); a fleet host then applies the hard stops of all its bodies at once
        (:class:`HardStops`)."""
        model, data = self.model, self.data
        for _ in range(self.substeps):
            mujoco.mj_step(model, data)

    def simulator(self) -> Callable[[], None]:
        """``mj_step`` itself bound to this body's model and data when one substep is the
        whole period (called from C: no Python frame per body and tick), else
        :meth:`simulate`."""
        if self.substeps == 1 and type(self).simulate is MujocoBody.simulate:
            return partial(mujoco.mj_step, self.model, self.data)
        return self.simulate

    def stop_at_limits(self) -> None:
        """The hard stops (module text): joints past a limit back on it, stopped there."""
        data = self.data
        q = data.qpos[self._qadr]
        past = (q < self._lower) | (q > self._upper)
        data.qpos[self._qadr[past]] = np.clip(q[past], self._lower[past], self._upper[past])
        data.qvel[self._dadr[past]] = 0.0

    def halt(self) -> None:
        data = self.data
        data.ctrl[self._act_slice] = data.qpos[self._qadr]
        if self._mobile:
            self._base_target = [float(v) for v in data.qpos[self._base_q]]
            data.ctrl[self._base_slice] = self._base_target

    def contacts(self) -> list[tuple[str, str]]:
        return robot_contacts(self.model, self.data)

    def touching(self) -> bool:
        return bool(self.data.ncon)  # robot geoms collide only with each other, never the floor


class HardStops:
    """The hard stops (module text) of many bodies at once, after a fleet host's physics: one
    comparison of all their joints against all their limits, and the stops of the bodies that
    went past one. Why: per body, the check costs a fifth of its ``mj_step``."""

    def __init__(self, bodies: Sequence[MujocoBody]) -> None:
        self.bodies = list(bodies)
        self._spans = [b.data.qpos[b._span] for b in self.bodies]
        """Views of the stretch of each body's ``qpos`` holding its joints (they stay valid:
        an MjData never moves its buffers)."""
        lower, upper = [], []
        for b, span in zip(self.bodies, self._spans, strict=True):
            lo, hi = np.full(span.size, -np.inf), np.full(span.size, np.inf)
            lo[b._qadr - b._span.start] = b._lower  # what lies between joints: no limit
            hi[b._qadr - b._span.start] = b._upper
            lower.append(lo)
            upper.append(hi)
        self._lower = np.concatenate(lower or [np.zeros(0)])
        self._upper = np.concatenate(upper or [np.zeros(0)])
        self._ends = np.cumsum([span.size for span in self._spans])

    def apply(self) -> None:
        """Joints past a limit back on it, stopped there."""
        if not self.bodies:
            return
        q = np.concatenate(self._spans)
        past = (q < self._lower) | (q > self._upper)
        if past.any():
            for i in np.unique(np.searchsorted(self._ends, past.nonzero()[0], side="right")):
                self.bodies[int(i)].stop_at_limits()


def _copier(values: np.ndarray, index: slice | np.ndarray) -> Callable[[], np.ndarray]:
    """A new copy of ``values[index]`` at each call, without a Python frame: a kept view's
    ``copy`` for a slice (``values`` is an MjData's, whose buffers never move), else ``take``."""
    if isinstance(index, slice):
        return values[index].copy
    return partial(values.take, index)


def _as_slice(index: np.ndarray) -> slice | np.ndarray:
    """A contiguous run of indices as a slice (a quicker numpy assignment), else the indices."""
    if index.size and (np.diff(index) == 1).all():
        return slice(int(index[0]), int(index[-1]) + 1)
    return index
