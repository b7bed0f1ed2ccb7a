"""With the router down, every command blames the missing router and names the command that
starts it, and that command works: ``send`` and ``estop`` no longer say that no robot listens
or lives, ``status``, ``view`` and ``query`` no longer print Zenoh's bare "Unable to
connect", an agent says at once that nobody can command it. Then ``kinesphere router --listen
EP`` (the hint) is started and the same commands find it."""

from __future__ import annotations

import pytest

from kinesphere.cli import main
from kinesphere.procs import Supervisor
from kinesphere.zconfig import free_port
from support.system import port_open
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes


def test_every_command_names_the_missing_router_and_its_hint_starts_one(
    sup: Supervisor, capsys: pytest.CaptureFixture[str]
) -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    hint = f"no Zenoh router answers at {ep}: start one with 'kinesphere router --listen {ep}'"
    runs = {
        "send": (["send", "yb-1", "arm", "shoulder", "left-high", "far", "--wait", "0.5"], 2),
        "estop": (["estop", "--timeout", "0.5"], 1),
        "status": (["status", "--timeout", "0.5"], 2),
        "query": (["query", "youbot", "arm", "shoulder", "left-high", "far"], 2),
        "view": (["view", "--port", "0", "--duration", "0.1"], 2),
    }
    for name, (args, code) in runs.items():
        assert main([*args, "--connect", ep]) == code, name
        err = capsys.readouterr().err
        assert hint in err, (name, err)
        assert "Unable to connect" not in err and "no robot seen alive" not in err, (name, err)
    agent = sup.spawn("agent", ["agent", "youbot", "--id", "yb-1", "--connect", ep])
    until(lambda: hint in agent.tail(50), WAIT_S, "the agent's warning",
          explain=lambda: agent.tail())
    assert "nobody can command it until then" in agent.tail(50)

    sup.spawn("router", ["router", "--listen", ep])  # the hint, as printed
    until(lambda: port_open(int(ep.rsplit(":", 1)[1])), WAIT_S, "the router to listen")
    until(lambda: main(["status", "--timeout", "1", "--connect", ep, "--json"]) == 0, WAIT_S,
          "status to find the robot through the router")
    assert '"yb-1"' in capsys.readouterr().out, "the agent joined by itself"
