"""Every transcript in the docs (a fenced block of ``$ command`` lines and what each prints) is
run by a test, and the output it shows is what the command prints, numbers aside (times,
counts and angles vary from run to run; :func:`support.transcripts.normal`).

The README's tour runs in test_system_hub; docs/commands.md's answers of the command line run
here, in the setting its prose describes: a NAO, a PackBot and a youBot behind a router with
the shipped databank, ``alice@lab`` holding the youBot's lease, the command sent as
``ada@lab``; then with no robot running.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from kinesphere.procs import Supervisor
from support.paths import ROOT
from support.system import Observer, databank_args, log_of, router_hub
from support.transcripts import DOCS, Transcript, section, transcripts, unprinted, unshown
from support.wait import WAIT_S, until

RUN_BY = {
    ("README.md", "A five-minute tour"):
        "tests/system/test_system_hub.py::test_the_readme_tour_runs_as_written",
    ("docs/commands.md", "What the command line tells you"):
        "tests/system/test_docs_transcripts.py::test_the_command_lines_answers_are_as_shown",
}
"""Where each transcript is run: (document, section) -> the test that runs it."""


def test_every_transcript_in_the_docs_is_run_by_a_test() -> None:
    """A transcript added to the docs fails here until a test runs it."""
    found = {(t.doc, t.section) for doc in DOCS for t in transcripts(doc)}
    assert found <= set(RUN_BY), f"transcripts no test runs: {sorted(found - set(RUN_BY))}"
    for where, test in RUN_BY.items():
        assert where in found, f"{where} has no transcript any more"
        path, name = test.split("::")
        assert f"def {name}(" in (ROOT / path).read_text(encoding="utf-8"), test


OWN_LEASE = re.compile(r"; control: ada@lab$", flags=re.M)
"""The lease a motion command takes for its sender: it lapses 3 s after the sender's last
command, so a robot that answers ``reached`` later (a slower arm, a loaded machine) no longer
names it; neither the shown line nor the printed one is compared on it."""


def run(sup: Supervisor, name: str, block: Transcript, endpoint: str, code: int) -> None:
    """The block's one command as a process joined to ``endpoint``: it exits ``code`` and
    prints exactly the lines the block shows (numbers and the sender's own lease aside)."""
    (step,) = block.steps
    assert step.words[0] == "kinesphere" and not step.background, step
    child = sup.spawn(name, [*step.words[1:], "--connect", endpoint], expect_exit=True)
    assert sup.wait(name, WAIT_S) == code, child.tail()
    out = OWN_LEASE.sub("", log_of(child).read_text(encoding="utf-8", errors="replace"))
    shown = [OWN_LEASE.sub("", line) for line in step.shown]
    where = f"{block.doc}:{block.line}"
    assert not unprinted(shown, out), (where, unprinted(shown, out), out)
    assert not unshown(shown, out), (where, unshown(shown, out), out)


@pytest.mark.processes
@pytest.mark.realtime  # the PackBot's arm arrives within --timeout, after the lease lapsed
def test_the_command_lines_answers_are_as_shown(sup: Supervisor, tmp_path: Path) -> None:
    send, estop = section("docs/commands.md", "What the command line tells you")
    endpoint = router_hub(sup)
    join = ["--connect", endpoint]
    robots = {"nao-1": "nao", "pb-1": "packbot", "yb-1": "youbot"}
    sup.spawn("databank", ["databank", "serve", *databank_args(sorted(set(robots.values()))),
                           *join])
    for rid, platform in robots.items():
        sup.spawn(rid, ["agent", platform, "--id", rid, "--control-rate", "250", *join])
    obs = Observer(mode="client", connect=[endpoint])
    try:
        obs.wait_alive(set(robots), databank=True, sup=sup)
        lease = sup.spawn("lease", ["lease", "acquire", "yb-1", "--hold", "60", "--sender",
                                    "alice@lab", *join])
        until(lambda: "holding the lease" in lease.tail(), WAIT_S, "alice@lab's lease",
              guard=sup.check, explain=lease.tail)
        sup.env["KINESPHERE_SENDER"] = "ada@lab"
        run(sup, "send", send, endpoint, 1)
        for name in ("lease", *robots):  # alice gives the lease back, then the robots stop
            assert sup.stop(name) == 0, sup.children[name].tail()
        until(lambda: not obs.alive.robots, WAIT_S, "every robot gone")
    finally:
        obs.close()
    run(sup, "estop", estop, endpoint, 1)
