"""``kinesphere up``, ``status``, ``router`` and ``film``: the system as operators run it.

Heavy imports (Zenoh, MuJoCo, rich) happen inside the handlers so ``kinesphere --help`` stays
quick.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from kinesphere.cliargs import (
    DEFAULT_ENDPOINT,
    WATCHER,
    Subcommands,
    add_bodies,
    add_json,
    add_output,
    add_prefix,
    add_score_options,
    add_timeout,
    add_zenoh_arguments,
    command,
)
from kinesphere.deploy.plan import DEFAULT_ROBOTS, UpOptions
from kinesphere.errors import KinesphereError

UP = UpOptions(robots=[], phrases=[])
"""The defaults ``kinesphere up`` shows and uses."""
STATUS_TIMEOUT_S = 2.0
"""How long ``kinesphere status`` listens at most."""


def register(sub: Subcommands) -> None:
    up = command(sub, "up", _up)
    up.add_argument(
        "--robots", default=",".join(DEFAULT_ROBOTS), metavar="LIST",
        help=f"comma-separated platforms, optionally PLATFORM:ID (default "
        f"{','.join(DEFAULT_ROBOTS)})",
    )
    up.add_argument(
        "--phrase", action="append", default=[], metavar="FILE[@ROBOT]",
        help="play this phrase, on every robot or on ROBOT (repeatable, in order; default: the "
        "paper's Left-High example on all robots, then the PackBot sweep on the packbot)",
    )
    up.add_argument("--out", type=Path, default=UP.out, metavar="DIR",
                    help=f"where pictures, summary.json and logs/ go (default {UP.out}/)")
    up.add_argument("--headless", action="store_true",
                    help="no viewer windows and no live redraw: print tables instead")
    up.add_argument("--keep-running", action="store_true",
                    help="after the demo, keep the system up until Ctrl-C")
    up.add_argument("--start-timeout", type=float, default=UP.start_timeout, metavar="S",
                    help="seconds allowed for every process to come up (default "
                    f"{UP.start_timeout:g})")
    up.add_argument("--db", action="append", default=[], metavar="PLATFORM=PATH",
                    help="serve this databank file instead of the shipped one (repeatable)")
    add_prefix(up, UP.prefix)

    st = command(sub, "status", _status)
    add_timeout(st, STATUS_TIMEOUT_S, "discovery to settle",
                then="exit 1 when nothing answered by then")
    add_json(st, "the databanks and robots found (instead of a table)")
    add_zenoh_arguments(st, WATCHER, listen=False)

    rt = command(sub, "router", _router)
    rt.add_argument("--config", type=Path, metavar="FILE", help="Zenoh JSON5 config file")
    rt.add_argument("--listen", action="append", metavar="EP",
                    help="listen endpoint, overrides the file's (repeatable; default: the "
                    f"file's, else {DEFAULT_ENDPOINT}, loopback only; e.g. tls/0.0.0.0:7447 "
                    "to serve other machines)")
    rt.add_argument("--robots", type=Path, metavar="FILE",
                    help="fleet file (deploy/robots.toml): admit each robot by its own "
                    "certificate (CN = robot id) to its own keys only, and each operator "
                    "(CN = name) to put commands only under its own name")
    rt.add_argument("--print-acl", action="store_true",
                    help="print the access-control rules --robots generates, and exit")
    rt.add_argument("--link", action="append", metavar="EP",
                    help="another router to link with, e.g. tls/hq.example:7447 (repeatable; "
                    "overrides the file's connect endpoints; linked routers route for each "
                    "other's clients, see deploy/README.md, 'Several sites')")
    rt.add_argument("--log-denials", action=argparse.BooleanOptionalAction, default=None,
                    help="log access-control denials (default: on when access control is)")

    fm = command(sub, "film", _film)
    fm.add_argument("phrase", metavar="PHRASE|SCORE",
                    help="phrase file (TOML), score file (JSON) or a shipped name")
    add_score_options(fm, "the score's first")
    add_output(fm, "the video file", default="PHRASE.mp4", metavar="MP4")
    fm.add_argument("--gif", metavar="GIF", help="GIF file (default: the video's name, .gif)")
    fm.add_argument("--no-gif", action="store_true", help="write only the MP4")
    add_bodies(fm, DEFAULT_ROBOTS)
    fm.add_argument("--width", type=int, default=320, help="tile width in pixels (default 320)")
    fm.add_argument("--height", type=int, default=240, help="tile height (default 240)")
    fm.add_argument("--fps", type=float, default=15.0, help="frames per second (default 15)")


def _up(args: argparse.Namespace) -> int:
    """start a whole local system (databank + robots), play a demo, stop it all

    Start a router (the hub, serving nothing else), a databank and one robot agent per robot as
    separate processes on loopback, all Zenoh clients of the router (any of them can be killed and
    the rest keep talking), wait until each is alive, play the demo phrases, show a live status
    table, write pictures of the final poses and joint trajectories to --out, then stop every
    process (also on Ctrl-C). Exit 0 after the demo.
    """
    from kinesphere.deploy.plan import check_installed, default_phrases, parse_phrase, parse_robots

    check_installed()
    from kinesphere.deploy.up import Demo

    robots = parse_robots(args.robots)
    phrases = [parse_phrase(p) for p in args.phrase] or default_phrases(robots)
    opts = UpOptions(robots=robots, phrases=phrases, out=args.out, headless=args.headless,
                     keep_running=args.keep_running, prefix=args.prefix,
                     start_timeout=args.start_timeout, databanks=args.db)
    return Demo(opts).run()


def _status(args: argparse.Namespace) -> int:
    """list live databanks and robots and each robot's last state

    Listen to who is alive (liveliness, with history) and to every robot's state until discovery
    settles: every live robot has reported and nothing new turned up for 0.3 s (a peer waits at
    least 1 s for its gossip links), or --timeout. Exit 0 when something answered, 1 when nothing
    did.
    """
    from kinesphere.deploy.status import collect, print_status
    from kinesphere.keyexpr import Keys
    from kinesphere.zconfig import session_from_args

    with session_from_args(args) as session:
        info = collect(session, Keys(args.prefix), args.timeout)
    return print_status(info, args.json)


def _router(args: argparse.Namespace) -> int:
    """run a Zenoh router (TLS, access control) until SIGTERM/Ctrl-C

    Run a Zenoh router from the Python package with a JSON5 config file (see deploy/router.json5).
    With access control on, every denied message is logged as 'access denied: ...'.
    """
    from kinesphere.deploy.router import print_acl, run_router

    if args.print_acl:
        if args.robots is None:
            raise KinesphereError("malformed", "--print-acl needs --robots FILE")
        return print_acl(args.robots)
    return run_router(args.config, args.listen, robots=args.robots, links=args.link,
                      log_denials=args.log_denials)


def _film(args: argparse.Namespace) -> int:
    """film a movement phrase or a Labanotation score performed by every body side by side (MP4 and
    GIF)

    Render PHRASE (a phrase file or shipped name) on each platform's real agent controller with its
    real ECL, off-screen with MuJoCo, side by side with the current command in words, as an MP4 and
    a GIF. Or a gesture of a Labanotation score (a .json file or a shipped score's name, e.g. big2;
    see docs/labanotation.md): each body performs the parts it has at the score's times, the caption
    is the keyframe's notation.
    """
    from kinesphere.deploy.plan import FILM_NEEDS, check_installed

    check_installed("kinesphere film runs the robots' controllers and ECLs here", FILM_NEEDS)
    from kinesphere.deploy.film import render

    out = Path(args.output or f"{Path(args.phrase).stem}.mp4")
    gif = None if args.no_gif else Path(args.gif or out.with_suffix(".gif"))
    try:
        n = render(args.phrase, out, gif, args.bodies, args.width, args.height, args.fps,
                   args.gesture, 1.0 if args.speed is None else args.speed, _film_progress)
    except KeyboardInterrupt:
        print(f"film interrupted: nothing written to {out}" + (f" nor {gif}" if gif else ""),
              file=sys.stderr)
        return 130
    print(f"wrote {n} frames to {out}" + (f" and {gif}" if gif else "") + " (the phrase, "
          "then every body coming to rest)", file=sys.stderr)
    return 0


def _film_progress(t: float, heading: str) -> None:
    """A film's progress on stderr: each cue as the bodies start it (a score's notation, the
    heading's second line, left out)."""
    print(f"filming t = {t:.1f} s: {heading.splitlines()[0]}", file=sys.stderr, flush=True)
