"""The bodies an agent can drive, by the name ``--body`` takes: a registry of factories.

Apart from :mod:`body` (the seam itself) so that the seam imports none of its implementations;
each factory imports its body only when chosen (no MuJoCo, no rmw_zenoh at import).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from kinesphere.errors import KinesphereError, choices
from kinesphere.robots.agent.body import Body

BodyFactory = Callable[..., Body]
"""Makes a body for a platform (a shipped name or a folder) stepped every ``dt`` seconds. The
agent also passes, by keyword, its ``session`` (Zenoh), ``options`` (AgentOptions) and
``robot_id``: a body that talks to hardware over the network uses them, a simulation not."""


def _mujoco(platform: str, dt: float, **_context: object) -> Body:
    from kinesphere.platforms.mjcf import platform_model
    from kinesphere.robots.agent.mujoco_body import MujocoBody  # MuJoCo loads only when chosen

    return MujocoBody(platform_model(platform, visuals=False), dt)


def _ros2(platform: str, dt: float, *, session: Any = None, options: Any = None,
          robot_id: str = "robot", **_context: object) -> Body:
    from kinesphere.platforms.platform import load_platform
    from kinesphere.robots.agent.options import AgentOptions
    from kinesphere.robots.agent.ros2_body import make_ros2_body  # rmw_zenoh only when chosen

    if session is None:
        raise KinesphereError("malformed", "the ros2 body needs the agent's Zenoh session")
    ros2 = (options if options is not None else AgentOptions()).ros2
    return make_ros2_body(load_platform(platform), dt, session, ros2, robot_id)


BODIES: dict[str, BodyFactory] = {"mujoco": _mujoco, "ros2": _ros2}
"""Bodies by the name ``--body`` takes (``options.BODY_KINDS``): the platform's MuJoCo model,
or a ros2_control robot over rmw_zenoh (``ros2_body.py``)."""


def make_body(kind: str, platform: str, dt: float, **context: Any) -> Body:
    """The body ``kind`` for ``platform``; an unknown kind is ``malformed`` naming the valid.
    ``context`` (``session``, ``options``, ``robot_id``) goes to the factory."""
    factory = BODIES.get(kind)
    if factory is None:
        raise KinesphereError("malformed", f"unknown body {kind!r}; valid: {choices(BODIES)}")
    return factory(platform, dt, **context)
