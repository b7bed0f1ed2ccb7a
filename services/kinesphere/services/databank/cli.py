"""``kinesphere databank serve`` and ``kinesphere query``: the databank from a shell.

Imports of Zenoh and the ECL happen inside the handlers, so ``kinesphere --help`` stays quick.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from kinesphere.cliargs import (
    QUERY,
    SERVICE,
    Subcommands,
    add_json,
    add_timeout,
    add_zenoh_arguments,
    command,
    command_group,
)
from kinesphere.errors import KinesphereError
from kinesphere.services.options import QueryOptions, add_exact


def register(sub: Subcommands) -> None:
    dsub = command_group(
        sub, "databank",
        help="serve ECL databanks over Zenoh (pose queries for agents and clients)",
        description="The databank service: answers pose, compound, catalogue and record "
        "queries under <prefix>/ecl/<platform>/ (see docs/protocol.md).",
        dest="databank_command",
    )
    s = command(dsub, "serve", _serve)
    s.add_argument(
        "--platform", action="append", default=[], metavar="NAME",
        help="serve this platform's shipped databank (a name or platform folder; repeatable)",
    )
    s.add_argument(
        "--db", action="append", default=[], metavar="PATH",
        help="serve this databank file; its meta names the platform. PLATFORM=PATH pairs it "
        "with a platform name or folder (repeatable)",
    )
    s.add_argument(
        "--replica", metavar="ID",
        help="replica name in the liveliness token <prefix>/alive/databank/ID (default "
        "<host>-<pid>)",
    )
    s.add_argument(
        "--allow-writes", action="store_true",
        help="accept record queries and puts (super-user pose edits); off by default. Restrict "
        "who may send them with Zenoh access control on <prefix>/ecl/*/record",
    )
    s.add_argument(
        "--known-platform", action="append", default=[], metavar="NAME",
        help="a platform other replicas serve: never answer unknown_platform for it "
        "(shipped platforms are always known)",
    )
    add_zenoh_arguments(s, SERVICE)

    q = command(sub, "query", _query)
    q.add_argument("platform", help="platform name, e.g. baxter")
    q.add_argument("params", nargs="*", metavar="L O D S", help="limb origin direction size")
    q.add_argument("--catalogue", action="store_true",
                   help="print what the platform answers instead of a pose")
    add_json(q, "the reply message")
    add_exact(q)
    add_timeout(q, QueryOptions.timeout_s, "an answer")
    add_zenoh_arguments(q, QUERY)


def _serve(args: argparse.Namespace) -> int:
    """serve databanks until SIGTERM or Ctrl-C

    Serve every shipped databank (embedded SQLite, no set-up), or those named. Several replicas may
    serve the same platforms: each query gets one answer, and when a replica stops the others
    answer. Logs one line on start and one on stop; exits 0 on SIGTERM/SIGINT.
    """
    from kinesphere.keyexpr import Keys
    from kinesphere.services.databank.process import default_replica_id, open_ecls, run
    from kinesphere.zconfig import session_from_args

    keys = Keys(args.prefix)
    ecls = open_ecls(args.platform, args.db)
    session = session_from_args(args)
    replica = args.replica or default_replica_id()
    return run(session, ecls, keys, replica, args.allow_writes, args.known_platform)


def _query(args: argparse.Namespace) -> int:
    """ask the databank for a pose (or a platform's catalogue)

    Print the joint targets f_SB(L, O, D, S) of PLATFORM, plus the base translation when S is beyond
    the largest stored size. L and O are labels or aliases (limb_11, right_arm), D a Laban direction
    (left-high), S a size (1, 2.5, far). A direction the limb lacks is served by the nearest one it
    has (and says so) unless --exact. Exit 2 with the error code when the databank refuses or nobody
    answers.
    """
    if not args.catalogue and len(args.params) != 4:
        raise KinesphereError(
            "malformed",
            f"query needs LIMB ORIGIN DIRECTION SIZE (got {len(args.params)} values), "
            "or --catalogue",
        )
    if args.catalogue and args.params:
        raise KinesphereError("malformed", "--catalogue takes no LIMB ORIGIN DIRECTION SIZE")
    from kinesphere.keyexpr import Keys
    from kinesphere.platforms.platform import platform_spelling
    from kinesphere.services.databank import client
    from kinesphere.zconfig import session_from_args

    keys = Keys(args.prefix)
    args.platform = platform_spelling(args.platform)  # 'PackBot' asks for packbot
    with session_from_args(args) as s:
        if args.catalogue:
            msg: Any = client.query_catalogue(s, args.platform, keys=keys, timeout=args.timeout)
        else:
            limb, origin, direction, size = args.params
            msg = client.query_pose(s, args.platform, limb, origin, direction, size, keys=keys,
                                    timeout=args.timeout, exact=args.exact)
    if args.json:
        print(json.dumps(client.to_builtins(msg), indent=2))
    elif args.catalogue:
        _print_catalogue(msg)
    else:
        _print_pose(msg)
    return 0


def _print_pose(pose: Any) -> None:
    where = f"k_id {pose.k_id}" + (f", p_id {pose.p_id}" if pose.p_id is not None else "")
    print(
        f"{pose.platform} {pose.limb} from {pose.origin} {pose.direction} size {pose.size:g} "
        f"({where})"
    )
    width = max((len(n) for n in pose.joints), default=0)
    for name, value in pose.joints.items():
        print(f"  {name:<{width}}  {value: .6f}")
    if not pose.joints:
        print("  (no joints move)")
    if pose.translation is not None:
        x, y, z = pose.translation
        print(f"  translate base  x {x:+.4f}  y {y:+.4f}  z {z:+.4f} m (body frame)")
    for sub in pose.substitutions:
        print(f"  substituted: {sub.limb} has no {sub.requested}; served {sub.served} "
              f"({sub.angle:.1f} degrees away)")
    sys.stdout.flush()


def _print_catalogue(cat: Any) -> None:
    print(f"{cat.platform} (ECL {cat.version}); sizes {', '.join(map(str, cat.sizes))}")
    aliases = {v: k for k, v in cat.aliases.items()}
    for e in cat.limbs:
        names = [f"{n} ({aliases[n]})" if n in aliases else n for n in (e.limb, e.origin)]
        print(f"  {names[0]} from {names[1]}: {', '.join(e.directions)}")
    if cat.can_translate:
        print(f"  core {', '.join(cat.core)} translates {cat.translation_step:g} m per size "
              f"unit: {', '.join(cat.directions_for_core)}")
    print(f"  joints: {', '.join(j.name for j in cat.joints)}")
