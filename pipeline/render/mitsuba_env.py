"""Loading Mitsuba with a libLLVM that drjit's LLVM backend can use.

drjit 1.5 aborts with Debian 12's libLLVM 15 ("Cannot select ... fmaximum") and
works with libLLVM 19. It loads the first libLLVM it finds unless
``DRJIT_LIBLLVM_PATH`` names one, so before drjit is imported we pick the newest
libLLVM with a major version we know works, unless the user has chosen one.
Every module that needs Mitsuba goes through :func:`load_mitsuba`.

**The variant is chosen once.** Mitsuba's variant is process-global: ``set_variant``
switches every ``mi.*`` type, and a Python plugin registered under one variant is
"not found" under another. So the variant is resolved once, at the edge (a build's
driver from the spec, a command from its options) by :func:`resolve_variant`, and that
full name is passed down to everything that touches Mitsuba. This module is the only
one that names a variant or calls ``set_variant`` (tests/test_architecture.py).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import platform
import signal
import sys
import threading

import numpy as np

from pipeline.errors import SetupError
from pipeline.render.libllvm import INSTALL_HINT, MIN_LLVM_MAJOR, find_libllvm  # noqa: F401 (re-exported)

#: The CPU variant: RGB, with the AD types the Python BSDF needs.
LLVM_VARIANT = "llvm_ad_rgb"
#: The GPU variant, chosen by ``auto`` when a CUDA device works.
CUDA_VARIANT = "cuda_ad_rgb"
#: What a spec's ``render.variant`` or a ``--variant`` option may say (or a full name).
VARIANT_CHOICES = ("auto", "llvm", "cuda", "scalar")
#: Short names of the variants.
SHORT_VARIANTS = {"llvm": LLVM_VARIANT, "cuda": CUDA_VARIANT, "scalar": "scalar_rgb"}


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


@contextlib.contextmanager
def _sigint_held():
    """A Ctrl-C while drjit and Mitsuba initialise (their native modules, a variant's plugins:
    a second or more) is held until they are done, then delivered as it would have been.
    Raised inside their initialisation, a KeyboardInterrupt can abort the process (SIGABRT) or
    leave a half-made module (``NameError: name '_drjit_ext' is not defined``)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        signal.raise_signal(signal.SIGINT)  # to the handler the process had: KeyboardInterrupt, or ignored


def _import_mitsuba(requested: str):
    if "drjit" not in sys.modules and not requested.startswith("cuda"):
        try:
            select_libllvm()
        except SetupError:
            if requested != "auto":
                raise
            # auto on a GPU machine needs no libLLVM; without a GPU, resolve_variant raises.
    with _sigint_held():
        import mitsuba as mi

    return mi


def resolve_variant(requested: str = "auto") -> str:
    """The full Mitsuba variant name for ``requested``; imports Mitsuba but sets nothing.

    ``auto``: cuda when a CUDA device works, else llvm; ``llvm``/``cuda``: their RGB AD
    variants; a full name: itself, if this Mitsuba build has it.
    """
    mi = _import_mitsuba(requested)
    if requested == "auto":
        if cuda_works() and CUDA_VARIANT in mi.variants():
            return CUDA_VARIANT
        select_libllvm()  # no GPU: the CPU variant needs a usable libLLVM
        return LLVM_VARIANT
    name = SHORT_VARIANTS.get(requested, requested)
    if name not in mi.variants():
        raise SetupError(
            f"render.variant: {requested!r} is not available; allowed: {', '.join(VARIANT_CHOICES)} "
            f"or one of {', '.join(mi.variants())}"
        )
    if name.startswith("cuda_") and not cuda_works():
        raise SetupError(
            f"render.variant: {requested!r} needs a CUDA device and none works here "
            "(drjit.has_backend(drjit.JitBackend.CUDA) is false)"
        )
    return name


def cuda_works() -> bool:
    """Whether drjit's CUDA backend works in this process (a GPU and its driver)."""
    try:
        import drjit as dr

        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # no CUDA driver at all
        return False


def load_mitsuba(variant: str):
    """Import Mitsuba with a working libLLVM, make ``variant`` current; return the module.

    ``variant`` is what :func:`resolve_variant` returned at the edge of the program
    (short forms are resolved here too, for the command line of the tools). This is
    the only call of ``mi.set_variant`` in the project.
    """
    mi = sys.modules.get("mitsuba")
    if mi is not None and variant == mi.variant():  # already current by its full name: a build calls
        return mi  # this several times a render, and resolving takes two signal handler swaps
    name = resolve_variant(variant)
    mi = _import_mitsuba(name)
    if mi.variant() != name:
        try:
            with _sigint_held():
                mi.set_variant(name)
        except Exception as exc:  # mitsuba raises plain ImportError/RuntimeError
            raise SetupError(f"cannot use Mitsuba variant {name!r}: {exc}") from exc
    return mi


#: (variant, plugin name) of every Python plugin registered in this process.
_PLUGINS: set[tuple[str, str]] = set()


