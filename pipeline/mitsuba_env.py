"""Loading Mitsuba with a libLLVM that drjit's LLVM backend can use.

drjit 1.5 aborts with Debian 12's libLLVM 15 ("Cannot select ... fmaximum") and
works with libLLVM 19. It loads the first libLLVM it finds unless
``DRJIT_LIBLLVM_PATH`` names one, so before drjit is imported we pick the newest
libLLVM with a major version we know works, unless the user has chosen one.
Every module that needs Mitsuba goes through :func:`load_mitsuba`.
"""

from __future__ import annotations

import glob
import os
import re
import sys

from pipeline.errors import SetupError

#: libLLVM majors below this crash drjit 1.5's LLVM backend (15 measured here).
MIN_LLVM_MAJOR = 16
#: Default Mitsuba variant: CPU, RGB, with the AD types the Python BSDF needs.
DEFAULT_VARIANT = "llvm_ad_rgb"

_SEARCH_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
    "/usr/local/opt/llvm/lib/libLLVM*.dylib",
)

INSTALL_HINT = (
    "drjit's LLVM backend needs libLLVM >= {min} (19 is tested). On Debian 12: "
    "`sudo apt-get install libllvm19`; elsewhere install LLVM 16-19 and set "
    "DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so"
).format(min=MIN_LLVM_MAJOR)


def _llvm_major(path: str) -> int | None:
    name = os.path.basename(path)
    match = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", name)
    return int(match.group(1)) if match else None


def find_libllvm(globs: tuple[str, ...] = _SEARCH_GLOBS) -> str | None:
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


def select_libllvm() -> str:
    """Make sure DRJIT_LIBLLVM_PATH names a usable libLLVM; return its path.

    Respects a path the user set. Must run before drjit is imported to have effect.
    """
    chosen = os.environ.get("DRJIT_LIBLLVM_PATH")
    if chosen:
        if not os.path.isfile(chosen):
            raise SetupError(f"DRJIT_LIBLLVM_PATH={chosen!r} does not exist. {INSTALL_HINT}")
        return chosen
    found = find_libllvm()
    if found is None:
        raise SetupError(f"no usable libLLVM found. {INSTALL_HINT}")
    os.environ["DRJIT_LIBLLVM_PATH"] = found
    return found


def load_mitsuba(variant: str = DEFAULT_VARIANT):
    """Import Mitsuba with a working libLLVM and set ``variant``; return the module.

    ``variant`` may be ``auto`` (cuda if a GPU works, else llvm), a full variant
    name, or the short forms ``llvm``, ``cuda`` and ``scalar`` (all RGB).
    """
    if variant.startswith("llvm") or variant == "auto":
        if "drjit" not in sys.modules:
            select_libllvm()
    import mitsuba as mi

    name = resolve_variant(variant, mi)
    if mi.variant() != name:
        try:
            mi.set_variant(name)
        except Exception as exc:  # mitsuba raises plain ImportError/RuntimeError
            raise SetupError(f"cannot use Mitsuba variant {name!r}: {exc}") from exc
    return mi


def resolve_variant(variant: str, mi) -> str:
    short = {"llvm": "llvm_ad_rgb", "cuda": "cuda_ad_rgb", "scalar": "scalar_rgb"}
    if variant == "auto":
        try:
            import drjit as dr

            if dr.has_backend(dr.JitBackend.CUDA):
                return "cuda_ad_rgb"
        except Exception:  # no CUDA driver: fall back to the CPU
            pass
        return DEFAULT_VARIANT
    name = short.get(variant, variant)
    if name not in mi.variants():
        raise SetupError(
            f"render.variant: {variant!r} is not available; allowed: auto, llvm, cuda, scalar "
            f"or one of {', '.join(mi.variants())}"
        )
    return name


def library_versions() -> dict[str, str]:
    """Versions that determine the bytes of a render (recorded in dataset descriptions)."""
    import drjit as dr
    import mitsuba as mi

    return {
        "mitsuba": mi.__version__,
        "drjit": dr.__version__,
        "libllvm": os.environ.get("DRJIT_LIBLLVM_PATH", ""),
    }
