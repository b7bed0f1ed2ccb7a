"""Each host installs only its role: a fresh venv per host, built from this checkout's wheels
(built once, in one environment holding their build requirements) with ``-c
constraints.txt``, runs its commands, lacks the others' (with a clear message), and holds none
of the packages that host must not carry. The dependencies are fetched once, into the
wheelhouse beside this checkout's wheels, and every host installs from there alone (pip still
resolves each host's own set), so four hosts do not download the same wheels four times."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

from kinesphere.cli import ROLE_COMMANDS, _command_word, build_parser, commands, missing_role
from support.paths import ROOT
from support.venvs import clean_env, fresh_venv, pip_install

pytestmark = pytest.mark.processes

DISTS = {".": "kinesphere", "platforms": "kinesphere-platforms", "robots": "kinesphere-robots",
         "services": "kinesphere-services", "clients": "kinesphere-clients",
         "deploy": "kinesphere-deploy"}
INSTALL_TIMEOUT_S = 600


@dataclass(frozen=True)
class Host:
    parts: tuple[str, ...]
    """Folders of this checkout it installs (their distributions, see DISTS)."""
    smoke: tuple[tuple[tuple[str, ...], str], ...]
    """(arguments, text the output must contain): each must exit 0."""
    absent: tuple[str, ...]
    """Distributions this host must not carry."""
    lacks: tuple[str, str]
    """(a command of a role not installed here, the distribution it names)."""


HOSTS = {
    "robot": Host(
        (".", "platforms", "robots"),
        ((("agent", "--help"), "--body"), (("describe", "baxter"), "baxter: 14 DOF"),
         (("platforms",), "youbot")),
        ("pygame", "mink", "matplotlib"),
        ("gamepad", "kinesphere-clients"),
    ),
    "operator": Host(
        (".", "clients"),
        ((("send", "--help"), "--drive"), (("gamepad", "--help"), "deadman"),
         (("play", "--help"), "left_high")),
        ("mujoco", "mink", "ruckig", "matplotlib", "kinesphere-platforms"),
        ("agent", "kinesphere-robots"),
    ),
    "databank": Host(
        (".", "platforms", "services"),
        ((("query", "--help"), "--catalogue"),
         (("ecl", "get", "baxter", "right_arm", "right_shoulder", "left-high", "far"),
          "right_s0"),
         (("describe", "baxter"), "baxter: 14 DOF")),
        ("pygame", "matplotlib", "ruckig", "kinesphere-robots"),
        ("send", "kinesphere-clients"),
    ),
    "router": Host(
        (".", "deploy"),
        ((("router", "--help"), "--config"), (("status", "--help"), "--timeout")),
        ("mujoco", "pygame", "mink", "ruckig", "matplotlib", "kinesphere-platforms"),
        ("databank", "kinesphere-services"),
    ),
}


def _run(cmd: list[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=cwd, env=clean_env(), capture_output=True, text=True,
                          timeout=timeout)


def _install(name: str, host: Host, wheels: dict[str, Path], base: Path) -> Path:
    venv = base / name
    python = fresh_venv(venv, INSTALL_TIMEOUT_S)
    done = pip_install(python, ["-c", str(ROOT / "constraints.txt"), "--no-index",
                                "--find-links", str(base / "wheels"),
                                *(str(wheels[DISTS[p]]) for p in host.parts)],
                       base, INSTALL_TIMEOUT_S)
    assert done.returncode == 0, f"{name} host: pip failed:\n{done.stdout}\n{done.stderr}"
    return venv


def _build_env(venv: Path) -> Path:
    """One venv holding what every distribution's ``[build-system] requires`` names, for
    their wheels to be built in (pip's isolation would make six such environments, installing
    the backend six times: 7.9 against 3.2 CPU-s, medians of three); its Python is returned."""
    requires = set()
    for part in DISTS:
        with open(ROOT / part / "pyproject.toml", "rb") as fh:
            requires.update(tomllib.load(fh)["build-system"]["requires"])
    python = fresh_venv(venv, INSTALL_TIMEOUT_S)
    done = pip_install(python, sorted(requires), venv.parent, INSTALL_TIMEOUT_S)
    assert done.returncode == 0, f"pip could not install {sorted(requires)}:\n{done.stderr}"
    return python


@pytest.fixture(scope="module")
def venvs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Path]]:
    """One venv per host, installed concurrently from wheels built and fetched once."""
    base = tmp_path_factory.mktemp("hosts")
    builder = _build_env(base / "build")
    built = _run([sys.executable, "-m", "pip", "--python", str(builder), "wheel", "--quiet",
                  "--no-deps", "--no-build-isolation", "-w", str(base / "wheels"),
                  *(str(ROOT / p) for p in DISTS)], base, 300)
    assert built.returncode == 0, built.stderr
    wheels = {}
    for dist in DISTS.values():
        (wheel,) = (base / "wheels").glob(f"{dist.replace('-', '_')}-*.whl")
        wheels[dist] = wheel
    fetched = _run([sys.executable, "-m", "pip", "download", "--quiet", "-d", str(base / "wheels"),
                    "-c", str(ROOT / "constraints.txt"), *map(str, wheels.values())], base,
                   INSTALL_TIMEOUT_S)
    assert fetched.returncode == 0, f"pip download failed:\n{fetched.stdout}\n{fetched.stderr}"
    with ThreadPoolExecutor(len(HOSTS)) as pool:
        jobs = {n: pool.submit(_install, n, h, wheels, base) for n, h in HOSTS.items()}
        yield {n: job.result() for n, job in jobs.items()}


def _installed(venv: Path) -> dict[str, int]:
    """Distribution name -> bytes of its installed files, as the venv sees them."""
    code = (
        "import importlib.metadata as m, json, os\n"
        "out = {}\n"
        "for d in m.distributions():\n"
        "    files = [f.locate() for f in d.files or ()]\n"
        "    out[d.metadata['Name'].lower()] = sum(os.path.getsize(f) for f in files"
        " if os.path.isfile(f))\n"
        "print(json.dumps(out))\n"
    )
    done = _run([str(venv / "bin" / "python"), "-c", code], venv)
    assert done.returncode == 0, done.stderr
    sizes: dict[str, int] = json.loads(done.stdout)
    return sizes


@pytest.mark.parametrize("name", sorted(HOSTS))
def test_each_host_runs_its_role_and_only_its_role(name: str, venvs: dict[str, Path]) -> None:
    host, venv = HOSTS[name], venvs[name]
    kinesphere = str(venv / "bin" / "kinesphere")
    dists = {DISTS[p] for p in host.parts}

    helped = _run([kinesphere, "--help"], venv)
    assert helped.returncode == 0, helped.stderr
    expected = {"label", *(c for d in dists if d in ROLE_COMMANDS for c in ROLE_COMMANDS[d])}
    listed = {line.split()[0] for line in helped.stdout.split("COMMAND\n", 2)[-1].splitlines()
              if line.startswith("    ") and not line.startswith("     ")}
    assert listed == expected, helped.stdout

    for args, shows in host.smoke:
        done = _run([kinesphere, *args], venv)
        assert done.returncode == 0, f"kinesphere {' '.join(args)}:\n{done.stderr}"
        assert shows in done.stdout, f"kinesphere {' '.join(args)}:\n{done.stdout}"

    command, dist = host.lacks
    refused = _run([kinesphere, command, "--help"], venv)
    assert refused.returncode == 2
    assert f"'kinesphere {command}' comes with {dist}" in refused.stderr
    assert "Traceback" not in refused.stderr

    sizes = _installed(venv)
    assert dists <= set(sizes)
    carried = sorted(set(host.absent) & set(sizes))
    assert not carried, f"the {name} host must not install {carried}"
    print(f"\n{name} host ({' + '.join(sorted(dists))}): {len(sizes)} distributions, "
          f"{sum(sizes.values()) / 1e6:.0f} MB (without bytecode)")


def test_up_names_what_a_router_host_lacks(venvs: dict[str, Path]) -> None:
    venv = venvs["router"]
    done = _run([str(venv / "bin" / "kinesphere"), "up", "--headless"], venv)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    for dist in ("kinesphere-platforms", "kinesphere-robots", "kinesphere-services",
                 "kinesphere-clients", "matplotlib"):
        assert dist in done.stderr
    assert "kinesphere-deploy[up]" in done.stderr


def test_film_names_what_a_router_host_lacks(venvs: dict[str, Path]) -> None:
    venv = venvs["router"]
    done = _run([str(venv / "bin" / "kinesphere"), "film", "left_high"], venv)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    for dist in ("kinesphere-platforms", "kinesphere-robots", "kinesphere-services",
                 "imageio-ffmpeg"):
        assert dist in done.stderr
    assert "kinesphere-deploy[up]" in done.stderr


def test_role_commands_name_every_registered_command_and_its_distribution() -> None:
    """The core's list of which distribution brings which command matches what the
    installed roles register (everything is installed here)."""
    from importlib.metadata import entry_points

    parser = build_parser()
    offered = commands(parser)
    registered: dict[str, set[str]] = {}
    for ep in entry_points(group="kinesphere.commands"):
        assert ep.dist is not None
        sub = argparse.ArgumentParser().add_subparsers()
        ep.load()(sub)
        registered.setdefault(ep.dist.metadata["Name"], set()).update(sub.choices)
    assert {d: set(c) for d, c in ROLE_COMMANDS.items()} == registered
    assert set(offered) == {"label"} | {c for cs in registered.values() for c in cs}


def test_a_missing_role_is_named_whatever_options_come_first() -> None:
    parser = build_parser()
    assert _command_word(parser, ["--platforms", "/tmp/p", "agent", "--help"]) == "agent"
    assert _command_word(parser, ["-v", "send", "all"]) == "send"
    message = missing_role("agent", ["label", "send"])
    assert message is not None and "kinesphere-robots" in message and "label, send" in message
    assert missing_role("agent", ["agent"]) is None
    assert missing_role("no-such-command", ["label"]) is None  # argparse explains that one


def test_the_parser_of_every_role_imports_no_numerics() -> None:
    """``kinesphere --help`` builds the parser of every installed role (a command, its own
    role's); that costs no NumPy, Ruckig, MuJoCo, yourdfpy nor SciPy, which a client's
    command never needs (here, where every role is installed)."""
    code = ("import sys\nfrom kinesphere.cli import build_parser\nbuild_parser()\n"
            "print(sorted(m for m in ('numpy', 'ruckig', 'mujoco', 'yourdfpy', 'scipy')"
            " if m in sys.modules))")
    done = _run([sys.executable, "-c", code], ROOT)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout


def test_a_command_line_holds_its_role_alone_and_parses_as_the_whole_one() -> None:
    """A process builds only the role that brings its command (the others' modules unread);
    each command's help, hence its options, is the same as in the whole command line. An
    unknown word gets the whole line, for argparse to list every command."""
    whole = commands(build_parser())
    for names in ROLE_COMMANDS.values():
        for name in names:
            alone = commands(build_parser(name))
            assert set(alone) == {"label", *names}, name
            assert alone[name].format_help() == whole[name].format_help(), name
    assert set(commands(build_parser("label"))) == {"label"}
    assert set(commands(build_parser("agnet"))) == set(whole)
    assert set(commands(build_parser(None))) == set(whole)
