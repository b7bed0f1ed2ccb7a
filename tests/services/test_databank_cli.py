"""``kinesphere databank serve`` and ``kinesphere query`` as real processes: replicas,
failover on SIGKILL, clean SIGTERM, and the command-line client."""

from __future__ import annotations

import json
import queue
import re
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO

import pytest
import zenoh

from kinesphere import zconfig
from kinesphere.cli import main
from kinesphere.errors import KinesphereError
from kinesphere.services.databank import client
from kinesphere.services.databank.process import open_ecls
from support.databank import Tokens, build_toy, cli, pose_of, raw_get, serve_process
from support.network import OWN_KEYS, peer
from support.paths import ROOT, TOY
from support.wait import WAIT_S

pytestmark = pytest.mark.processes

CMD = ("toyarm", "arm", "shoulder", "left-high", "2")


@pytest.fixture(scope="module")
def db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_toy(tmp_path_factory.mktemp("db") / "toy.sqlite")


@pytest.fixture
def watched_hub() -> Iterator[tuple[str, zenoh.Session, Tokens]]:
    """A hub of the test's own (no queryables, and no databank's token from another test), a
    querier joined to it, and a token watcher."""
    with zconfig.loopback_hub() as (_hub, endpoint):
        querier = peer(endpoint)
        tokens = Tokens(querier)
        try:
            yield endpoint, querier, tokens
        finally:
            tokens.close()
            zconfig.close_session(querier)


def serve_args(endpoint: str, db: Path) -> list[str]:
    return ["--db", f"{TOY}={db}", "--prefix", OWN_KEYS.prefix, "--connect", endpoint,
            "--listen", zconfig.LOOPBACK_ANY_PORT]


