"""Bring your own robot, end to end, as a user does it: ``platform new`` from a third-party
URDF (example-robot-data) -> ``ecl build`` (one arm, so it fits CI) -> ``databank serve`` and
``agent`` processes finding the folder through ``--platforms`` -> ``send ... left-high 3`` over
real Zenoh, and the arm's tip ends up up-left of its shoulder (forward kinematics of the real
MuJoCo model at the joint values the agent reports)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import mujoco
import numpy as np
import pytest

from kinesphere import zconfig
from kinesphere.cli import main
from kinesphere.laban import Direction
from kinesphere.platforms.mjcf import platform_model
from kinesphere.platforms.platform import load_platform
from kinesphere.protocol import SpatialCommand
from support.agents import DatabankProcess, StateWatch, joints_close
from support.byor import PANDA, TALOS, TIAGO, UR5, built_once, robot_data
from support.network import Hub
from support.paths import ROOT
from support.wait import WAIT_S

pytestmark = pytest.mark.processes

# name: (URDF, limb, origin, direction, what the user edits in platform.toml's [neutral])
ROBOTS = {
    "panda": (PANDA, "arm", "shoulder", "left-high", ""),
    # the UR5's zero pose is a stretched, singular arm: bend it by hand, as docs/byor.md says
    "ur5": (UR5, "arm", "shoulder", "left-high",
            "shoulder_lift_joint = -1.2\nelbow_joint = 1.5\nwrist_1_joint = -1.5\n"),
    "tiago": (TIAGO, "right_arm", "right_shoulder", "left-high", ""),
    # Talos's right arm cannot reach left-high across its head without touching it (the
    # generator drops it honestly); its up-left pull that is kept is left-forward-high
    "talos": (TALOS, "right_arm", "right_shoulder", "left-forward-high", ""),
}


# Made and built by ``built_once`` (the same two commands, the build in one process), once per
# test run: tests/platforms/test_byor_collections.py builds the same arms of the same URDFs.
BUILT_ONCE = ("tiago", "talos")


@pytest.fixture(scope="module")
def brought(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One folder of platforms, each made and built once for every test of this module (two
    copied from the run's shared builds)."""
    root = tmp_path_factory.mktemp("platforms")
    for name, (urdf, limb, _, _, neutral) in ROBOTS.items():
        if name in BUILT_ONCE:
            continue
        keep = ["--neutral", "zero"] if neutral else []  # the hand-made one replaces it
        assert main(["platform", "new", name, "--urdf", str(robot_data() / urdf),
                     "--dir", str(root), *keep]) == 0
        if neutral:
            with open(root / name / "platform.toml", "a") as fh:
                fh.write(neutral)
        assert main(["ecl", "build", str(root / name), "--limb", limb]) == 0
    # the shared ones last: another worker building one of them meanwhile is not waited for
    built = built_once(tmp_path_factory, [(n, ROBOTS[n][0], ROBOTS[n][1]) for n in BUILT_ONCE])
    for name, folder in built.items():
        shutil.copytree(folder, root / name)
    return root


@pytest.fixture(scope="module")
def own_hub() -> Iterator[Hub]:
    """Not the shared hub: this module's databank serves the brought robots under the default
    prefix, where the shared databank (complete on ``{p}/ecl/*/**``) would call them unknown."""
    with zconfig.loopback_hub() as pair:
        yield Hub(*pair)


@pytest.fixture(scope="module")
def bank(brought: Path, own_hub: Hub) -> Iterator[DatabankProcess]:
    """One databank process serving the four brought robots, found by name via --platforms."""
    session, endpoint = own_hub
    args = ["--platforms", str(brought)]
    for name in ROBOTS:
        args += ["--platform", name]
    b = DatabankProcess(endpoint, session, args)
    b.start()
    yield b
    b.stop()


def test_a_new_folder_holds_a_describable_platform(
    brought: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for name in ROBOTS:
        folder = brought / name
        assert {p.name for p in folder.iterdir()} >= {
            f"{name}.eurdf", "platform.toml", "vsam.toml", "meshes", f"{name}.sqlite"}
        assert main(["--platforms", str(brought), "describe", name]) == 0
        assert main(["ecl", "report", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "torso_lift_joint" in out and "right_arm" in out
    assert out.count("ECL quality") == len(ROBOTS)


def test_platforms_are_found_on_the_search_path_only_when_given(brought: Path) -> None:
    assert main(["describe", "talos"]) == 2  # not shipped, not on the search path
    env = {**os.environ, "KINESPHERE_PLATFORMS": str(brought)}
    out = subprocess.run([sys.executable, "-m", "kinesphere.cli", "platforms"], env=env,
                         capture_output=True, text=True, timeout=120, check=True).stdout
    assert all(name in out for name in ROBOTS) and str(brought) in out


@pytest.mark.parametrize("name", list(ROBOTS))
def test_send_up_left_far_moves_the_tip_up_left_of_the_shoulder(
    name: str, brought: Path, bank: DatabankProcess, own_hub: Hub
) -> None:
    session, endpoint = own_hub
    _, limb, origin, direction, _ = ROBOTS[name]
    pull = np.array(Direction.parse(direction).vector, dtype=float)
    pull /= np.linalg.norm(pull)
    robot = f"{name}-1"
    watch = StateWatch(session, robot)
    log = (brought / f"{robot}.log").open("wb")
    agent = subprocess.Popen(
        [sys.executable, "-m", "kinesphere.cli", "agent", name, "--id", robot,
         "--platforms", str(brought), "--connect", endpoint,
         "--listen", zconfig.LOOPBACK_ANY_PORT],
        cwd=ROOT, env={**os.environ, "PYTHONUNBUFFERED": "1"}, stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        first = watch.wait(lambda s: True, f"the first state of {robot}", timeout=90)
        assert first.platform == name
        assert main(["send", robot, limb, origin, direction, "3",
                     "--connect", endpoint]) == 0
        pose = bank.query(name, SpatialCommand(limb, origin, direction, 3))
        assert pose.direction == direction and pose.joints
        done = watch.wait(lambda s: joints_close(s, pose.joints, 0.02),
                          f"{robot} at the {direction} far pose", timeout=90)
    finally:
        watch.close()
        agent.send_signal(signal.SIGTERM)
        agent.wait(timeout=WAIT_S)
        log.close()
    before = _tip_offset(brought / name, limb, origin, dict(zip(first.joint_names, first.q,
                                                              strict=True)))
    after = _tip_offset(brought / name, limb, origin, dict(zip(done.joint_names, done.q,
                                                             strict=True)))
    assert after[1] > 0.0 and after[2] > 0.0, after  # up and to the robot's left
    assert float(after @ pull) / float(np.linalg.norm(after)) > 0.8
    assert float((after - before) @ pull) > 0.05  # and it got there by moving


def _tip_offset(folder: Path, limb: str, origin: str, q: dict[str, float]) -> np.ndarray:
    """Tip minus origin joint anchor, in the body frame (a fixed base: the world frame)."""
    plat = load_platform(str(folder))
    pm = platform_model(str(folder))
    data = mujoco.MjData(pm.model)
    data.qpos[:] = pm.neutral_qpos()
    for joint, value in q.items():
        data.qpos[pm.qpos_index[joint]] = value
    mujoco.mj_forward(pm.model, data)
    e = plat.eurdf
    tip = data.xpos[pm.model.body(e.tip_link(limb)).id]
    anchor = data.xpos[pm.model.body(e.urdf.joint_map[e.origin_joint(origin)].child).id]
    return np.asarray(tip - anchor)
