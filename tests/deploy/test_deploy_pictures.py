"""``kinesphere up``'s pictures: real MuJoCo renders of shipped platforms laid out by
matplotlib, and joint trajectories."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image
import numpy as np

from kinesphere.deploy.pictures import TILE, pose_sheets, trajectory_png
from kinesphere.platforms.platform import load_platform
from kinesphere.protocol import RobotState


def _at_neutral(platform: str, robot_id: str, x: float = 0.0) -> RobotState:
    p = load_platform(platform)
    return RobotState(robot_id=robot_id, platform=platform, seq=1, stamp_ns=0,
                      joint_names=list(p.joint_names), q=[float(v) for v in p.neutral_vector()],
                      qd=[], base_pose=[x, 0.0, 0.0], status="idle", detail="at rest",
                      last_command_seq=0)


def test_pose_sheet_has_one_rendered_tile_per_robot_in_id_order(tmp_path: Path) -> None:
    path = tmp_path / "poses.png"
    states = {"yb": _at_neutral("youbot", "yb"), "bx": _at_neutral("baxter", "bx")}
    assert pose_sheets({path: states}) == [path]
    pixels = matplotlib.image.imread(path)[..., :3]
    assert pixels.shape[1] == 2 * TILE and pixels.shape[0] > TILE
    tiles = [pixels[:TILE, :TILE], pixels[:TILE, TILE:]]
    for tile in tiles:
        assert tile.std() > 0.05  # a robot, not a blank square
    assert np.abs(tiles[0] - tiles[1]).mean() > 0.01  # baxter first, then the youBot: different


def test_trajectory_is_drawn_at_the_asked_size_even_when_empty(tmp_path: Path) -> None:
    t = np.linspace(0.0, 4.0, 120)
    names = [f"j{i}" for i in range(14)]
    qs = [[np.sin(x * (i + 1)) if i < 12 else 0.0 for i in range(14)] for x in t]
    full = trajectory_png("r", names, list(t), qs, tmp_path / "t.png", width=800, height=400)
    empty = trajectory_png("r", names, [], [], tmp_path / "e.png", width=800, height=400)
    a, b = matplotlib.image.imread(full), matplotlib.image.imread(empty)
    assert a.shape[:2] == b.shape[:2] == (400, 800)
    assert np.abs(a[..., :3] - b[..., :3]).mean() > 0.01  # the lines are there