def register_plugin(variant: str, name: str, kind: str, make_class) -> None:
    """Register the Python plugin ``name`` with Mitsuba for ``variant``: ``kind`` "bsdf" or
    "integrator", its class ``make_class(mi)`` made after the variant is loaded (a class
    registered under one variant is not found under another). Calling it again is a no-op."""
    mi = load_mitsuba(variant)
    key = (mi.variant(), name)
    if key in _PLUGINS:
        return
    cls = make_class(mi)
    getattr(mi, f"register_{kind}")(name, lambda props: cls(props))
    _PLUGINS.add(key)


#: Re-rendering a sample on the same machine and versions gives the same bytes. Holds for the
#: llvm variant, whose renders are split into power-of-two passes for it (docs/build.md,
#: Determinism; tests/test_build.py).
BYTE_IDENTICAL = "byte-identical"
#: Re-rendering a sample gives another render of the same image, equal within its noise but
#: not bit for bit: Mitsuba's cuda variant is not bit-stable (mitsuba3#1938).
WITHIN_NOISE = "within-noise"
#: Strongest first: a dataset's guarantee is the weakest of the builds that wrote it.
GUARANTEES = (BYTE_IDENTICAL, WITHIN_NOISE)
GUARANTEE_BASIS = {
    BYTE_IDENTICAL: "llvm variant, spp rendered as power-of-two passes: byte-identical re-renders, "
    "tested (tests/test_build.py)",
    WITHIN_NOISE: "not bit-stable on this backend (mitsuba3#1938): a re-render agrees within noise, not byte for byte",
}


def determinism(variant: str) -> str:
    """The guarantee a re-render of ``variant`` (a full name) gives: :data:`BYTE_IDENTICAL` for
    the llvm variants, whose byte-identity is tested here, :data:`WITHIN_NOISE` for every other
    (cuda's is reported unstable upstream; scalar is neither used nor tested)."""
    return BYTE_IDENTICAL if variant.startswith("llvm_") else WITHIN_NOISE


def weakest_guarantee(*guarantees: str | None) -> str:
    """The weakest of ``guarantees`` (None and unknown values ignored; none left: byte-identical)."""
    known = [g for g in guarantees if g in GUARANTEES]
    return max(known, key=GUARANTEES.index) if known else BYTE_IDENTICAL


def library_versions() -> dict[str, str]:
    """Versions that determine the bytes of a render (recorded in dataset descriptions)."""
    import drjit as dr
    import mitsuba as mi

    return {
        "mitsuba": mi.__version__,
        "drjit": dr.__version__,
        "libllvm": os.environ.get("DRJIT_LIBLLVM_PATH", ""),
    }


def llvm_target() -> tuple[str | None, int | None]:
    """drjit's LLVM target CPU and vector width in this process (its JIT targets the host).

    drjit's Python API does not expose them; its core library exports them as C++ functions
    (``jit_llvm_target_cpu``, ``jit_llvm_vector_width``), read here with ctypes. (None, None)
    when the library or the symbols are not there (another drjit, no llvm backend)."""
    if "drjit" not in sys.modules:
        return None, None  # importing drjit here would load it before select_libllvm chose a libLLVM
    try:
        import drjit as dr

        lib = ctypes.CDLL(os.path.join(os.path.dirname(dr.__file__), "libdrjit-core.so"))
        cpu = lib._Z19jit_llvm_target_cpuv
        cpu.restype = ctypes.c_char_p
        width = lib._Z21jit_llvm_vector_widthv
        width.restype = ctypes.c_uint32
        name = cpu()
        return (name.decode() if name else None), int(width()) or None
    except (OSError, AttributeError, ImportError):
        return None, None


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo), what results pages and fingerprints name."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.lower().startswith(("model name", "cpu model", "hardware")):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_fingerprint() -> dict:
    """What of this machine can change the last bits of a render or a material's maps.

    Recorded, never compared on resume: renders of one plan made on two CPU types are equally
    valid samples (docs/build.md, "What is reproducible where"). ``llvm_target_cpu`` and
    ``llvm_vector_width`` are what drjit's JIT compiles kernels for; ``numpy_simd`` the SIMD
    kernels numpy dispatches to (its transcendental functions' last bits depend on them).
    """
    target, width = llvm_target()
    return {
        "arch": platform.machine(),
        "cpu_model": cpu_model(),
        "llvm_target_cpu": target,
        "llvm_vector_width": width,
        "numpy": np.__version__,
        "numpy_simd": numpy_simd(),
    }


def _numpy_umath():
    core = getattr(np, "_core", None) or np.core  # numpy 2 / numpy 1
    return core._multiarray_umath


def numpy_dispatch_targets() -> list[str]:
    """The SIMD targets this numpy build can dispatch to (the names NPY_DISABLE_CPU_FEATURES takes)."""
    return list(_numpy_umath().__cpu_dispatch__)


def numpy_simd() -> list[str]:
    """The dispatch targets numpy uses in this process (this CPU has them, none is disabled)."""
    features = _numpy_umath().__cpu_features__
    return [name for name in numpy_dispatch_targets() if features.get(name)]
