"""Third-party robots for the bring-your-own-robot tests: the URDFs example-robot-data ships."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco

if TYPE_CHECKING:
    import pytest

INSTALL = "pip install -c constraints.txt 'example-robot-data'  (or: make install)"


def robot_data() -> Path:
    """The folder of robots inside the installed example-robot-data package."""
    try:
        dist = distribution("example-robot-data")
    except PackageNotFoundError:
        raise AssertionError(f"example-robot-data is not installed: {INSTALL}") from None
    return Path(str(dist.locate_file("cmeel.prefix/share/example-robot-data/robots")))


def all_urdfs() -> list[Path]:
    found = sorted(robot_data().rglob("*.urdf"))
    assert len(found) > 60, f"example-robot-data ships fewer URDFs than expected: {INSTALL}"
    return found


PANDA = "panda_description/urdf/panda.urdf"
UR5 = "ur_description/urdf/ur5_robot.urdf"
TIAGO = "tiago_description/robots/tiago.urdf"
TALOS = "talos_data/robots/talos_reduced.urdf"


def _package_dir(dist: str, module: str, install: str) -> Path:
    try:
        distribution(dist)
    except PackageNotFoundError:
        raise AssertionError(f"{dist} is not installed: {install}") from None
    import importlib

    found = importlib.import_module(module).__file__
    assert found is not None
    return Path(found).parent


def pybullet_data() -> Path:
    """pybullet's own collection of URDFs (robots, objects, 1000 random objects)."""
    return _package_dir("pybullet", "pybullet_data", "pip install -c constraints.txt pybullet")


def rtb_data() -> Path:
    """The Robotics Toolbox's collection (industrial arms among its xacro sources)."""
    return _package_dir("rtb-data", "rtbdata", "pip install -c constraints.txt rtb-data")


def collections() -> dict[str, Path]:
    """The three public URDF collections the bring-your-own-robot sweep covers."""
    return {"erd": robot_data(), "pyb": pybullet_data(), "rtb": rtb_data()}


XARM6 = "xarm/xarm6_robot.urdf"  # pybullet_data
IIWA = "kuka_iiwa/model.urdf"
LAIKAGO_TOES = "laikago/laikago_toes.urdf"
LAIKAGO = "laikago/laikago.urdf"
MINI_CHEETAH = "mini_cheetah/mini_cheetah.urdf"
PENDULUM5 = "pendulum5.urdf"
RACECAR = "racecar/racecar.urdf"
MINITAUR = "quadruped/minitaur.urdf"
R2D2 = "r2d2.urdf"
HUMANOID = "humanoid/humanoid.urdf"
A1 = "a1/a1.urdf"
HUSKY = "husky/husky.urdf"


def standing(folder: Path) -> tuple[float, list[str]]:
    """A brought platform at its neutral pose and base height: the height of its lowest
    standing point above the floor, and the links within 3 mm of that point."""
    from kinesphere.platforms.mjcf import build_spec
    from kinesphere.platforms.platform import load_platform
    from kinesphere.platforms.stance import bearing_geoms, lowest

    plat = load_platform(str(folder))
    model = build_spec(plat).compile()
    data = mujoco.MjData(model)
    for joint, value in plat.eurdf.with_mimics(plat.neutral).items():
        data.qpos[model.jnt_qposadr[model.joint(joint).id]] = value
    mujoco.mj_kinematics(model, data)
    heights = {g: lowest(model, data, g) for g in bearing_geoms(model)}
    low = min(heights.values())
    feet = sorted({model.body(int(model.geom_bodyid[g])).name
                   for g, h in heights.items() if h < low + 0.003})
    return low, feet


def built_once(factory: pytest.TempPathFactory,
               wanted: Sequence[tuple[str, str, str]]) -> dict[str, Path]:
    """For each ``(name, urdf, limb)``, the folder ``platform new NAME --urdf URDF`` then
    ``ecl build --limb LIMB --jobs 1`` make, made once per test run and shared by the tests
    that need it (the collections' sample and the end-to-end test build TIAGo's and Talos's
    right arms: sharing them took the two files' run from 145 to 115 CPU-s).

    Under pytest-xdist the folders sit beside the workers' own temporary folders (in the
    run's), and a lock per folder makes one worker build it while another waits. A worker
    first builds those no other worker is building, so two that ask at once build different
    robots side by side; it waits only for what is left. A run without workers keeps them in
    its own temporary folder. Callers copy the folders or only read them."""
    run = factory.getbasetemp()
    shared = (run.parent if os.environ.get("PYTEST_XDIST_WORKER") else run) / "built-once"
    shared.mkdir(exist_ok=True)
    pending = list(wanted)
    while pending:
        for i, spec in enumerate(pending):  # one nobody is building, if any
            if _build_locked(shared, *spec, wait=False):
                del pending[i]
                break
        else:  # every one left is being built elsewhere: wait for the first
            _build_locked(shared, *pending.pop(0), wait=True)
    return {name: shared / name for name, _, _ in wanted}


def _build_locked(shared: Path, name: str, urdf: str, limb: str, wait: bool) -> bool:
    """Build ``name`` under its lock unless it is built; False if the lock is held elsewhere
    and ``wait`` is false."""
    from kinesphere.cli import main

    done = shared / f"{name}.done"
    with open(shared / f"{name}.lock", "w") as lock:
        try:  # released when the file closes
            fcntl.flock(lock, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            return False
        if not done.exists():
            assert main(["platform", "new", name, "--urdf", str(robot_data() / urdf),
                         "--dir", str(shared)]) == 0
            assert main(["ecl", "build", str(shared / name), "--limb", limb,
                         "--jobs", "1"]) == 0
            done.write_text(f"{urdf} {limb}\n")
    assert done.read_text() == f"{urdf} {limb}\n", (name, done.read_text())
    return True
