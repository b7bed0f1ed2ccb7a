"""``kinesphere up`` end to end, and the pieces of the system role that need no processes.

The two runs use one youBot and a short phrase: what is checked is the orchestration (exit
code, pictures, summary, no process left behind, Ctrl-C mid-phrase), not the robots.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from kinesphere.deploy.denials import DenialFilter, describe_subject
from kinesphere.deploy.plan import (
    default_phrases,
    parse_phrase,
    parse_robots,
    shipped_phrases_dir,
)
from kinesphere.deploy.up import SETTLED_QD
from kinesphere.errors import KinesphereError
from support.paths import ROOT
from support.system import SHIPPED_DBS, ctrl_c_reaches_it
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

PHRASE = (
    'name = "short"\n[[step]]\nduration = 1.5\nparts = ["limb_11 distal_11 left-high 2"]\n'
)


def _db_args() -> list[str]:
    if (SHIPPED_DBS / "youbot.sqlite").exists():
        return []
    dev = os.environ.get("KINESPHERE_TEST_DBS")
    if dev and (Path(dev) / "youbot.sqlite").exists():
        return ["--db", f"youbot={Path(dev) / 'youbot.sqlite'}"]
    pytest.fail(f"no youbot databank in {SHIPPED_DBS} (or $KINESPHERE_TEST_DBS): "
                "run `kinesphere ecl build --all` or restore it with git")


SIGINT_AT_FORK = """\
import os, signal
_nth = int(os.environ.pop("KINESPHERE_TEST_SIGINT_AT_FORK", "0"))
_forks = [0]
def _after_fork_in_parent() -> None:
    _forks[0] += 1
    if _forks[0] == _nth:
        os.kill(os.getpid(), signal.SIGINT)
if _nth:
    os.register_at_fork(after_in_parent=_after_fork_in_parent)
"""
"""A ``sitecustomize`` that makes ``up`` Ctrl-C itself in the fork hooks of its Nth child's
start, where Python's own handler raised KeyboardInterrupt into a hook that printed and dropped
it (a Ctrl-C at that moment was lost and ``up`` played on)."""


def _up(tmp_path: Path, *extra: str, seconds: float = 1.5,
        sigint_at_fork: int = 0) -> tuple[subprocess.Popen[bytes], Path]:
    phrase = tmp_path / "short.toml"
    phrase.write_text(PHRASE.replace("1.5", str(seconds)))
    out = tmp_path / "out"
    log = tmp_path / "up.log"
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), PYTHONFAULTHANDLER="1")
    if sigint_at_fork:
        hook = tmp_path / "hook"
        hook.mkdir()
        (hook / "sitecustomize.py").write_text(SIGINT_AT_FORK)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(hook), env.get("PYTHONPATH")]))
        env["KINESPHERE_TEST_SIGINT_AT_FORK"] = str(sigint_at_fork)
    with open(log, "wb") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "kinesphere.cli", "up", "--headless", "--robots", "youbot",
             "--phrase", str(phrase), "--out", str(out), *_db_args(), *extra],
            stdout=f, stderr=subprocess.STDOUT, cwd=ROOT, env=env,
            preexec_fn=ctrl_c_reaches_it,
        )
    return proc, log


def _endpoint(log: Path) -> str | None:
    m = re.search(r"hub (tcp/127\.0\.0\.1:\d+)", log.read_text(errors="replace"))
    return m[1] if m else None


def _processes_using(endpoint: str) -> list[int]:
    """PIDs whose command line mentions ``endpoint`` (every child is given it)."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                cmd = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ")
            except OSError:
                continue
            if endpoint.encode() in cmd:
                found.append(int(entry))
    return found


def test_up_runs_the_demo_and_leaves_nothing_behind(tmp_path: Path) -> None:
    proc, log = _up(tmp_path)
    code = proc.wait(timeout=180)
    text = log.read_text(errors="replace")
    assert code == 0, text
    endpoint = _endpoint(log)
    assert endpoint is not None, text
    assert _processes_using(endpoint) == []
    out = tmp_path / "out"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["endpoint"] == endpoint
    assert summary["robots"]["youbot"]["platform"] == "youbot"
    assert summary["robots"]["youbot"]["max_qd"] < SETTLED_QD, "the demo ends at rest"
    assert summary["robots"]["youbot"]["status"] == "holding"
    assert "robots at rest" in text
    assert summary["problems"] == {}
    for name in ("final_poses.png", "peak_poses.png", "trajectory_youbot.png"):
        assert (out / name).stat().st_size > 1000, name
    assert "all processes stopped" in text


def _exit_code(proc: subprocess.Popen[bytes], log: Path) -> int:
    """``up``'s exit code; a run that does not end within WAIT_S is aborted so that its log
    shows where every thread was (faulthandler), and the test fails with that log."""
    try:
        return proc.wait(timeout=WAIT_S)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        proc.wait(timeout=WAIT_S)
        pytest.fail(f"up did not end within {WAIT_S:g} s of Ctrl-C:\n"
                    f"{log.read_text(errors='replace')}")


