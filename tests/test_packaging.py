"""The distribution installs under names of its own, and its declared dependencies match its imports."""
from __future__ import annotations

import ast
import sys
from importlib import metadata
from pathlib import Path

import tomllib

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
FOLDERS = {"electrosense.meshes": "meshes", "electrosense.bem": "bem", "electrosense.psm": "psm",
           "electrosense.validation": "validation"}
NOT_INSTALLED = {"validation/studies"}

# import name -> distribution name, where they differ
DISTRIBUTION = {"serial": "pyserial", "yaml": "pyyaml", "sklearn": "scikit-learn", "skimage": "scikit-image"}


def _package_folders() -> set[str]:
    """Every folder of ours with an __init__.py, as the dotted name it is installed under."""
    names = set()
    for prefix, folder in FOLDERS.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT)
            if any(rel.as_posix().startswith(p) for p in NOT_INSTALLED):
                continue
            names.add(".".join([prefix, *rel.parts[1:]]))
    return names


def test_every_package_folder_is_installed_under_electrosense():
    setuptools = PYPROJECT["tool"]["setuptools"]
    assert setuptools["package-dir"] == FOLDERS
    assert set(setuptools["packages"]) == _package_folders()


def test_nothing_generic_at_the_top_of_site_packages():
    top_level = {p.split(".")[0] for p in PYPROJECT["tool"]["setuptools"]["packages"]}
    assert top_level == {"electrosense"}
    assert PYPROJECT["project"]["scripts"] == {"esense": "electrosense.validation.cli:main"}


def _imported_top_level(paths) -> set[str]:
    found = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                found.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found.add(node.module.split(".")[0])
    return found


def _declared(requirements) -> set[str]:
    import re

    return {re.split(r"[\[<>=!~; ]", r, maxsplit=1)[0].lower() for r in requirements}


def test_declared_dependencies_match_the_imports():
    sources = [p for folder in FOLDERS.values() for p in (ROOT / folder).rglob("*.py")
               if not any(p.relative_to(ROOT).as_posix().startswith(n) for n in NOT_INSTALLED)]
    third_party = {m for m in _imported_top_level(sources)
                   if m not in sys.stdlib_module_names and m not in {"electrosense", "__future__"}}
    project = PYPROJECT["project"]
    declared = _declared(project["dependencies"])
    for extra in project.get("optional-dependencies", {}).values():
        declared |= _declared(extra)
    missing = {m for m in third_party if DISTRIBUTION.get(m, m).lower().replace("_", "-") not in
               {d.replace("_", "-") for d in declared}}
    assert not missing, f"imported but not declared in pyproject.toml: {sorted(missing)}"


def test_installed_metadata_names_the_command():
    eps = metadata.entry_points(group="console_scripts")
    assert any(ep.name == "esense" and ep.value == "electrosense.validation.cli:main" for ep in eps)
