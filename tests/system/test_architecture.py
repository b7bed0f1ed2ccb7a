"""docs/architecture.md and the layer contracts cannot drift from the tree: the module map
lists exactly the modules that exist, with their layer; the main loops it names exist; the
"core imports no role" contract names every core module."""

from __future__ import annotations

import re
import tomllib

from support.names import MISSING, resolve
from support.paths import ROOT

DOC = ROOT / "docs" / "architecture.md"
LAYERS = ("core", "platforms", "robots", "services", "clients", "deploy")


def tree_modules() -> dict[str, str]:
    """Every module of the six distributions (``__init__`` excluded) -> its layer."""
    out: dict[str, str] = {}
    for layer in LAYERS:
        dist = ROOT if layer == "core" else ROOT / layer  # the distribution's folder
        package = dist / "kinesphere" if layer == "core" else dist / "kinesphere" / layer
        files = package.glob("*.py") if layer == "core" else package.rglob("*.py")
        for f in files:
            if f.name != "__init__.py":
                out[".".join(f.relative_to(dist).with_suffix("").parts)] = layer
    return out


def section(title: str) -> str:
    text = DOC.read_text(encoding="utf-8")
    start = text.index(f"\n## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end >= 0 else len(text)]


def test_the_tree_has_every_layer_and_no_core_init() -> None:
    modules = tree_modules()
    assert set(modules.values()) == set(LAYERS)
    assert "kinesphere.protocol" in modules and "kinesphere.robots.agent.runtime" in modules
    assert "kinesphere.platforms.platform" in modules
    assert not (ROOT / "kinesphere" / "__init__.py").exists()  # PEP 420: never add one


def test_module_map_lists_exactly_the_modules_of_the_tree_with_their_layer() -> None:
    rows = re.findall(r"^\| `(kinesphere[\w.]*)` \| (\w+) \| (.+) \|$", section("Module map"),
                      flags=re.M)
    documented = {name: layer for name, layer, _ in rows}
    assert len(documented) == len(rows), "a module has two rows"
    modules = tree_modules()
    missing = sorted(set(modules) - set(documented))
    stale = sorted(set(documented) - set(modules))
    assert not missing, f"add a row to docs/architecture.md's module map for: {missing}"
    assert not stale, f"docs/architecture.md lists modules that do not exist: {stale}"
    wrong = {n: (documented[n], modules[n]) for n in modules if documented[n] != modules[n]}
    assert not wrong, f"layer (documented, actual): {wrong}"
    assert all(holds.strip() for _, _, holds in rows)


def test_every_main_loop_and_module_the_processes_table_names_exists() -> None:
    names = re.findall(r"`(kinesphere\.[\w.]+)`", section("Processes and their main loops"))
    assert len(names) >= 8
    for dotted in names:
        assert resolve(dotted) is not MISSING, dotted


def test_the_core_contract_lists_every_core_module() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    contracts = config["tool"]["importlinter"]["contracts"]
    (core,) = [c for c in contracts if c["name"] == "The core imports no role"]
    listed = set(core["source_modules"])
    modules = {n for n, layer in tree_modules().items() if layer == "core"}
    assert listed == modules, (
        f"pyproject.toml 'The core imports no role': add {sorted(modules - listed)}, "
        f"remove {sorted(listed - modules)}"
    )
    roles = {f"kinesphere.{layer}" for layer in LAYERS if layer != "core"}
    assert set(core["forbidden_modules"]) == roles
