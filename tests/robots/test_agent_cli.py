"""``kinesphere agent`` as a process: it comes up, obeys its group, leaves cleanly on SIGTERM."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from kinesphere import zconfig
from kinesphere.deploy.watch import watch_alive
from support.agents import CommandSender, DatabankProcess, StateWatch, robots_alive
from support.network import KEYS, Hub
from support.paths import ROOT
from support.wait import WAIT_S

pytestmark = pytest.mark.processes


def test_agent_process_obeys_its_group_and_stops_on_sigterm(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    alive, tokens = watch_alive(session, KEYS)
    watch = StateWatch(session, "arm-7")
    proc = subprocess.Popen(
        [sys.executable, "-m", "kinesphere.cli", "agent", "youbot", "--id", "arm-7",
         "--group", "arms", "--connect", endpoint, "--listen", zconfig.LOOPBACK_ANY_PORT],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )
    try:
        robots_alive(alive, lambda ids: "arm-7" in ids, "liveliness token declared")
        first = watch.wait(lambda s: True, "state published")
        assert first.platform == "youbot" and first.robot_id == "arm-7"
        assert first.last_command_seq == -1

        entry = databank.catalogue("youbot").limbs[0]
        with CommandSender(session, key=KEYS.group_command("arms")) as group:
            seq = group.send((entry.limb, entry.origin, entry.directions[-1], 2.0))
            watch.after(seq, lambda s: s.status in ("moving", "idle", "clamped"),
                        "group command")

        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=WAIT_S)
        assert proc.returncode == 0, err.decode()
        robots_alive(alive, lambda ids: "arm-7" not in ids, "token undeclared on SIGTERM")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        watch.close()
        zconfig.undeclare(*tokens)
