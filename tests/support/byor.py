"""Third-party robots for the bring-your-own-robot tests: the URDFs example-robot-data ships."""

from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path

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