class StartLine:
    """Reads a serve process's stderr on a thread; yields its start line's zenoh id."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.lines: queue.Queue[str] = queue.Queue()
        self.text: list[str] = []
        assert proc.stderr is not None
        stream = proc.stderr
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            self.text.append(line)
            self.lines.put(line)

    def zid(self, timeout: float = 20.0) -> str:
        deadline = time.monotonic() + timeout
        while True:
            line = self.lines.get(timeout=max(0.01, deadline - time.monotonic()))
            found = re.search(r"serving .* zenoh id ([0-9a-f]+)\)", line)
            if found:
                return found.group(1)


def test_query_cli_and_clean_sigterm(
    watched_hub: tuple[str, zenoh.Session, Tokens], db: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    endpoint, _, tokens = watched_hub
    zargs = ["--connect", endpoint, "--prefix", OWN_KEYS.prefix, "--timeout", "5"]
    with serve_process(serve_args(endpoint, db), "cli1") as proc:
        assert tokens.wait("cli1")
        text = subprocess.run(cli("query", *CMD, *zargs), capture_output=True, text=True,
                              cwd=ROOT, timeout=60)
        assert text.returncode == 0, text.stderr
        assert "limb_11 from distal_11 left-high size 2 (k_id" in text.stdout
        assert re.search(r"^\s+elbow\s+0\.500000$", text.stdout, re.M)
        # the same command in-process (a process start costs seconds)
        assert main(["query", *CMD, "--json", *zargs]) == 0
        pose = json.loads(capsys.readouterr().out)
        assert pose["type"] == "pose" and pose["p_id"] == 2 and pose["limb"] == "limb_11"
        assert main(["query", "toyarm", "--catalogue", *zargs]) == 0
        assert "limb_11 (arm) from distal_11" in capsys.readouterr().out
        assert main(["query", "toyarm", "leg", "shoulder", "left-high", "2", *zargs]) == 2
        assert "[unknown_limb]" in capsys.readouterr().err
        assert main(["query", "toyarm", "arm", *zargs]) == 2
        assert "[malformed]" in capsys.readouterr().err
        assert main(["query", "nosuchbot", "arm", "shoulder", "left-high", "2", *zargs]) == 2
        err = capsys.readouterr().err
        assert "[unknown_platform]" in err and "baxter" in err  # the shipped ones are known
        # a known platform nobody serves: silence, which the client reports as unavailable
        assert main(["query", "baxter", "limb_11", "distal_11", "left-high", "2",
                     *zargs[:-1], "0.3"]) == 2
        assert "[unavailable]" in capsys.readouterr().err
        # platform names are any case ('BAXTER' asks for baxter: unavailable, not unknown)...
        assert main(["query", "BAXTER", "limb_11", "distal_11", "left-high", "2",
                     *zargs[:-1], "0.3"]) == 2
        assert "[unavailable]" in capsys.readouterr().err
        # ... and a misspelt one is answered with the nearest known name
        assert main(["query", "packbto", "limb_11", "distal_11", "left-high", "2", *zargs]) == 2
        assert "no platform 'packbto' (did you mean 'packbot'?)" in capsys.readouterr().err
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=WAIT_S)
        assert proc.returncode == 0, err
        assert re.search(r"databank cli1 serving toyarm \[\w+\] under kstest/", err)
        assert re.search(r"databank cli1 stopped on SIGTERM after [\d.]+ s", err)
        assert tokens.wait("cli1", present=False)


def test_query_cli_without_a_databank_is_unavailable(capsys: pytest.CaptureFixture[str]) -> None:
    with zconfig.loopback_hub() as (_hub, endpoint):
        assert main(["query", *CMD, "--connect", endpoint, "--timeout", "0.3"]) == 2
    assert "[unavailable]" in capsys.readouterr().err


def test_replicas_one_answer_and_failover_on_sigkill(
    watched_hub: tuple[str, zenoh.Session, Tokens], db: Path,
) -> None:
    """Two replicas serve toyarm: each query gets one answer. The one answering is killed
    (SIGKILL, no goodbye): queries keep succeeding, the client changes nothing."""
    endpoint, querier, tokens = watched_hub
    args = serve_args(endpoint, db)
    with serve_process(args, "r1") as p1, serve_process(args, "r2") as p2:
        procs = {StartLine(p1).zid(): p1, StartLine(p2).zid(): p2}
        assert tokens.wait("r1") and tokens.wait("r2")
        key = OWN_KEYS.pose("toyarm", "limb_11", "distal_11", "left-high", 2)
        answers = []
        for _ in range(30):
            replies = list(querier.get(key, consolidation=zenoh.ConsolidationMode.NONE,
                                       timeout=5.0))
            assert len(replies) == 1 and replies[0].ok is not None
            answers.append(replies[0])
        expected = pose_of(raw_get(querier, key))
        serving = set()
        for r in answers:
            assert r.replier_id is not None, "a reply names the session that sent it"
            serving.add(str(r.replier_id.zid))
        assert len(serving) == 1 and serving <= procs.keys()
        victim = procs[serving.pop()]

        failures: list[Exception] = []
        served = 0
        stop = threading.Event()

        def stream() -> None:  # a client that knows nothing about replicas
            nonlocal served
            while not stop.is_set():
                try:
                    assert client.query_pose(querier, "toyarm", "limb_11", "distal_11",
                                             "left-high", 2, keys=OWN_KEYS, timeout=5.0) == expected
                    served += 1
                except Exception as exc:  # noqa: BLE001 - every failure counts
                    failures.append(exc)

        thread = threading.Thread(target=stream)
        thread.start()
        try:
            assert wait_served(lambda: served, 20)
            victim.kill()
            name = "r1" if victim is p1 else "r2"
            assert tokens.wait(name, present=False)
            after = served
            assert wait_served(lambda: served - after, 50)
        finally:
            stop.set()
            thread.join(10)
        assert failures == []
        for _ in range(10):
            assert pose_of(raw_get(querier, key)) == expected


def wait_served(count: Callable[[], int], n: int, timeout: float = 20.0) -> bool:
    """Until the streaming client has been answered ``n`` times (polls a counter)."""
    deadline = time.monotonic() + timeout
    while count() < n:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def test_open_ecls_pairs_databanks_with_platforms(db: Path, tmp_path: Path) -> None:
    ecls = open_ecls([str(TOY)], [f"{TOY}={db}"])  # --db wins over the shipped default
    assert list(ecls) == ["toyarm"] and ecls["toyarm"].db_path == db.resolve()
    with pytest.raises(KinesphereError) as info:
        open_ecls([], [str(db)])  # toyarm is not shipped: the file alone cannot say where
    assert info.value.code == "unknown_platform" and f"--db FOLDER={db}" in info.value.message
    other = build_toy(tmp_path / "other.sqlite")
    with pytest.raises(KinesphereError) as info:
        open_ecls([], [f"{TOY}={db}", f"{TOY}={other}"])
    assert info.value.code == "conflict"
