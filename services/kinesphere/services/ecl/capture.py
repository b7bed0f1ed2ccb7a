"""Capture a pose from a running robot: the super-user's "move it there, then record".

The paper's super-user records poses by moving the robot by hand. Here the robot is an agent on
Zenoh: we take one fresh ``RobotState`` of the named robot and keep the joints of the limb being
recorded. Only the core protocol is used, so the databank never imports the agent.
"""

from __future__ import annotations

import threading

import zenoh

from kinesphere import hints, zconfig
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.protocol import RobotState, decode


def capture_state(
    session: zenoh.Session, robot_id: str, keys: Keys, timeout: float, platform: str
) -> RobotState:
    """The next RobotState the robot publishes, or ``unavailable`` after ``timeout`` s (naming
    the command that starts a ``platform`` robot with that id)."""
    got: list[RobotState] = []
    ready = threading.Event()

    def on_state(sample: zenoh.Sample) -> None:
        if ready.is_set():
            return
        try:
            got.append(decode(sample.payload.to_bytes(), RobotState))
        except KinesphereError:
            return  # not a state we can read; wait for the next one
        ready.set()

    sub = session.declare_subscriber(keys.state(robot_id), on_state)
    try:
        if not ready.wait(timeout):
            raise KinesphereError(
                "unavailable",
                f"no state from robot {robot_id!r} on {keys.state(robot_id)} within "
                f"{timeout:g} s; is it running and reachable (--connect)? Start one with "
                f"'{hints.start_agent(platform, robot_id)}'",
            )
    finally:
        zconfig.undeclare(sub)
    return got[0]


def limb_joints_of(state: RobotState, joints: tuple[str, ...]) -> dict[str, float]:
    """The values of ``joints`` in ``state``; a joint the robot does not report is named."""
    values = dict(zip(state.joint_names, state.q, strict=True))
    missing = [j for j in joints if j not in values]
    if missing:
        raise KinesphereError(
            "malformed",
            f"robot {state.robot_id!r} ({state.platform}) does not report {', '.join(missing)}",
        )
    return {j: float(values[j]) for j in joints}
