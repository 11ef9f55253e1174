"""The repository's scripts/ as modules the tests call into."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

REPO = Path(__file__).resolve().parents[2]


def script_module(name: str) -> ModuleType:
    """scripts/NAME.py loaded afresh as a module named NAME (imported, not run as a script)."""
    spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
