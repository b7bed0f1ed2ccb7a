"""``kinesphere record`` and ``kinesphere replay``: a session on Zenoh to MCAP and back.

Registered through their own ``kinesphere.commands`` entry point; the handlers import mcap and
Zenoh only when they run, so ``kinesphere --help`` stays quick.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

from kinesphere.cliargs import (
    OPERATOR,
    WATCHER,
    Subcommands,
    add_output,
    add_wait,
    add_zenoh_arguments,
    command,
)
from kinesphere.clients.options import REPLAYED, TrafficOptions, add_duration, add_identity
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.signals import handle_signals


def register(sub: Subcommands) -> None:
    r = command(sub, "record", record)
    d = TrafficOptions()
    add_output(r, "the MCAP file")
    add_duration(r, "stop")
    r.add_argument("--max-mb", type=float, default=d.max_mb, metavar="MB",
                   help=f"stop when MB megabytes of messages are written (default {d.max_mb:g})")
    add_zenoh_arguments(r, WATCHER)

    p = command(sub, "replay", replay)
    p.add_argument("recording", metavar="FILE", help="MCAP file written by kinesphere record")
    p.add_argument("--what", choices=REPLAYED, default=d.what,
                   help=f"which messages to put back (default {d.what})")
    p.add_argument("--speed", type=float, default=d.speed,
                   help=f"time scale (default {d.speed:g} = as recorded)")
    p.add_argument("--restamp", action="store_true",
                   help="send commands now and as yours (--sender), each recorded session as "
                   "a fresh one (seq kept), so robots that heard the original do not drop "
                   "them as stale and lease to you")
    p.add_argument("--max-gap", type=float, default=d.max_gap_s, metavar="S",
                   help="shorten a silence in the recording longer than S seconds to S "
                   f"(default {d.max_gap_s:g})")
    add_wait(p, d.wait_s, "a subscriber on each recorded key, and each robot the commands "
             "name to be seen alive, before the first put")
    add_identity(p)
    add_zenoh_arguments(p, OPERATOR)


def record(args: argparse.Namespace) -> int:
    """record every command, state, ack and recorded pose to an MCAP file

    Record {prefix}/robot/*/command, {prefix}/group/*/command, {prefix}/robot/*/state,
    {prefix}/robot/*/ack and {prefix}/ecl/*/changed and write every message to an MCAP file (one
    channel per key, JSON with a JSON Schema per message type: Foxglove and 'mcap info' read it).
    Stops on Ctrl-C, SIGTERM, --duration or --max-mb.
    """
    from kinesphere.clients.recording.traffic import TrafficRecorder, summary
    from kinesphere.zconfig import session_from_args

    if not args.max_mb > 0:
        raise KinesphereError("malformed", f"--max-mb must be > 0, got {args.max_mb}")
    stop = threading.Event()
    with handle_signals(lambda signum, frame: stop.set()), session_from_args(args) as session:
        rec = TrafficRecorder(session, Keys(args.prefix), args.output, int(args.max_mb * 1e6))
        try:
            print(f"recording to {args.output}; Ctrl-C to stop", file=sys.stderr, flush=True)
            deadline = None if args.duration is None else time.monotonic() + args.duration
            while not stop.is_set() and not rec.full.is_set():
                if deadline is not None and time.monotonic() >= deadline:
                    break
                stop.wait(0.1)
            if rec.full.is_set():
                print(f"--max-mb {args.max_mb:g} reached", file=sys.stderr)
        finally:
            tally = rec.close()
    print(summary(tally, Path(args.output)), file=sys.stderr)
    return 0


def replay(args: argparse.Namespace) -> int:
    """re-publish a recorded session's commands (or states) with the original timing

    Put the messages of an MCAP recording back on their keys, spaced as they were recorded:
    'commands' drive running robots again; 'states' replay what the robots did, to watch it in
    'kinesphere view' with no robot running. Commands keep their recorded sender, session, seq and
    sent_ns, so robots that heard the original session drop them as stale; --restamp sends them as
    new, as yours (--sender). Only command and state keys under --prefix are replayed (another key
    refuses the whole file before anything is put), silences longer than --max-gap are shortened,
    and the file is read a chunk at a time, with every size bounded. Waits first for a subscriber on
    each recorded key and for each robot the commands name to be seen alive (--wait); fails
    when nobody listens on any key. Then says what the robots answered
    to the commands put: exits 0 only when they acted on them and dropped or refused none (130 when
    stopped by Ctrl-C).
    """
    from kinesphere.clients.recording.traffic import few
    from kinesphere.clients.recording.traffic import replay as put_back
    from kinesphere.zconfig import session_from_args

    stop = threading.Event()
    with handle_signals(lambda signum, frame: stop.set()), session_from_args(args) as session:
        done = put_back(session, args.recording, args.what, args.speed, stop.is_set,
                        restamp=args.restamp, wait=args.wait, keys=Keys(args.prefix),
                        sender=args.sender, max_gap=args.max_gap)
    if done.shortened:
        print(f"shortened {done.shortened} silence(s) longer than {args.max_gap:g} s",
              file=sys.stderr)
    if done.unheard:
        print(f"nobody listened on {len(done.unheard)} recorded key(s): "
              f"{few(done.unheard, 10)}", file=sys.stderr)
    if done.unseen:
        print(f"not seen alive within --wait {args.wait:g} s: robot(s) "
              f"{few(done.unseen, 10)}", file=sys.stderr)
    if done.interrupted:
        print(f"replay interrupted: {done.sent} {args.what} message(s) from {args.recording} "
              "put before it was stopped", file=sys.stderr)
    else:
        print(f"replayed {done.sent} {args.what} message(s) from {args.recording}",
              file=sys.stderr)
    code = 0
    if done.commands:
        said, code = done.answers.words(done.commands, args.recording, args.restamp)
        print(said, file=sys.stderr)
    return 130 if done.interrupted else code
