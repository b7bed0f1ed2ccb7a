"""Sub-commands about robot bodies: ``platforms``, ``describe`` and ``platform new``."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from kinesphere.cliargs import Subcommands, add_json, add_merge_distance, command, command_group

if TYPE_CHECKING:  # imported lazily: yourdfpy/trimesh cost ~1 s at every CLI start
    from kinesphere.eurdf import Eurdf


def register(sub: Subcommands) -> None:
    nsub = command_group(sub, "platform", "bring your own robot: 'platform new NAME --urdf FILE'",
                         dest="platform_command", metavar="ACTION")
    new = command(nsub, "new", _platform_new)
    new.add_argument("name", help="platform name: a-z and 0-9 words joined by single _ or -, "
                     "starting with a letter")
    new.add_argument("--urdf", type=Path, required=True, help="the robot's URDF file")
    new.add_argument(
        "--dir", type=Path, default=None,
        help="folder to create NAME/ in (default: the first --platforms folder, else .)",
    )
    add_merge_distance(new)
    new.add_argument("--up", default="auto", choices=("auto", "z", "y", "x", "-z", "-y", "-x"),
                     help="the file's up axis (default auto: from where its legs point; z "
                     "for a robot without legs). A Y-up file (pybullet's) is turned so z is up")
    new.add_argument("--neutral", default="auto", choices=("auto", "zero"),
                     help="auto (default): where the zero pose leaves a limb few directions "
                     "(a stretched, singular arm), propose a bent neutral and say why; zero: "
                     "keep zero (kept 0.05 rad off every limit)")
    new.add_argument("--force", action="store_true",
                     help="replace an existing platform folder (as a whole, once the new one "
                     "is complete)")
    p = command(sub, "platforms", _platforms)
    add_json(p, "the list")
    d = command(sub, "describe", _describe)
    d.add_argument(
        "platform", help="platform name, any case (see 'kinesphere platforms'), 'all' (with "
        "--json: one list), or an eURDF path"
    )
    add_json(d, "the description")


def _platform_new(args: argparse.Namespace) -> int:
    """scaffold a platform folder from any URDF

    Write DIR/NAME/: the eURDF (proposed labels, meshes copied beside it), platform.toml (base kind,
    height, neutral pose) and vsam.toml (Laban-27 for every limb). The folder is written whole or
    not at all. What MuJoCo would refuse is mended where the mend is standard (inertias balanced,
    zero-size shapes dropped, a spherical joint as three revolutes, a missing mesh as a box from its
    link's inertia) and every mend is listed; what cannot be mended is one error naming the element.
    Edit the files, then 'kinesphere ecl build DIR/NAME' and run it with '--platforms DIR' (or
    $KINESPHERE_PLATFORMS=DIR) like a shipped platform.
    """
    from kinesphere import hints
    from kinesphere.platforms.platform import search_path
    from kinesphere.platforms.scaffold import new_platform

    parent = args.dir if args.dir is not None else (search_path() or [Path(".")])[0]
    s = new_platform(args.name, args.urdf, parent, args.merge_distance, args.force, args.up,
                     args.neutral)
    e = s.eurdf
    print(f"wrote {s.folder}/: {e.name}.eurdf ({len(e.limits)} DOF, C={len(e.core)}, "
          f"{len(e.limbs)} limbs), platform.toml (base {s.base_kind}, height {s.height} m), "
          f"vsam.toml ({len(s.limbs)} entries)")
    m = s.meshes
    print(f"meshes: {m.copied} copied, {m.converted} converted to binary STL, {m.hulls} "
          f"replaced by convex hulls, {len(m.missing)} not found")
    for line in s.mends:
        print(f"  mended: {line}")
    if s.warnings:
        print(f"  {s.warnings}")
    if s.base_kind == "legged":
        print(f"stands on {', '.join(s.standing_on)}: base legged (walking abstracted)")
    if s.knees:
        print("neutral: straight standing legs, knees bent so a foot can lift: "
              + ", ".join(f"{j} = {v:g}" for j, v in s.knees.items()))
    for proposal in s.neutral:
        if proposal.joints:
            print(f"neutral: {proposal} (--neutral zero keeps zero)")
    for p in e.limbs:
        if p.index[1] == 1:
            print(f"  {p.name:<8} {p.alias or '':<18} from {p.distal}: "
                  f"{len(e.limb_joints(p.name))} joints" + (f", tip {p.tip}" if p.tip else ""))
    print(f"next: edit the three files, check with '{hints.describe(str(s.folder))}', then "
          f"'{hints.build_ecl(str(s.folder))}'")
    return 0


def _platforms(args: argparse.Namespace) -> int:
    """list the known platforms (shipped and brought)"""
    from kinesphere.platforms.platform import load_platform, platform_names

    rows = []
    for name in platform_names():
        p = load_platform(name)
        rows.append(
            {
                "name": name,
                "title": p.title,
                "dof": len(p.joint_names),
                "base": p.base.kind,
                "limbs": len(p.eurdf.limbs),
                "folder": None if p.shipped else str(p.folder),
            }
        )
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        for r in rows:
            where = f"  [{r['folder']}]" if r["folder"] else ""
            print(f"{r['name']:<9} {r['dof']:>3} DOF  base={r['base']:<6} {r['title']}{where}")
    return 0


def describe_dict(e: Eurdf, base: str | None = None) -> dict[str, Any]:
    """The (C, J, L, P) of an eURDF and its body vocabulary as plain data (the --json
    output)."""
    from kinesphere.vocabulary import vocabulary

    def num(x: float) -> float | None:
        return x if math.isfinite(x) else None

    return {
        "name": e.name,
        "base": base,
        "dof": len(e.limits),
        "C": [{"label": p.name, "alias": p.alias, "links": list(p.links)} for p in e.core],
        "J": [{"label": p.name, "alias": p.alias, "joints": list(p.joints)} for p in e.distals],
        "L": [
            {
                "label": p.name,
                "alias": p.alias,
                "distal": p.distal,
                "links": list(p.links),
                "joints": list(e.limb_joints(p.name)),
                "tip": e.tip_link(p.name),
            }
            for p in e.limbs
        ],
        "P": [
            {
                "joint": lim.name,
                "type": lim.kind,
                "lower": num(lim.lower),
                "upper": num(lim.upper),
                "velocity": num(lim.velocity),
            }
            for lim in e.P
        ],
        "vocabulary": [
            {"word": w.word, "label": w.label or None, "end": w.end or None, "note": w.note}
            for w in vocabulary(e)
        ],
    }


def _describe(args: argparse.Namespace) -> int:
    """print a platform's labels C, J, L, configuration space P and body vocabulary

    Print C (core), J (joint locations), L (limbs, with the links each covers), the DOF count, P
    (joint limits) and the body vocabulary: which label answers each Motif/Labanotation body part
    (right_arm, upper_arm, forearm, left_leg, ...), read from the labels' aliases. PLATFORM is a
    shipped name or an .eurdf file.
    """
    from kinesphere.eurdf import load_eurdf
    from kinesphere.platforms.platform import load_platform, platform_names

    if args.platform == "all" and args.json:  # one JSON document: a list, one per platform
        every = [describe_dict(p.eurdf, p.base.kind) for p in map(load_platform, platform_names())]
        print(json.dumps(every, indent=2))
        return 0
    if args.platform == "all":
        for name in platform_names():
            args.platform = name
            _describe(args)
            print()
        return 0
    if args.platform.endswith((".eurdf", ".urdf", ".xml")) or Path(args.platform).is_file():
        eurdf, base = load_eurdf(args.platform), None
    else:
        platform = load_platform(args.platform)
        eurdf, base = platform.eurdf, platform.base.kind
    info = describe_dict(eurdf, base)
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    print(f"{info['name']}: {info['dof']} DOF" + (f", base {base}" if base else ""))
    print("C = {" + ", ".join(c["label"] for c in info["C"]) + "}")
    print("J = {" + ", ".join(j["label"] for j in info["J"]) + "}")
    print("L = {" + ", ".join(lb["label"] for lb in info["L"]) + "}")
    for c in info["C"]:
        print(f"  {c['label']:<10} {c['alias'] or '':<16} links: {', '.join(c['links'])}")
    for j in info["J"]:
        print(f"  {j['label']:<10} {j['alias'] or '':<16} joints: {', '.join(j['joints'])}")
    for lb in info["L"]:
        print(f"  {lb['label']:<10} {lb['alias'] or '':<16} from {lb['distal']}, tip {lb['tip']}")
        print(f"  {'':<27} joints: {', '.join(lb['joints'])}")
        print(f"  {'':<27} links:  {', '.join(lb['links'])}")
    print(f"P ({info['dof']} joints):")
    for p in info["P"]:
        lo = "-inf" if p["lower"] is None else f"{p['lower']:+.4f}"
        hi = "+inf" if p["upper"] is None else f"{p['upper']:+.4f}"
        vel = "inf" if p["velocity"] is None else f"{p['velocity']:.3f}"
        print(f"  {p['joint']:<18} {p['type']:<10} [{lo}, {hi}]  vmax {vel}")
    print("body vocabulary (Motif/Labanotation words -> labels):")
    for w in info["vocabulary"]:
        if w["label"]:
            to = w["label"] + (f" up to {w['end']}" if w["end"] else "")
            print(f"  {w['word']:<16} {to:<22} {w['note']}".rstrip())
    lacks = [w["word"] for w in info["vocabulary"] if not w["label"]]
    if lacks:
        print(f"  lacks: {', '.join(lacks)}")
    return 0
