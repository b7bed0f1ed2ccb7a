"""``kinesphere view``: the parser and its handler.

Registered through its own ``kinesphere.commands`` entry point; the handler imports viser and
Zenoh only when it runs, so ``kinesphere --help`` stays quick.
"""

from __future__ import annotations

import argparse
import sys
import threading

from kinesphere.cliargs import WATCHER, Subcommands, add_zenoh_arguments, command
from kinesphere.clients.options import ViewOptions, add_duration
from kinesphere.keyexpr import Keys
from kinesphere.signals import handle_signals


def register(sub: Subcommands) -> None:
    v = command(sub, "view", view)
    d = ViewOptions()
    v.add_argument("--host", default=d.host,
                   help=f"address to serve the page on (default {d.host}; 0.0.0.0 = every "
                   "interface, for other machines)")
    v.add_argument("--port", type=int, default=d.port,
                   help=f"HTTP/websocket port (default {d.port})")
    v.add_argument("--fps", type=float, default=d.fps,
                   help=f"scene updates per second sent to browsers (default {d.fps:g})")
    v.add_argument("--allow-origin", action="append", default=[], metavar="ORIGIN",
                   help="a web origin (http://lab-pc:8080) whose pages may open the view's "
                   "websocket, and whose host name the view answers to; repeatable. By "
                   "default only the view's own page may, reached by a loopback name, the "
                   "--host address, or (with --host 0.0.0.0) this machine's names")
    add_duration(v)
    add_zenoh_arguments(v, WATCHER)


def view(args: argparse.Namespace) -> int:
    """a live 3D view of every robot, in the browser

    Serve a web page (viser) that draws every robot on the Zenoh network at its live joint state and
    base pose, with its id, status, current command in words, substitutions and e-stop state, and
    the target pose as a translucent ghost while it moves. Bodies come from the databank
    ({prefix}/ecl/PLATFORM/body): no platform files are needed here. Open http://HOST:PORT in a
    browser; no internet access is needed.
    """
    from kinesphere.clients.view.app import FleetView
    from kinesphere.zconfig import session_from_args

    stop = threading.Event()
    with handle_signals(lambda signum, frame: stop.set()), session_from_args(args) as session:
        app = FleetView(session, Keys(args.prefix), args.host, args.port, args.fps,
                        args.allow_origin)
        try:
            print(f"kinesphere view on http://{args.host}:{app.port}/", file=sys.stderr,
                  flush=True)
            app.run(stop, args.duration)
        finally:
            app.close()
    return 0
