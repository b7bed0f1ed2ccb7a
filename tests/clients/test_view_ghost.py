"""The view shows a robot's target as a translucent ghost while it moves, and hides it after.

A router, a databank and a Baxter agent run as processes on loopback (the command goes
through the router, see test_view_browser); the view runs in this process and
the test drives its frames, so it reads the scene's own handles: while Baxter reports moving
toward a commanded pose, the ghost is shown posed at the pose the databank answers for that
command (ahead of the body, which is still on its way), and it is hidden at rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from kinesphere.clients.view.app import FleetView
from kinesphere.procs import Supervisor
from kinesphere.protocol import Status
from kinesphere.zconfig import free_port
from support.network import KEYS
from support.system import Observer, at_pose, query_pose, router_hub
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

POSE = ("limb_11", "distal_11", "right-high", 3)
RID = "baxter-1"


@dataclass(frozen=True)
class ViewFrame:
    """One frame of the view: Baxter's reported status, the body's and the ghost's joints.

    ``around`` holds the statuses just before and just after the frame: the frame draws
    whichever state it found, and a new state may arrive meanwhile."""

    status: str
    ghost: bool
    body_q: np.ndarray
    ghost_q: np.ndarray | None
    around: tuple[str, str] = ("", "")



def test_the_target_ghost_shows_while_a_robot_moves(sup: Supervisor) -> None:
    endpoint = router_hub(sup)  # the hub: it routes every put
    sup.spawn("databank", ["databank", "serve", "--connect", endpoint, "--platform", "baxter"])
    obs = Observer(mode="peer", connect=[endpoint])
    view: FleetView | None = None
    try:
        obs.wait_alive(set(), databank=True, sup=sup)
        sup.spawn(RID, ["agent", "baxter", "--id", RID, "--connect", endpoint])
        obs.wait_alive({RID}, databank=True, sup=sup)
        view = FleetView(obs.session, KEYS, port=free_port())
        v = view

        def drawn() -> bool:
            v.frame()
            robot = v.fleet.snapshot().get(RID)
            return RID in v.drawings and robot is not None and robot.state is not None \
                and robot.state.status == Status.IDLE
        until(drawn, WAIT_S, "Baxter drawn, idle", every=1 / 30)
        drawing = view.drawings[RID]
        assert not drawing.ghost.root.visible, "no ghost before any command"

        target = query_pose(obs.session, "baxter", *POSE).joints
        sup.spawn("send", ["send", RID, *map(str, POSE), "--connect", endpoint, "--mode",
                           "client", "--wait", "20"], expect_exit=True)
        seen: list[ViewFrame] = []

        def frame_until_back_at_rest() -> bool:
            before = v.fleet.snapshot()[RID].state
            v.frame()
            robot = v.fleet.snapshot()[RID]
            assert before is not None and robot.state is not None
            ghost = drawing.ghost
            assert drawing.solid.q is not None
            seen.append(ViewFrame(robot.state.status, bool(ghost.root.visible),
                             drawing.solid.q.copy(), None if ghost.q is None else ghost.q.copy(),
                             (before.status, robot.state.status)))
            # at rest before the frame too: a state that arrives while a frame draws leaves
            # that frame drawn from the state before it
            return (at_pose(robot.state, target)
                    and Status.MOVING not in (before.status, robot.state.status))
        until(frame_until_back_at_rest, WAIT_S, "Baxter at the pose, at rest", every=1 / 30,
              explain=obs.describe)
        assert sup.wait("send", WAIT_S) == 0
    finally:
        if view is not None:
            view.close()
        obs.close()

    shown = [s for s in seen if s.ghost]
    print(f"\n{len(seen)} frames, the ghost in {len(shown)}, moving in "
          f"{sum(s.status == Status.MOVING for s in seen)}")
    assert shown, f"no ghost in {len(seen)} frames ({sorted({s.status for s in seen})})"
    assert all(Status.MOVING in s.around for s in shown), "a ghost only while moving"
    assert not seen[-1].ghost, "the ghost is hidden once the robot holds the pose"
    index = {n: i for i, n in enumerate(drawing.body.joint_names)}
    for s in shown:  # the ghost stands where the databank says the command ends
        assert s.ghost_q is not None
        assert all(abs(s.ghost_q[index[n]] - q) < 1e-9 for n, q in target.items())
    first = shown[0]
    assert max(abs(first.body_q[index[n]] - q) for n, q in target.items()) > 0.1, \
        "the ghost shows where the arm is going, ahead of where it is"
