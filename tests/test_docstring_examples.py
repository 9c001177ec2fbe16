"""Every docstring example of the installed packages runs and prints what it says.

The examples are collected from the source folders (bem/, psm/, meshes/, validation/) and run in
their module's namespace, as ``python -m doctest`` would; the studies are scripts outside the
installed package and are not collected.
"""
from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("meshes", "bem", "psm", "validation")
NOT_INSTALLED = ("validation/studies",)


def _module_names() -> list[str]:
    names = []
    for top in PACKAGES:
        for path in sorted((ROOT / top).rglob("*.py")):
            rel = path.relative_to(ROOT)
            if any(rel.as_posix().startswith(p) for p in NOT_INSTALLED):
                continue
            parts = list(rel.with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            names.append("electrosense." + ".".join(parts))
    return names


def _with_examples(name: str) -> bool:
    path = ROOT / Path(*name.split(".")[1:])
    source = (path / "__init__.py" if path.is_dir() else path.with_suffix(".py")).read_text(encoding="utf-8")
    return ">>>" in source


@pytest.mark.parametrize("name", [n for n in _module_names() if _with_examples(n)])
def test_docstring_examples(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write files write them here
    module = importlib.import_module(name)
    tests = doctest.DocTestFinder(exclude_empty=True).find(module, name)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples in {name} failed (see output above)"
