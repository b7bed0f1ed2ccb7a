"""The robot's body without the network: MuJoCo plus the trajectory generators.

One control step is: Ruckig update for the joints (and the base), the outputs written to the
position actuators' ``ctrl``, and ``mj_step``. It is single-threaded and knows nothing about
wall-clock time, so the runtime can pace it to real time while tests and benchmarks step it
as fast as they like.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable

import mujoco
import numpy as np

from kinesphere.robots.agent.base import BaseController, make_base, wrap_angle
from kinesphere.robots.agent.trajectory import DEFAULT_MARGIN, JointTrajectory
from kinesphere.robots.mjcf import BASE_JOINTS, PlatformModel, robot_contacts

BLOCKED_TOL = 0.05
"""rad (m): a joint this far from where its finished trajectory ended is blocked."""


class Controller:
    """A platform's MuJoCo model and data, driven at ``rate`` Hz by Ruckig outputs."""

    def __init__(self, pm: PlatformModel, rate: float = 500.0, margin: float = DEFAULT_MARGIN):
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"control rate must be > 0 Hz, got {rate}")
        self.pm = pm
        self.platform = pm.platform
        self.dt = 1.0 / rate
        model = pm.model
        self.substeps = max(1, round(self.dt / model.opt.timestep))
        timestep = self.dt / self.substeps
        if abs(timestep - model.opt.timestep) > 1e-12:
            model = copy.copy(model)  # platform_model() is cached and shared: never mutate it
            model.opt.timestep = timestep
        self.model = model
        self.data = mujoco.MjData(model)
        template = pm.make_data()
        self.data.qpos[:] = template.qpos
        self.data.ctrl[:] = template.ctrl
        mujoco.mj_forward(model, self.data)
        names = self.platform.joint_names
        self.joint_names = names
        self._qadr = np.array([pm.qpos_index[j] for j in names], dtype=int)
        self._dadr = np.array([pm.dof_index[j] for j in names], dtype=int)
        self._act = np.array([pm.actuator_index[j] for j in names], dtype=int)
        limits = [self.platform.eurdf.limits[j] for j in names]
        self.joints = JointTrajectory(
            limits,
            self.platform.max_acceleration,
            self.platform.max_jerk,
            self.dt,
            self.data.qpos[self._qadr],
            margin,
        )
        self.base: BaseController | None = make_base(self.platform.base, self.dt)
        if self.base is not None:
            self._base_q = np.array([pm.qpos_index[j] for j in BASE_JOINTS], dtype=int)
            self._base_act = np.array([pm.actuator_index[j] for j in BASE_JOINTS], dtype=int)
            self.base.pose[:] = self.data.qpos[self._base_q]
        self.time = 0.0
        self.steps = 0
        self.on_step: Callable[[Controller], None] | None = None
        """Called after every step (tests record the Ruckig outputs here)."""

    @property
    def moving(self) -> bool:
        """A trajectory, drive or stop is still being followed."""
        return self.joints.moving or (self.base is not None and self.base.moving)

    def step(self) -> None:
        """One control cycle: trajectories forward, ctrl set, physics forward."""
        joints = self.joints
        joints.step()
        ctrl = self.data.ctrl
        ctrl[self._act] = joints.position
        if self.base is not None:
            self.base.step()
            ctrl[self._base_act] = self.base.pose
        for _ in range(self.substeps):
            mujoco.mj_step(self.model, self.data)
        self.time += self.dt
        self.steps += 1
        if self.on_step is not None:
            self.on_step(self)

    def halt(self) -> None:
        """Brake joints and base to rest where they are (jerk-limited)."""
        self.joints.stop()
        if self.base is not None:
            self.base.stop()

    def q(self) -> list[float]:
        """Measured joint positions in P order."""
        return self.data.qpos[self._qadr].tolist()  # type: ignore[no-any-return]

    def qd(self) -> list[float]:
        return self.data.qvel[self._dadr].tolist()  # type: ignore[no-any-return]

    def base_pose(self) -> list[float]:
        """Measured ``[x, y, yaw]`` of the base, yaw in (-pi, pi] (zeros for a fixed base)."""
        if self.base is None:
            return [0.0, 0.0, 0.0]
        x, y, yaw = self.data.qpos[self._base_q].tolist()
        return [x, y, wrap_angle(yaw)]

    def commanded_base_yaw(self) -> float | None:
        return None if self.base is None else float(self.base.pose[2])

    def settle(self, max_steps: int = 100_000, extra: int = 0) -> int:
        """Step until nothing moves (then ``extra`` more steps); returns steps taken."""
        n = 0
        while self.moving and n < max_steps:
            self.step()
            n += 1
        for _ in range(extra):
            self.step()
        return n + extra

    def blocked(self, tol: float = BLOCKED_TOL) -> str:
        """Why the body is not where the trajectory ended, or "" when it is.

        The ECL checks its poses, not the joint-space path to them: an arm can catch on the
        other one on the way and stay there. Saying "at target" then would be a lie.
        """
        error = np.abs(np.asarray(self.q()) - self.joints.target)
        worst = int(np.argmax(error)) if error.size else 0
        if not error.size or error[worst] <= tol:
            return ""
        contacts = sorted({f"{a}/{b}" for a, b in robot_contacts(self.model, self.data)})
        touching = f"; self-contact {', '.join(contacts[:3])}" if contacts else ""
        return (f"blocked: {self.joint_names[worst]} is {error[worst]:.3f} from its target"
                f"{touching}")
