"""A ROS 2 peer written by others (zenoh-ros2-sdk, ``sdk_peer.py``) as a process the tests drive.

Two builds of it: in the test venv (the eclipse-zenoh kinesphere runs), and in a venv of its
own with the eclipse-zenoh that Jazzy's rmw_zenoh 0.2.9 links (1.6.2, its
``zenoh_cpp_vendor``), made on first use under ``build/`` and reused while its pins are the
same (about 30 s once; ``make test`` makes it in a fresh clone). Events are waited on with
bounded timeouts, never slept for.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from support.paths import ROOT
from support.venvs import clean_env, fresh_venv, pip_install
from support.wait import WAIT_S
from support.watch import Heard

SCRIPT = Path(__file__).resolve().parent / "sdk_peer.py"
JAZZY_ZENOH = "1.6.2"
"""The eclipse-zenoh of Jazzy's rmw_zenoh 0.2.9 (zenoh_cpp_vendor: "Set VCS_VERSION to 1.6.2
commits of zenoh/zenoh-c/zenoh-cpp"), released 2025-11-12 and Jazzy's until 0.2.10."""
SDK = "zenoh-ros2-sdk==0.1.8"
INSTALL_TIMEOUT_S = 600


def _pins(zenoh: str) -> list[str]:
    """The skew venv's requirements: that zenoh, the SDK, and the test venv's own pins for
    everything else (constraints.txt without its eclipse-zenoh)."""
    pins = [line.strip() for line in (ROOT / "constraints.txt").read_text().splitlines()
            if line.strip() and not line.startswith("#")
            and not line.lower().startswith("eclipse-zenoh==")]
    return [f"eclipse-zenoh=={zenoh}", SDK, *pins]


def peer_python(zenoh: str | None = None) -> str:
    """The Python that runs the peer: this one, or that of the cached venv with ``zenoh``."""
    if zenoh is None:
        return sys.executable
    pins = _pins(zenoh)
    stamp_text = hashlib.sha256("\n".join(pins).encode()).hexdigest()
    venv = ROOT / "build" / f"ros2-peer-zenoh-{zenoh}"
    python = venv / "bin" / "python"
    stamp = venv / ".installed"
    if stamp.is_file() and stamp.read_text() == stamp_text and python.is_file():
        return str(python)
    python = fresh_venv(venv, INSTALL_TIMEOUT_S)
    constraints = venv / "constraints.txt"
    constraints.write_text("\n".join(pins[2:]) + "\n")
    done = pip_install(python, ["-c", str(constraints), pins[0], pins[1]], venv,
                       INSTALL_TIMEOUT_S)
    if done.returncode != 0:
        raise RuntimeError(f"installing the ROS 2 peer with eclipse-zenoh {zenoh} failed:\n"
                           f"{done.stdout}\n{done.stderr}")
    stamp.write_text(stamp_text)
    return str(python)


class SdkPeer(Heard[dict[str, Any]]):
    """``sdk_peer.py`` in a subprocess, joined to ``router``; its events, kept in order."""

    def __init__(self, router: str, zenoh: str | None = None, domain: int = 0,
                 distro: str = "jazzy") -> None:
        super().__init__()
        self.events = self.heard
        self.domain = domain
        env = clean_env()
        env["PYTHONUNBUFFERED"] = "1"
        self._log = tempfile.TemporaryFile(mode="w+")  # the SDK's logging, for failures
        self.proc = subprocess.Popen(
            [peer_python(zenoh), "-P", str(SCRIPT), "--router", router, "--domain", str(domain),
             "--distro", distro],
            cwd=ROOT, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=self._log, text=True)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.ready = self.wait(lambda e: e["event"] == "ready", "the peer to start")

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.add(json.loads(line))
        self.add({"event": "exit"})

    def send(self, **cmd: Any) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()

    def sub(self, name: str, topic: str, ros_type: str, **kw: Any) -> dict[str, Any]:
        """Subscribe; returns the ``subscribed`` event (with the key the SDK made)."""
        self.send(op="sub", name=name, topic=topic, type=ros_type, **kw)
        return self.wait(lambda e: e["event"] == "subscribed" and e["name"] == name,
                         f"the subscription {name}")

    def pub(self, name: str, topic: str, ros_type: str, fields: dict[str, Any],
            every: float | None = None) -> None:
        self.send(op="pub", name=name, topic=topic, type=ros_type, fields=fields, every=every)

    def in_graph(self, pattern: str, pred: Callable[[str], bool], what: str) -> str:
        """The first graph token under ``pattern`` that satisfies ``pred``, as the peer's own
        liveliness subscriber (rmw_zenoh's graph cache) sees it: it comes once the peer's link
        to the token's session is open."""
        self.send(op="graph", pattern=pattern)
        e = self.wait(lambda e: e["event"] == "token" and pred(e["key"]), what)
        return str(e["key"])

    def explain(self) -> str:
        return f"from the ROS 2 peer ({len(self.events)} other events); its log: {self._stderr()}"

    def wait(self, pred: Callable[[dict[str, Any]], bool], what: str,
             timeout: float = WAIT_S, *, start: int = 0) -> dict[str, Any]:
        """The first event from index ``start`` on that satisfies ``pred``; an ``error`` event
        or the peer's exit fails the wait at once, naming it."""

        def failing(e: dict[str, Any]) -> bool:
            if e["event"] in ("error", "exit"):
                raise AssertionError(f"the ROS 2 peer failed while waiting for {what}: "
                                     f"{e} {self._stderr()}")
            return pred(e)

        return super().wait(failing, what, timeout, start=start)

    def messages(self, name: str) -> list[dict[str, Any]]:
        with self._cond:
            return [e["msg"] for e in self.events if e["event"] == "msg" and e["name"] == name]

    def message(self, name: str, pred: Callable[[dict[str, Any]], bool] = lambda m: True,
                what: str = "", timeout: float = WAIT_S) -> dict[str, Any]:
        """The first message on subscription ``name`` that satisfies ``pred``."""
        e = self.wait(lambda e: e["event"] == "msg" and e["name"] == name and pred(e["msg"]),
                      what or f"a message on {name}", timeout)
        msg: dict[str, Any] = e["msg"]
        return msg

    def sample(self, name: str, timeout: float = WAIT_S) -> dict[str, Any]:
        return self.wait(lambda e: e["event"] == "sample" and e["name"] == name,
                         f"a sample on {name}", timeout)

    def _stderr(self) -> str:
        self._log.seek(0)
        return self._log.read()[-2000:]

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.send(op="quit")
                self.proc.wait(timeout=WAIT_S)
            except (BrokenPipeError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self._reader.join(timeout=5)
        self._log.close()
