"""Fresh virtual environments the tests install into (a role's host, the ROS 2 peer with
another eclipse-zenoh): made without a pip of their own and filled by this interpreter's pip
(``pip --python``), compiling nothing ahead, with neither this run's venv nor its path."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path


def clean_env() -> dict[str, str]:
    """This process's environment without its venv and path (what a fresh shell would have)."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    return env


def fresh_venv(venv: Path, timeout: float) -> Path:
    """Make ``venv`` (emptied if it exists) without pip; its Python."""
    made = subprocess.run([sys.executable, "-m", "venv", "--clear", "--without-pip", str(venv)],
                          env=clean_env(), capture_output=True, text=True, timeout=timeout)
    assert made.returncode == 0, f"could not make the venv {venv}:\n{made.stderr}"
    return venv / "bin" / "python"


def pip_install(python: Path, args: Sequence[str], cwd: Path,
                timeout: float) -> subprocess.CompletedProcess[str]:
    """``pip install --quiet --no-compile ARGS`` into the venv of ``python``."""
    return subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install",
                           "--quiet", "--no-compile", *args], cwd=cwd, env=clean_env(),
                          capture_output=True, text=True, timeout=timeout)
