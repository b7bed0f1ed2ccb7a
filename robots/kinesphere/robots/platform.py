"""The platform registry: each folder under ``platforms/`` is one robot body.

A platform is its eURDF (the Body: labels and configuration space), its ``platform.toml``
(base kind, motion limits, the Place-Middle neutral pose) and, for the ECL, its ``vsam.toml``.
Loading validates the neutral pose against P so a bad edit cannot reach a running robot.
"""

from __future__ import annotations

import functools
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from kinesphere.errors import KinesphereError
from kinesphere.eurdf import Eurdf, load_eurdf

PLATFORMS_DIR = Path(__file__).resolve().parent / "platforms"
BASE_KINDS = ("fixed", "omni", "diff", "skid")


@dataclass(frozen=True)
class BaseSpec:
    """How the core moves: not at all, omnidirectionally, or differentially (diff/skid)."""

    kind: str
    height: float
    max_speed: float
    max_yaw_rate: float
    max_acceleration: float
    max_jerk: float

    @property
    def mobile(self) -> bool:
        return self.kind != "fixed"

    @property
    def holonomic(self) -> bool:
        return self.kind == "omni"


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


def platform_names() -> list[str]:
    """Names of the shipped platforms, sorted."""
    return sorted(p.name for p in PLATFORMS_DIR.iterdir() if (p / "platform.toml").is_file())


def load_platform(name: str) -> Platform:
    """Load a shipped platform by name, or a platform folder by path."""
    folder = Path(name)
    if not (folder / "platform.toml").is_file():
        if name not in platform_names():
            raise KinesphereError(
                "unknown_platform",
                f"unknown platform {name!r}; valid platforms: {', '.join(platform_names())}",
            )
        folder = PLATFORMS_DIR / name
    return _load(folder.resolve())


@functools.cache
def _load(folder: Path) -> Platform:
    with open(folder / "platform.toml", "rb") as fh:
        cfg: dict[str, Any] = tomllib.load(fh)
    meta = cfg.get("platform", {})
    name = str(meta.get("name", folder.name))
    eurdf = load_eurdf(folder / str(meta.get("eurdf", f"{name}.eurdf")))
    b = cfg.get("base", {})
    base = BaseSpec(
        kind=str(b.get("kind", "fixed")),
        height=float(b.get("height", 0.0)),
        max_speed=float(b.get("max_speed", 0.0)),
        max_yaw_rate=float(b.get("max_yaw_rate", 0.0)),
        max_acceleration=float(b.get("max_acceleration", 0.0)),
        max_jerk=float(b.get("max_jerk", 0.0)),
    )
    if base.kind not in BASE_KINDS:
        raise KinesphereError(
            "invalid_eurdf", f"{folder}/platform.toml: base kind {base.kind!r} not in {BASE_KINDS}"
        )
    motion = cfg.get("motion", {})
    neutral = {str(k): float(v) for k, v in cfg.get("neutral", {}).items()}
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
        title=str(meta.get("title", name)),
        folder=folder,
        eurdf=eurdf,
        base=base,
        max_acceleration=float(motion.get("max_acceleration", 4.0)),
        max_jerk=float(motion.get("max_jerk", 40.0)),
        neutral=neutral,
    )
