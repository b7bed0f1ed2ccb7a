"""A joint the solve holds still does not limit the limb being pulled, however narrow its range.

TIAGo's base carries +-5 mm suspension joints: mink's joint limits kept 1 cm from every limit
left those rows without a solution, so each step of each arm failed and the brought robot kept
2 of 26 directions per arm. The toy arm with its tail made such a joint must keep every
direction it keeps without it.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from kinesphere.services.ecl.generate import generate
from support.paths import TOY

TAIL = '<joint name="tail_joint" type="continuous">'
SUSPENSION = '<joint name="tail_joint" type="prismatic">'
ARM = ("limb_11", "distal_11")


def _suspended_toy(tmp_path: Path) -> Path:
    """The toy arm whose tail is a prismatic joint with a +-5 mm range (a suspension)."""
    folder = tmp_path / "toyarm"
    shutil.copytree(TOY, folder)
    eurdf = folder / "toyarm.eurdf"
    text = eurdf.read_text()
    assert text.count(TAIL) == 1
    text = text.replace(TAIL, SUSPENSION).replace(
        '<axis xyz="1 0 0"/><limit velocity="2" effort="1"/>',
        '<axis xyz="0 0 1"/><limit lower="-0.005" upper="0.005" velocity="2" effort="1"/>',
    )
    assert 'lower="-0.005"' in text
    eurdf.write_text(text)
    return folder


def test_a_narrow_joint_outside_the_limb_leaves_its_directions(tmp_path: Path) -> None:
    plain, _ = generate(str(TOY), only=ARM)
    suspended, report = generate(str(_suspended_toy(tmp_path)), only=ARM)
    kept = {(r.direction, r.size) for r in plain}
    assert len(kept) > 40  # the toy arm keeps most of its 26 directions at three sizes
    assert {(r.direction, r.size) for r in suspended} == kept
    assert report.entries[0].kept
