"""``kinesphere view --port N`` serves on N or refuses: with N taken it exits 2 naming the port
(viser alone would quietly serve on N+1, and a bookmarked operator page would show nothing)."""

from __future__ import annotations

import socket

import pytest

from kinesphere.cli import main
from support.network import Hub


def test_a_busy_port_is_refused_not_moved(hub: Hub, capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code = main(["view", "--port", str(port), "--connect", hub.endpoint,
                     "--duration", "0.1"])
    err = capsys.readouterr().err
    assert code == 2
    assert f"port {port} on 127.0.0.1 is in use" in err and "--port N" in err
    assert "kinesphere view on" not in err, "it never claimed to serve"
