"""The describe / platforms / label commands, run as a user runs them."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from kinesphere.cli import main
from support.paths import TOY_EURDF

pytestmark = pytest.mark.processes


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "kinesphere.cli", *args], capture_output=True, text=True, timeout=120
    )


def test_describe_json_gives_the_sets(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["describe", str(TOY_EURDF), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["dof"] == 4
    assert [lb["label"] for lb in info["L"]] == ["limb_11", "limb_12", "limb_21"]
    assert info["L"][1]["links"] == ["lower", "hand", "tip"]
    assert info["P"][3]["lower"] is None  # continuous joint


def test_describe_text_lists_limbs_with_links(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["describe", str(TOY_EURDF)]) == 0
    out = capsys.readouterr().out
    assert "L = {limb_11, limb_12, limb_21}" in out
    assert "links:  lower, hand, tip" in out


def test_unknown_platform_is_a_clear_error() -> None:
    proc = run("describe", "r2d2")
    assert proc.returncode == 2
    assert "unknown platform 'r2d2'" in proc.stderr and "baxter" in proc.stderr


def test_platform_names_are_any_case_and_misspellings_get_a_suggestion(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["describe", "PackBot", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["name"] == "packbot"
    assert main(["describe", "packbto"]) == 2
    assert "unknown platform 'packbto' (did you mean 'packbot'?)" in capsys.readouterr().err
    assert main(["ecl", "get", "baxter", "right_amr", "right_shoulder", "left-high", "3"]) == 2
    assert "no limb 'right_amr' in its ECL (did you mean 'right_arm'?)" in capsys.readouterr().err
    assert main(["ecl", "get", "baxter", "right_arm", "right_shoulde", "left-high", "3"]) == 2
    assert "(did you mean 'right_shoulder'?)" in capsys.readouterr().err
    assert main(["ecl", "get", "baxter", "right_arm", "right_shoulder", "left-hihg", "3"]) == 2
    assert "unknown direction 'left-hihg' (did you mean 'left-high'?)" in capsys.readouterr().err


def test_describe_all_json_is_one_document() -> None:
    proc = run("describe", "all", "--json")
    assert proc.returncode == 0, proc.stderr
    assert [p["name"] for p in json.loads(proc.stdout)] == [
        "baxter", "khepera", "nao", "packbot", "youbot"]


def test_a_reader_that_closes_the_pipe_gets_no_traceback() -> None:
    """``kinesphere describe all --json | head``: the reader is gone before the writer writes."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = subprocess.run([sys.executable, "-m", "kinesphere.cli", "describe", "all", "--json"],
                              stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert proc.returncode == 141 and proc.stderr == "", proc.stderr


def test_platforms_lists_all_five() -> None:
    proc = run("platforms", "--json")
    assert proc.returncode == 0, proc.stderr
    names = [row["name"] for row in json.loads(proc.stdout)]
    assert names == ["baxter", "khepera", "nao", "packbot", "youbot"]


def test_label_prints_a_loadable_eurdf(tmp_path: Path) -> None:
    out = tmp_path / "proposal.eurdf"
    assert main(["label", str(TOY_EURDF), "-o", str(out)]) == 0
    assert main(["describe", str(out)]) == 0


def test_help_explains() -> None:
    proc = run("describe", "--help")
    assert proc.returncode == 0
    assert "P (joint limits)" in " ".join(proc.stdout.split())