def test_ctrl_c_mid_phrase_stops_everything(tmp_path: Path) -> None:
    proc, log = _up(tmp_path, "--keep-running", seconds=60)
    logs = tmp_path / "out" / "logs"
    endpoint = ""
    try:
        until(lambda: proc.poll() is None and any(logs.glob("play-*.log")), WAIT_S * 2,
              "the phrase to start")
        endpoint = _endpoint(log) or ""
        assert endpoint
        until(lambda: len(_processes_using(endpoint)) >= 3, WAIT_S, "databank, agent and play")
        proc.send_signal(signal.SIGINT)
        assert _exit_code(proc, log) == 130, log.read_text(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
    assert _processes_using(endpoint) == []
    assert "all processes stopped" in log.read_text(errors="replace")


@pytest.mark.parametrize("nth", [2, 4], ids=["databank", "play"])
def test_ctrl_c_while_a_child_starts_stops_everything(tmp_path: Path, nth: int) -> None:
    """Ctrl-C lands in the fork hooks of the Nth child's start (the router is the first, the
    play the fourth): it is not lost, every process stops and ``up`` exits 130."""
    proc, log = _up(tmp_path, "--keep-running", seconds=60, sigint_at_fork=nth)
    try:
        code = _exit_code(proc, log)
    finally:
        if proc.poll() is None:
            proc.kill()
    text = log.read_text(errors="replace")
    assert code == 130, text
    assert "Exception ignored" not in text
    endpoint = _endpoint(log)
    assert endpoint is not None, text
    assert _processes_using(endpoint) == []
    assert "all processes stopped" in text


# --- no processes -------------------------------------------------------------------------------


def test_robot_and_phrase_options() -> None:
    robots = parse_robots("baxter,nao,baxter,youbot:yb")
    assert [(r.platform, r.robot_id) for r in robots] == [
        ("baxter", "baxter"), ("nao", "nao"), ("baxter", "baxter-2"), ("youbot", "yb")]
    for bad in ("", "baxter:x,nao:x", "baxter:a/b", "nosuch"):
        with pytest.raises(KinesphereError):
            parse_robots(bad)
    assert [(r.platform, r.robot_id) for r in parse_robots("PackBot")] == [("packbot", "packbot")]
    with pytest.raises(KinesphereError, match=r"'packbto' \(did you mean 'packbot'\?\)"):
        parse_robots("packbto")
    shipped = shipped_phrases_dir()
    phrases = default_phrases(parse_robots("baxter,packbot"), shipped)
    assert [(p.path.name, p.target) for p in phrases] == [
        ("left_high.toml", "all"), ("packbot_sweep.toml", "packbot")]
    assert parse_phrase(f"{shipped / 'left_high.toml'}@nao").target == "nao"
    with pytest.raises(KinesphereError):
        parse_phrase(str(shipped / "nope.toml"))


ACL = "zenoh::net::routing::interceptor::access_control"
Z = "2d1d14328b9e10d7"


def _line(thread: str, msg: str, target: str = ACL) -> str:
    stamp = "\x1b[2m2026-01-01T00:00:00.000000Z\x1b[0m"
    return f"{stamp} \x1b[35mTRACE\x1b[0m {thread} {target}: {msg}"


def test_router_reports_each_denial_once_with_the_role() -> None:
    denials: list[str] = []
    other: list[str] = []
    now = [0.0]
    f = DenialFilter(report=denials.append, passthrough=other.append, clock=lambda: now[0])
    subject = f"Interface(lo)+CertCommonName(superuser)+Transport(Tls)+{Z}"
    rx = "rx-0 ThreadId(09)"
    # a key's permissions computed at declaration: not a denial
    f.feed(_line(rx, f"{Z} on {subject} is unauthorized to Put (ingress) on k/robot/a/command"))
    f.feed(_line(rx, f"{Z} on {subject} is authorized to Declare Subscriber (ingress) on k/x"))
    assert denials == []
    # a message dropped with the cached permission
    for _ in range(3):
        f.feed(_line(rx, f"Using cached result: {Z} is unauthorized to Put (ingress) on "
                         "k/robot/a/command"))
        f.feed(_line(rx, "Msg intercepted!", "zenoh::net::routing::interceptor"))
    assert denials == [
        f"access denied: Put (ingress) on k/robot/a/command by CN=superuser (interface=lo, "
        f"link=Tls, zid={Z})"]
    now[0] = 5.0
    f.feed(_line(rx, f"Using cached result: {Z} is unauthorized to Put (ingress) on "
                     "k/robot/a/command"))
    f.feed(_line(rx, "Msg intercepted!", "zenoh::net::routing::interceptor"))
    assert denials[-1].endswith("(+2 more)") and f.denials == 4
    f.feed("2026-01-01T00:00:00Z  WARN acc-0 ThreadId(05) zenoh_link_tls::unicast: no certs")
    assert other and "no certs" in other[-1]
    assert describe_subject("Transport(Tcp)+abc", "abc") == "no certificate (link=Tcp, zid=abc)"
