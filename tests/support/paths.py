"""Where things are: the repository, the test data, the reference tables."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
"""The repository's top folder (the working directory of every process a test starts)."""
DATA = ROOT / "tests" / "data"
TOY = DATA / "toyarm"
"""A three-limb toy platform folder (eURDF, platform.toml, vsam.toml) made for the tests."""
DEPLOY = ROOT / "deploy"
REFERENCE = ROOT.parent / "shared" / "reference" / "robots"
"""The reference joint tables (``shared/`` beside the repository, as on CI)."""
TOY_EURDF = TOY / "toyarm.eurdf"
LABAN_EDITOR = ROOT / "tests" / "third_party" / "labanotationsuite" / "labanProcessor.py"
"""LabanEditor's own ``labanProcessor.py`` (Microsoft's LabanotationSuite, vendored unchanged
with its MIT licence): the oracle a notation cell is checked against."""
