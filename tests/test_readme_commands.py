"""The README's quick-start lines work as a user types them, and CI runs the very same test line.

Plain ``pytest`` does not put the checkout on ``sys.path``; ``python -m pytest`` does. A test that
imports a source folder by its bare name (``import bem``) therefore passes one way and fails the
other: these tests look for such imports and collect the suite both ways.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCE_FOLDERS = ("meshes", "bem", "psm", "validation")
# `import bem`, `from psm.images import ...`, `__import__("meshes")`: in code, docstrings and `python -c` strings;
# `pytest.importorskip("psm")` too, which under plain pytest skips its whole module in silence (two modules did)
_NAMES = "|".join(SOURCE_FOLDERS)
BARE_IMPORT = re.compile(rf"""(?:^|[;"'(]|>>>)\s*(?:from|import)\s+(?:{_NAMES})(?!\w)"""
                         rf"""|(?:__import__|importorskip)\(\s*["'](?:{_NAMES})(?!\w)""")


def quick_start_lines(readme: Path = ROOT / "README.md") -> list[str]:
    """The commands of the README's *Quick start* code block, one a line."""
    text = readme.read_text(encoding="utf-8")
    m = re.search(r"^## Quick start.*?^```[^\n]*\n(.*?)^```", text, re.MULTILINE | re.DOTALL)
    assert m, "README.md has no '## Quick start' section with a code block"
    return [line.strip() for line in m.group(1).splitlines() if line.strip()]


def test_quick_start_is_an_install_and_run_line_and_a_test_line():
    lines = quick_start_lines()
    assert len(lines) == 2, lines
    assert lines[0].startswith("pip install -e . && esense ")
    assert lines[1].startswith('pip install -e ".[test]" && ') and lines[1].endswith("pytest")


def test_ci_runs_the_readmes_test_line_as_written():
    test_line = quick_start_lines()[1]
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    commands = [line.strip() for line in ci.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    assert test_line in commands, f".ci/run does not run the README's test line {test_line!r}"
    assert commands[-1] == test_line, ".ci/run must end with the README's test line (its exit status is CI's)"


def test_bare_import_pattern():
    hits = ["import bem", "from psm.images import x", '__import__("meshes")', "python -c 'from validation.cli import main'",
            ">>> from meshes.cylinder_tank import CylinderTank", 'psm = pytest.importorskip("psm")']
    misses = ["from electrosense import bem", "from electrosense.bem import x", "import bempp.api", "import psmx", "from electrosense import psm",
              "# the bem solves", "imports validation data", 'pytest.importorskip("bempp_cl")',
              'pytest.importorskip("electrosense.meshes.sensor_mesh")']
    assert all(BARE_IMPORT.search(s) for s in hits)
    assert not any(BARE_IMPORT.search(s) for s in misses)


@pytest.mark.parametrize("folder", ["tests", *SOURCE_FOLDERS])
def test_no_source_folder_is_imported_by_its_bare_name(folder):
    """Only ``electrosense.<package>`` is installed: a bare ``bem`` works only where the checkout is on sys.path."""
    offenders = []
    for path in sorted((ROOT / folder).rglob("*.py")):
        if path.resolve() == Path(__file__).resolve():
            continue
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if BARE_IMPORT.search(line):
                offenders.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not offenders, "imports of a source folder by its bare name:\n" + "\n".join(offenders)


def _collected(cmd: list[str]) -> tuple[int, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTEST_ADDOPTS")}
    p = subprocess.run([*cmd, "--collect-only", "-q", "-p", "no:cacheprovider"], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=300)
    m = re.search(r"(\d+)(?:/\d+)? tests? collected|^(\d+) tests? ", p.stdout, re.MULTILINE)
    assert p.returncode == 0, f"{' '.join(cmd)} --collect-only exits {p.returncode}:\n{p.stdout[-3000:]}{p.stderr[-2000:]}"
    return int(next(g for g in m.groups() if g)) if m else -1, p.stdout


def test_plain_pytest_and_python_m_pytest_collect_the_same_tests():
    """The README's ``pytest`` (console script: checkout not on sys.path) and ``python -m pytest`` (checkout on it)."""
    script = Path(sys.executable).parent / "pytest"
    script = str(script) if script.exists() else shutil.which("pytest")
    if script is None:
        pytest.skip("no pytest console script beside this Python")
    n_plain, out_plain = _collected([script])
    n_module, _ = _collected([sys.executable, "-m", "pytest"])
    assert n_plain > 0 and n_plain == n_module, out_plain[-3000:]
