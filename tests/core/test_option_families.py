"""One option family per concept: every command spells, types and explains a shared option the
same way, and the defaults its help names are the ones it parses."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from kinesphere.cli import build_parser
from kinesphere.clients.options import ANSWER, SEND, TeleopOptions, TrafficOptions, ViewOptions
from kinesphere.deploy.plan import DEFAULT_ROBOTS
from kinesphere.robots.agent.options import AgentOptions
from kinesphere.services.options import QueryOptions

PARSER = build_parser()


Commands = list[tuple[str, argparse.ArgumentParser]]


def _commands(parser: argparse.ArgumentParser, path: str = "") -> Commands:
    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in dict(action.choices).items():
                here = f"{path} {name}".strip()
                out.append((here, sub))
                out += _commands(sub, here)
    return out


COMMANDS = _commands(PARSER)

FAMILIES: dict[str, tuple[str, ...]] = {
    # flag: the help's words every command that takes it starts with
    "--timeout": ("wait up to S seconds for ",),
    "--wait": ("wait up to S seconds for ",),
    "--json": ("print ",),
    "--output": ("the ",),
    "--target": ("robot id, group:NAME (agents run with --group) or 'all'",),
    "--ros2-domain": ("ROS domain id",),
    "--ros-distro": ("ROS 2 distribution of ",),
    "--duration": ("quit after S seconds", "stop after S seconds"),
    "--exact": ("this direction only: no substitution",),
    "--db": ("databank file to use instead of", "serve this databank file"),
    "--gesture": ("a score: only this gesture",),
    "--bodies": ("the platforms' bodies shown side by side",),
    "--platforms": ("a folder of platform folders",),
    "--rate": ("commands per second ",),
    "--control-rate": ("control and physics loop rate in Hz",),
}


def _takers(flag: str) -> list[tuple[str, argparse.Action]]:
    return [(name, p._option_string_actions[flag]) for name, p in COMMANDS
            if flag in p._option_string_actions]


@pytest.mark.parametrize("flag", sorted(FAMILIES))
def test_a_shared_option_reads_alike_in_every_command(flag: str) -> None:
    takers = _takers(flag)
    assert len(takers) >= 2, f"{flag} is no family: {takers}"
    # what a handler reads (dest, type, how many values, short form), alike everywhere
    shapes = {(a.dest, a.type, a.nargs, type(a).__name__, a.option_strings[0])
              for name, a in takers if not (flag == "--db" and name in ("up", "databank serve"))}
    assert len(shapes) == 1, f"{flag} is spelled or typed differently: {shapes}"
    for name, action in takers:
        assert action.help and action.help.startswith(FAMILIES[flag]), (name, action.help)


def test_every_seconds_option_says_s_and_its_default() -> None:
    for flag in ("--timeout", "--wait"):
        for name, action in _takers(flag):
            assert action.metavar == "S" and action.type is float, name
            assert f"(default {action.default:g})" in str(action.help), (name, action.help)


def test_the_help_names_the_default_each_command_parses() -> None:
    """A number in '(default N' is the value the option takes when it is not given."""
    checked = 0
    for name, parser in COMMANDS:
        for action in parser._actions:
            said = re.search(r"\(default:? (-?[0-9][0-9.]*)\b", str(action.help))
            if said is None or not isinstance(action.default, int | float):
                continue
            assert float(said[1]) == pytest.approx(action.default), (name, action.dest)
            checked += 1
    assert checked > 20


def _parse(*words: str) -> argparse.Namespace:
    return PARSER.parse_args(list(words))


def test_the_order_commands_wait_as_their_options_say() -> None:
    send = _parse("send", "all", "limb_11", "distal_11", "left-high", "3")
    assert (send.timeout, send.wait, send.rate) == (SEND.timeout_s, SEND.wait_s,
                                                    TeleopOptions.rate_hz)
    estop = _parse("estop")
    assert (estop.timeout, estop.wait, estop.target) == (ANSWER.timeout_s, ANSWER.wait_s, None)
    lease = _parse("lease", "take", "group:arms", "--timeout", "0.5")
    assert (lease.target, lease.timeout) == ("group:arms", 0.5)
    assert _parse("play", "left_high").target == "all"
    assert _parse("gamepad", "--target", "baxter-1").target == "baxter-1"


def test_the_databank_and_ecl_commands_share_their_families() -> None:
    query = _parse("query", "nao", "limb_11", "distal_11", "left-high", "3", "--exact")
    assert query.exact and query.timeout == QueryOptions.timeout_s
    record = _parse("ecl", "record", "nao", "--limb", "limb_11", "--origin", "distal_11",
                    "--direction", "left-high", "--size", "2", "--from-robot", "nao-1")
    assert record.timeout == QueryOptions.capture_timeout_s and record.db is None
    shown = _parse("ecl", "show", "nao", "--limb", "limb_11")
    assert (shown.limb, shown.origin, shown.direction) == ("limb_11", None, None)
    pose = _parse("pose", "nao", "limb_11", "distal_11", "left-high", "3", "-o", "p.png",
                  "--db", "x.sqlite")
    assert pose.output == Path("p.png") and pose.db == Path("x.sqlite")


@pytest.mark.parametrize("words", [("ecl", "render", "nao", "--limb", "limb_11", "--origin",
                                    "distal_11"),
                                   ("ecl", "export", "nao"),
                                   ("record",)])
def test_an_output_a_command_cannot_do_without_is_required(
    words: tuple[str, ...], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        _parse(*words)
    assert exit_.value.code == 2 and "-o/--output" in capsys.readouterr().err


def test_an_output_with_a_default_may_be_left_out() -> None:
    assert _parse("label", "robot.urdf").output is None
    assert _parse("film", "left_high").output is None
    assert _parse("label", "robot.urdf", "-o", "x.urdf").output == Path("x.urdf")


def test_a_list_of_bodies_is_a_list_wherever_it_is_taken() -> None:
    assert _parse("film", "left_high").bodies == list(DEFAULT_ROBOTS)
    assert _parse("film", "left_high", "--bodies", "nao, ,youbot").bodies == ["nao", "youbot"]
    assert _parse("ecl", "coverage", "--bodies", "baxter,nao").bodies == ["baxter", "nao"]
    assert _parse("ecl", "coverage").bodies is None  # every platform found


def test_every_command_finds_platform_folders_with_platforms() -> None:
    """--platforms is one thing: the folders platforms are found in, on every command (the
    commands showing bodies side by side name them with --bodies)."""
    for name, parser in COMMANDS:
        action = parser._option_string_actions.get("--platforms")
        assert action is not None and action.dest == "platform_dirs", name
    assert _parse("describe", "nao", "--platforms", "/tmp/p").platform_dirs == ["/tmp/p"]
    both = _parse("ecl", "compare", "limb_11", "distal_11", "left-high", "3", "-o", "x.png",
                  "--platforms", "/tmp/p", "--bodies", "mybot,baxter")
    assert (both.platform_dirs, both.bodies) == (["/tmp/p"], ["mybot", "baxter"])


def test_a_rate_is_commands_per_second_and_the_agents_loop_is_its_control_rate() -> None:
    """--rate is one thing (a client's commands per second); the agent's and the fleet host's
    control and physics loop is --control-rate, beside --state-rate."""
    loops = {name for name, p in COMMANDS if "--control-rate" in p._option_string_actions}
    assert loops == {"agent", "fleet"}
    streams = {name for name, p in COMMANDS if "--rate" in p._option_string_actions}
    assert streams >= {"send", "play", "gamepad"} and not streams & loops
    agent = _parse("agent", "nao", "--control-rate", "250", "--state-rate", "25")
    assert (agent.control_rate, agent.state_rate) == (250.0, 25.0)
    assert _parse("fleet", "f.toml").control_rate == AgentOptions.control_rate


def test_a_ros_domain_is_one_option_and_the_bridge_keeps_its_old_spelling() -> None:
    assert _parse("ros2", "bridge", "--domain", "3").ros2_domain == 3
    assert _parse("ros2", "bridge", "--ros2-domain", "4").ros2_domain == 4
    assert _parse("gamepad", "--ros2-domain", "5").ros2_domain == 5
    assert _parse("agent", "nao", "--ros2-domain", "6").ros2_domain == 6


def test_view_and_traffic_defaults_come_from_their_options() -> None:
    view = _parse("view")
    assert (view.host, view.port, view.fps) == (ViewOptions.host, ViewOptions.port,
                                                ViewOptions.fps)
    replay = _parse("replay", "x.mcap")
    t = TrafficOptions()
    assert (replay.what, replay.speed, replay.max_gap, replay.wait) == (
        t.what, t.speed, t.max_gap_s, t.wait_s)
    assert _parse("record", "-o", "x.mcap").max_mb == t.max_mb
