"""Finding a libLLVM that drjit's LLVM backend can use: the standard library only.

``make`` runs ``scripts/ensure_llvm.py`` before the virtual environment exists, with
whatever ``python3`` the machine has (on a bare Debian: the system's, with no numpy). That
script loads this file by its path, so it must import nothing but the standard library and
nothing of the project (tests/test_setup.py runs it under ``python3 -I -S``).
"""

from __future__ import annotations

import glob
import os
import re

#: libLLVM majors below this crash drjit 1.5's LLVM backend (15 measured here).
MIN_LLVM_MAJOR = 16

SEARCH_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
    "/usr/local/opt/llvm/lib/libLLVM*.dylib",
)

INSTALL_HINT = (
    f"drjit's LLVM backend needs libLLVM >= {MIN_LLVM_MAJOR} (19 is tested). On Debian 12: "
    "`sudo apt-get install libllvm19`; elsewhere install LLVM 16-19 and set "
    "DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so"
)


def _llvm_major(path: str) -> int | None:
    name = os.path.basename(path)
    match = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", name)
    return int(match.group(1)) if match else None


def find_libllvm(globs: tuple[str, ...] = SEARCH_GLOBS) -> str | None:
    """Return the path of the newest libLLVM with major >= MIN_LLVM_MAJOR, or None."""
    best: tuple[int, str] | None = None
    for pattern in globs:
        for path in sorted(glob.glob(pattern)):
            major = _llvm_major(path)
            if major is None or major < MIN_LLVM_MAJOR or not os.path.isfile(path):
                continue
            if best is None or major > best[0]:
                best = (major, os.path.realpath(path))
    return best[1] if best else None
