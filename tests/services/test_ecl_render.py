"""Pictures of ECL poses: the contact sheet's layout and content, one pose, the comparison."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from kinesphere.cli import main
from kinesphere.laban import Direction
from kinesphere.platforms.platform import load_platform
from kinesphere.services.ecl import render
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.store import PoseRow, write_databank
from kinesphere.services.ecl.vsam import load_vsam

CELL, LABEL, TITLE = render.CELL, render.LABEL, render.TITLE


def cell(sheet: np.ndarray, level: int, column: int) -> np.ndarray:
    y, x = TITLE + level * (CELL + LABEL), column * CELL
    return sheet[y : y + CELL, x : x + CELL].astype(float)


def test_contact_sheet_shows_each_stored_direction_and_greys_the_rest() -> None:
    ecl = Ecl.open("youbot")
    image = render.contact_sheet(ecl, "limb_13", "distal_13", 3)
    assert image.size == (9 * CELL, 3 * (CELL + LABEL) + TITLE)
    sheet = np.asarray(image)
    have = {d.slug for d in ecl.directions("limb_13", "distal_13")}
    shown: list[tuple[str, np.ndarray]] = []
    missing: list[tuple[str, np.ndarray]] = []
    for r, level in enumerate(render.LEVELS):
        for c, h in enumerate(render.COLUMNS):
            d = Direction((h.value, level.value))
            (shown if d.slug in have else missing).append((d.slug, cell(sheet, r, c)))
    assert len(shown) == len(have) >= 4 and missing
    for slug, pixels in shown:
        assert pixels.std() > 20, f"{slug} looks blank"
    for slug, pixels in missing:
        assert abs(pixels.mean() - np.mean(render.MISSING)) < 10, f"{slug} should be grey"
    frames = [p for _, p in shown]
    for i, a in enumerate(frames):  # every pose looks different from every other
        for b in frames[i + 1 :]:
            assert np.abs(a - b).mean() > 0.5


def test_pose_and_compare_commands_write_pngs(tmp_path: Path) -> None:
    out = tmp_path / "pose.png"
    assert main(["pose", "youbot", "limb_11", "distal_11", "left-high", "3", "-o", str(out)]) == 0
    with Image.open(out) as img:
        assert img.size == (640, 480 + TITLE)
        assert np.asarray(img).std() > 20
    fig = tmp_path / "compare.png"
    args = ["ecl", "compare", "limb_11", "distal_11", "left-high", "3", "-o", str(fig),
            "--bodies", "youbot,khepera"]
    assert main(args) == 0
    with Image.open(fig) as img:
        assert img.size == (2 * 360, 360 + LABEL + TITLE)
        pixels = np.asarray(img).astype(float)
    robot, absent = pixels[TITLE : TITLE + 360, :360], pixels[TITLE : TITLE + 360, 360:]
    assert robot.std() > 20 and absent.std() < 15  # khepera has no arm: a grey n/a cell


def test_compare_finds_a_brought_body_in_a_platforms_folder(tmp_path: Path) -> None:
    """--platforms DIR finds a brought robot (youBot's description under the name mybot, its
    one pose in its own databank) and --bodies names it beside a shipped body: both drawn."""
    brought = tmp_path / "robots"
    shutil.copytree(load_platform("youbot").folder, brought / "mybot")
    toml = brought / "mybot" / "platform.toml"
    toml.write_text(toml.read_text().replace('name = "youbot"', 'name = "mybot"', 1))
    mybot = load_platform(str(brought / "mybot"))
    words = ("limb_11", "distal_11", "left-high", 3)
    pose = Ecl.open("youbot").query(*words)
    write_databank(brought / "mybot" / "mybot.sqlite", mybot, load_vsam(mybot),
                   [PoseRow(*words, dict(pose.joints))], "test")
    fig = tmp_path / "compare.png"
    command = ["ecl", "compare", *map(str, words), "-o", str(fig), "--bodies", "mybot,baxter"]

    def cells() -> tuple[np.ndarray, np.ndarray]:
        with Image.open(fig) as img:
            assert img.size == (2 * 360, 360 + LABEL + TITLE)
            pixels = np.asarray(img).astype(float)
        return pixels[TITLE : TITLE + 360, :360], pixels[TITLE : TITLE + 360, 360:]

    assert main([*command, "--platforms", str(brought)]) == 0
    found, baxter = cells()
    assert found.std() > 20 and baxter.std() > 20
    assert main(command) == 0  # without the folder, mybot is unknown: a grey n/a cell
    unknown, _ = cells()
    assert unknown.std() < 15


def test_render_refuses_an_unknown_limb(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["ecl", "render", "youbot", "--limb", "limb_99", "--origin", "distal_11",
            "-o", str(tmp_path / "x.png")]
    assert main(args) == 2
    assert "limb_99" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()
