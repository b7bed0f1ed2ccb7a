"""The platform registry: each folder with a ``platform.toml`` is one robot body.

Platforms are found by name among the shipped ones (``shipped/`` in this package), then in
the folders of the platform search path (``--platforms DIR`` or ``$KINESPHERE_PLATFORMS``; a
brought robot lives there, made by ``kinesphere platform new``), or opened by folder path. A
databank opened alone (``--db FILE``) names its platform, which must then be shipped or on
the search path.

A platform is its eURDF (the Body: labels and configuration space), its ``platform.toml``
(base kind, motion limits, the Place-Middle neutral pose) and, for the ECL, its ``vsam.toml``.
Loading validates the neutral pose against P so a bad edit cannot reach a running robot.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, get_args

import msgspec
import numpy as np

from kinesphere.cliargs import PLATFORMS_ENV
from kinesphere.configfile import load_toml
from kinesphere.errors import KinesphereError, did_you_mean
from kinesphere.eurdf import Eurdf, load_eurdf

PLATFORMS_DIR = Path(__file__).resolve().parent / "shipped"
BaseKind = Literal["fixed", "omni", "diff", "skid", "legged"]
BASE_KINDS: tuple[str, ...] = get_args(BaseKind)


# Bounds on every number of platform.toml: a negative or absurd limit is an error.
Height = Annotated[float, msgspec.Meta(ge=0, le=10, description="0..10 m")]
Speed = Annotated[float, msgspec.Meta(ge=0, le=100, description="0..100 m/s")]
YawRate = Annotated[float, msgspec.Meta(ge=0, le=100, description="0..100 rad/s")]
Acceleration = Annotated[float, msgspec.Meta(ge=0, le=1000, description="0..1000 m/s^2")]
Jerk = Annotated[float, msgspec.Meta(ge=0, le=10_000, description="0..10000 m/s^3")]
JointAcceleration = Annotated[
    float, msgspec.Meta(gt=0, le=1000, description="> 0 and <= 1000 rad/s^2 (m/s^2)")
]
JointJerk = Annotated[
    float, msgspec.Meta(gt=0, le=10_000, description="> 0 and <= 10000 rad/s^3 (m/s^3)")
]


class BaseSpec(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """How the core moves: not at all, omnidirectionally, differentially (diff/skid), or by
    walking (legged: abstracted as a holonomic planar base, the legs free to gesture).
    Also the ``[base]`` table of platform.toml, decoded as is."""

    kind: BaseKind = "fixed"
    height: Height = 0.0
    max_speed: Speed = 0.0
    max_yaw_rate: YawRate = 0.0
    max_acceleration: Acceleration = 0.0
    max_jerk: Jerk = 0.0

    @property
    def mobile(self) -> bool:
        return self.kind != "fixed"

    @property
    def holonomic(self) -> bool:
        return self.kind in ("omni", "legged")


class _PlatformTable(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    name: str | None = None
    title: str | None = None
    eurdf: str | None = None


class _MotionTable(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    max_acceleration: JointAcceleration = 4.0
    max_jerk: JointJerk = 40.0


class _PlatformFile(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """platform.toml as written; the neutral pose is checked against P after decoding."""

    platform: _PlatformTable = msgspec.field(default_factory=_PlatformTable)
    base: BaseSpec = msgspec.field(default_factory=BaseSpec)
    motion: _MotionTable = msgspec.field(default_factory=_MotionTable)
    neutral: dict[str, float] = {}


@dataclass(frozen=True)
class Platform:
    name: str
    title: str
    folder: Path
    eurdf: Eurdf
    base: BaseSpec
    max_acceleration: float
    max_jerk: float
    neutral: dict[str, float]

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.eurdf.joint_names

    def neutral_vector(self) -> np.ndarray:
        """Neutral pose in P order (unlisted joints at 0)."""
        return np.array([self.neutral.get(j, 0.0) for j in self.joint_names], dtype=float)

    @property
    def vsam_path(self) -> Path:
        return self.folder / "vsam.toml"

    @property
    def shipped(self) -> bool:
        """Part of this package (its databank is package data too)."""
        return self.folder.parent == PLATFORMS_DIR


def search_path() -> list[Path]:
    """The folders searched for platform folders after the shipped ones, in order."""
    return [Path(p).expanduser() for p in os.environ.get(PLATFORMS_ENV, "").split(os.pathsep) if p]


def platform_folders() -> dict[str, Path]:
    """Every platform known by name: shipped, then on the search path (a search-path folder
    may itself be one platform folder); the first of a name wins."""
    found: dict[str, Path] = {}
    for root in (PLATFORMS_DIR, *search_path()):
        if (root / "platform.toml").is_file():
            found.setdefault(root.resolve().name, root.resolve())
        elif root.is_dir():
            for p in sorted(root.iterdir()):
                if not p.name.startswith(".") and (p / "platform.toml").is_file():
                    found.setdefault(p.name, p.resolve())
    return found


def platform_names() -> list[str]:
    """Names of every known platform (shipped and on the search path), sorted."""
    return sorted(platform_folders())


def load_platform(name: str) -> Platform:
    """Load a platform by name (shipped or on the search path), or a platform folder by path."""
    folder = Path(name).expanduser()
    if (folder / "platform.toml").is_file():
        return _load(folder.resolve())
    known = platform_folders()
    found = known.get(name) or _any_case(name, known)
    if found is None:
        raise KinesphereError(
            "unknown_platform",
            f"unknown platform {name!r}{did_you_mean(name, known)}; valid platforms: "
            f"{', '.join(sorted(known))} (a platform folder is found by path, or by name in a "
            f"--platforms DIR / ${PLATFORMS_ENV} folder)",
        )
    return _load(found)


def platform_spelling(name: str) -> str:
    """A known platform's own spelling of ``name`` (any case), else ``name`` unchanged; for
    commands that pass the name on, to a databank, rather than load it."""
    known = platform_folders()
    if name in known:
        return name
    found = _any_case(name, known)
    return found.name if found is not None else name


def _any_case(name: str, known: dict[str, Path]) -> Path | None:
    """The one platform whose name equals ``name`` ignoring case (``PackBot``), if one does."""
    same = [folder for n, folder in known.items() if n.casefold() == name.strip().casefold()]
    return same[0] if len(same) == 1 else None


@functools.cache
def _load(folder: Path) -> Platform:
    path = folder / "platform.toml"
    cfg = load_toml(path, _PlatformFile, "platform file", code="invalid_eurdf")
    name = cfg.platform.name or folder.name
    eurdf = load_eurdf(folder / (cfg.platform.eurdf or f"{name}.eurdf"))
    neutral = cfg.neutral
    for joint, value in neutral.items():
        lim = eurdf.limits.get(joint)
        if lim is None:
            raise KinesphereError(
                "invalid_eurdf", f"{name}: neutral pose names {joint!r}, which is not in P"
            )
        if not (lim.lower <= value <= lim.upper) or not math.isfinite(value):
            raise KinesphereError(
                "invalid_eurdf",
                f"{name}: neutral {joint}={value} is outside [{lim.lower}, {lim.upper}]",
            )
    for joint, lim in eurdf.limits.items():
        if joint not in neutral and not lim.lower <= 0.0 <= lim.upper:
            raise KinesphereError(
                "invalid_eurdf", f"{name}: neutral pose must set {joint} (0 is outside its limits)"
            )
    return Platform(
        name=name,
        title=cfg.platform.title or name,
        folder=folder,
        eurdf=eurdf,
        base=cfg.base,
        max_acceleration=cfg.motion.max_acceleration,
        max_jerk=cfg.motion.max_jerk,
        neutral=dict(neutral),
    )
