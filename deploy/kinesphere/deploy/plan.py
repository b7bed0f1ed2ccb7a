"""What ``kinesphere up`` runs: the robots, the phrases and the options, parsed from its flags.

Kept apart from :mod:`kinesphere.deploy.up` (which runs the plan) so the command line reads its
defaults from :class:`UpOptions` without loading Zenoh, rich or numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from importlib.util import find_spec
from pathlib import Path

from kinesphere.errors import KinesphereError, did_you_mean
from kinesphere.keyexpr import DEFAULT_PREFIX, Keys

DEFAULT_ROBOTS = ("baxter", "nao", "youbot", "packbot")
START_TIMEOUT_S = 120.0
PHRASE_TIMEOUT_S = 90.0


@dataclass(frozen=True)
class PlannedRobot:
    platform: str
    robot_id: str


@dataclass(frozen=True)
class PlannedPhrase:
    path: Path
    target: str  # a robot id, a group, or "all"


@dataclass
class UpOptions:
    robots: list[PlannedRobot]
    phrases: list[PlannedPhrase]
    out: Path = Path("out")
    headless: bool = False
    keep_running: bool = False
    prefix: str = DEFAULT_PREFIX
    start_timeout: float = START_TIMEOUT_S
    phrase_timeout: float = PHRASE_TIMEOUT_S
    databanks: list[str] = field(default_factory=list)  # PLATFORM=PATH for databank --db
    extra_agent_args: list[str] = field(default_factory=list)


def parse_robots(text: str) -> list[PlannedRobot]:
    """``baxter,nao`` or ``baxter:left,baxter:right``: ids default to the platform name."""
    from kinesphere.platforms.platform import platform_names, platform_spelling

    robots: list[PlannedRobot] = []
    seen: dict[str, int] = {}
    for item in (s.strip() for s in text.split(",")):
        if not item:
            continue
        platform, _, rid = item.partition(":")
        platform = platform_spelling(platform)  # 'PackBot' is packbot
        if not rid:
            seen[platform] = seen.get(platform, 0) + 1
            rid = platform if seen[platform] == 1 else f"{platform}-{seen[platform]}"
        robots.append(PlannedRobot(platform, rid))
    ids = [r.robot_id for r in robots]
    if not robots or len(set(ids)) != len(ids):
        raise KinesphereError("malformed", f"--robots needs distinct robots, got {text!r}")
    known = platform_names()
    for r in robots:
        Keys().command(r.robot_id)  # a valid key segment
        if r.platform not in known and not Path(r.platform).is_dir():
            raise KinesphereError(
                "unknown_platform", f"unknown platform {r.platform!r}"
                f"{did_you_mean(r.platform, known)}; valid: {', '.join(known)}")
    return robots


def parse_phrase(spec: str) -> PlannedPhrase:
    """``FILE`` (played on every robot) or ``FILE@ROBOT``."""
    path, _, target = spec.rpartition("@") if "@" in spec else (spec, "", "all")
    p = Path(path)
    if not p.is_file():
        raise KinesphereError("malformed", f"phrase file {p} does not exist")
    return PlannedPhrase(p, target or "all")


def shipped_phrases_dir() -> Path:
    """The phrases the client distribution ships (``kinesphere up`` plays them with it)."""
    try:
        return Path(str(resources.files("kinesphere.clients.orders") / "phrases"))
    except ModuleNotFoundError:
        raise KinesphereError(
            "unavailable", "kinesphere up plays phrases: install kinesphere-clients too"
        ) from None


def default_phrases(
    robots: list[PlannedRobot], phrases_dir: Path | None = None
) -> list[PlannedPhrase]:
    """The paper's Left-High example on every robot, then the PackBot sweep on each packbot."""
    phrases_dir = phrases_dir or shipped_phrases_dir()
    out: list[PlannedPhrase] = []
    left_high = sorted(phrases_dir.glob("*left*high*.toml"))
    if left_high:
        out.append(PlannedPhrase(left_high[0], "all"))
    sweep = phrases_dir / "packbot_sweep.toml"
    if sweep.is_file():
        out += [PlannedPhrase(sweep, r.robot_id) for r in robots if r.platform == "packbot"]
    if not out:
        raise KinesphereError("malformed", f"no demo phrases found in {phrases_dir}")
    return out


UP_NEEDS = {
    "kinesphere.platforms": "kinesphere-platforms",
    "kinesphere.robots": "kinesphere-robots",
    "kinesphere.services": "kinesphere-services",
    "kinesphere.clients": "kinesphere-clients",
    "matplotlib": "matplotlib",
}
"""What ``kinesphere up`` imports (module: distribution): it runs every role on one machine."""

FILM_NEEDS = {
    "kinesphere.platforms": "kinesphere-platforms",
    "kinesphere.robots": "kinesphere-robots",
    "kinesphere.services": "kinesphere-services",
    "kinesphere.clients": "kinesphere-clients",
    "PIL": "pillow",
    "imageio_ffmpeg": "imageio-ffmpeg",
}
"""What ``kinesphere film`` imports: the agent's controller, the ECL, the phrases, the encoders."""


def check_installed(why: str = "kinesphere up runs every role on this machine",
                    needs: dict[str, str] | None = None) -> None:
    """Name what a command of the ``up`` extra lacks on this host, before anything starts."""
    needs = UP_NEEDS if needs is None else needs
    missing = [dist for module, dist in needs.items() if find_spec(module) is None]
    if missing:
        raise KinesphereError(
            "unavailable",
            f"{why}; not installed: {', '.join(missing)}"
            " (install them with: pip install 'kinesphere-deploy[up]')",
        )
