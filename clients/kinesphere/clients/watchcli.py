"""Sub-commands that watch the Zenoh network: ``view``, ``record`` and ``replay``.

Registered through their own ``kinesphere.commands`` entry point; the handlers import viser,
mcap and Zenoh only when they run, so ``kinesphere --help`` stays quick.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from types import FrameType
from typing import Any

from kinesphere.cliargs import DEFAULT_ENDPOINT, add_zenoh_arguments

log = logging.getLogger(__name__)


def _zenoh(p: argparse.ArgumentParser) -> None:
    add_zenoh_arguments(
        p,
        default_help=f"Without --connect, --listen or --zenoh-config: connect to "
        f"{DEFAULT_ENDPOINT} (a router, or where 'kinesphere databank serve' listens).",
    )


def register(sub: Any) -> None:
    v = sub.add_parser(
        "view",
        help="a live 3D view of every robot, in the browser",
        description="Serve a web page (viser) that draws every robot on the Zenoh network at "
        "its live joint state and base pose, with its id, status, current command in words, "
        "substitutions and e-stop state, and the target pose as a translucent ghost while "
        "it moves. Bodies come from the databank ({prefix}/ecl/PLATFORM/body): no platform "
        "files are needed here. Open http://HOST:PORT in a browser; no internet access is "
        "needed.",
    )
    v.add_argument("--host", default="127.0.0.1",
                   help="address to serve the page on (default 127.0.0.1; 0.0.0.0 = every "
                   "interface, for other machines)")
    v.add_argument("--port", type=int, default=8080, help="HTTP/websocket port (default 8080)")
    v.add_argument("--fps", type=float, default=30.0,
                   help="scene updates per second sent to browsers (default 30)")
    v.add_argument("--duration", type=float, metavar="S", help="quit after S seconds")
    _zenoh(v)
    v.set_defaults(func=view)


def _session(args: argparse.Namespace) -> Any:
    from kinesphere import zconfig

    connect = args.connect
    if connect is None and args.listen is None and args.zenoh_config is None:
        connect = [zconfig.DEFAULT_ENDPOINT]
    return zconfig.session(args.mode, args.listen, connect, args.zenoh_config)


def _until_signal() -> Any:
    from kinesphere.signals import handle_signals

    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    return stop, handle_signals(on_signal, (signal.SIGINT, signal.SIGTERM))


def view(args: argparse.Namespace) -> int:
    from kinesphere.clients.view.app import View
    from kinesphere.keyexpr import Keys

    stop, signals = _until_signal()
    with signals, _session(args) as session:
        app = View(session, Keys(args.prefix), args.host, args.port, args.fps)
        try:
            print(f"kinesphere view on http://{args.host}:{app.port}/", file=sys.stderr,
                  flush=True)
            app.run(stop, args.duration)
        finally:
            app.close()
    return 0
