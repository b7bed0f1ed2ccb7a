"""The describe / platforms / label commands, run as a user runs them."""

import json
import subprocess
import sys
from pathlib import Path

from kinesphere.cli import main

TOY = Path(__file__).parent / "data" / "toyarm" / "toyarm.eurdf"


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "kinesphere.cli", *args], capture_output=True, text=True, timeout=120
    )


def test_describe_json_gives_the_sets(capsys: object) -> None:
    assert main(["describe", str(TOY), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)  # type: ignore[attr-defined]
    assert info["dof"] == 4
    assert [lb["label"] for lb in info["L"]] == ["limb_11", "limb_12", "limb_21"]
    assert info["L"][1]["links"] == ["lower", "hand", "tip"]
    assert info["P"][3]["lower"] is None  # continuous joint


def test_describe_text_lists_limbs_with_links(capsys: object) -> None:
    assert main(["describe", str(TOY)]) == 0
    out = capsys.readouterr().out  # type: ignore[attr-defined]
    assert "L = {limb_11, limb_12, limb_21}" in out
    assert "links:  lower, hand, tip" in out


def test_unknown_platform_is_a_clear_error() -> None:
    proc = run("describe", "r2d2")
    assert proc.returncode == 2
    assert "unknown platform 'r2d2'" in proc.stderr and "baxter" in proc.stderr


def test_platforms_lists_all_five() -> None:
    proc = run("platforms", "--json")
    assert proc.returncode == 0, proc.stderr
    names = [row["name"] for row in json.loads(proc.stdout)]
    assert names == ["baxter", "khepera", "nao", "packbot", "youbot"]


def test_label_prints_a_loadable_eurdf(tmp_path: Path) -> None:
    out = tmp_path / "proposal.eurdf"
    assert main(["label", str(TOY), "-o", str(out)]) == 0
    assert main(["describe", str(out)]) == 0


def test_help_explains() -> None:
    proc = run("describe", "--help")
    assert proc.returncode == 0
    assert "P (joint limits)" in " ".join(proc.stdout.split())
