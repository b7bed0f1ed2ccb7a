"""Third-party robots for the bring-your-own-robot tests: the URDFs example-robot-data ships."""

from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path

import mujoco

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
