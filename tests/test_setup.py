"""Set-up runs on a bare Python, and installs what the lock file pins.

``make`` runs scripts/ensure_llvm.py and ensure_optional.py (slurm, chromium) with the machine's own
python3 before the virtual environment exists: on a bare Debian that python3 has nothing
but the standard library. These tests hold that promise two ways: statically (every import
of those files is the standard library's) and by running them under ``python3 -I -S``, which
hides every site-packages directory, so numpy cannot be found even where it is installed.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: What make runs before .venv exists, and the project file ensure_llvm loads by path.
PRE_VENV = [
    "scripts/ensure_llvm.py",
    "scripts/ensure_optional.py",
    "pipeline/render/libllvm.py",
]


def _imported_top_names(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("rel", PRE_VENV)
def test_what_make_runs_before_the_venv_imports_the_standard_library_only(rel):
    foreign = _imported_top_names(REPO / rel) - set(sys.stdlib_module_names) - {"__future__"}
    assert not foreign, f"{rel} imports {sorted(foreign)}: make runs it before .venv exists"


@pytest.mark.parametrize(
    "script", ["scripts/ensure_llvm.py", "scripts/ensure_optional.py slurm", "scripts/ensure_optional.py chromium"]
)
def test_the_set_up_scripts_run_with_no_site_packages(script, tmp_path):
    """``-I -S``: no site-packages, no PYTHONPATH, no user site; cwd elsewhere."""
    path, *args = script.split()
    run = subprocess.run(
        [sys.executable, "-I", "-S", str(REPO / path), *args], cwd=tmp_path, capture_output=True, text=True, timeout=600
    )
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr and "ModuleNotFoundError" not in run.stderr, run.stderr
    if script.endswith("ensure_llvm.py"):
        assert "libLLVM for drjit: " in run.stdout


def _locked() -> dict[str, str]:
    """name -> version of every requirement of requirements.lock that applies to this Python."""
    pins: dict[str, str] = {}
    for line in (REPO / "requirements.lock").read_text().splitlines():
        match = re.match(r"^([A-Za-z0-9_.\-]+)==([^\s;\\]+)\s*(?:;\s*([^\\]+?))?\s*\\?$", line)
        if not match:
            continue
        name, version, marker = match.groups()
        if marker and not _marker_holds(marker):
            continue
        pins[_canonical(name)] = version
    return pins


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _marker_holds(marker: str) -> bool:
    from packaging.markers import Marker

    return Marker(marker).evaluate()


def test_every_locked_requirement_carries_a_hash_and_the_lock_covers_the_dependencies():
    text = (REPO / "requirements.lock").read_text()
    blocks = re.split(r"\n(?=[A-Za-z0-9])", text.split("\n", 3)[-1])
    for block in blocks:
        if "==" in block.splitlines()[0]:
            assert "--hash=sha256:" in block, block.splitlines()[0]
    pins = _locked()
    import tomllib

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    wanted = project["dependencies"] + project["optional-dependencies"]["dev"]
    for requirement in wanted:
        name = _canonical(re.split(r"[<>=~!\[ ;]", requirement, maxsplit=1)[0])
        assert name in pins, f"{name} (pyproject.toml) is not in requirements.lock: run `make lock`"


def test_this_environment_has_exactly_the_locked_versions():
    """What `make` installed is what the lock pins (a stale .venv is rebuilt by make)."""
    from importlib import metadata

    pins = _locked()
    wrong = {}
    for name, version in pins.items():
        try:
            installed = metadata.version(name)
        except metadata.PackageNotFoundError:
            wrong[name] = (version, None)
            continue
        if installed != version:
            wrong[name] = (version, installed)
    assert not wrong, f"locked vs installed: {wrong}; run `make setup` (or `make lock` after changing pyproject.toml)"
