"""Install libLLVM 19 for drjit when no usable libLLVM is on the machine (Debian/Ubuntu).

Run by `make setup` with the machine's python3 before the virtual environment exists, so it
uses the standard library only; does nothing when a usable libLLVM (major >= 16) exists.
"""

import importlib.util
import os
import shutil
import subprocess
import sys

# Loaded by path, not as `pipeline.render.libllvm`: importing the package would run its
# `__init__`s, which need numpy, and this runs before the virtual environment exists.
_LIBLLVM = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "pipeline", "render", "libllvm.py")
_spec = importlib.util.spec_from_file_location("shaderball_libllvm", _LIBLLVM)
_libllvm = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_libllvm)
INSTALL_HINT, find_libllvm = _libllvm.INSTALL_HINT, _libllvm.find_libllvm


def main() -> int:
    found = find_libllvm()
    if found:
        print(f"libLLVM for drjit: {found}")
        return 0
    if not shutil.which("apt-get"):
        print(f"error: {INSTALL_HINT}", file=sys.stderr)
        return 1
    sudo = [] if os.geteuid() == 0 else ["sudo"]
    print("installing libllvm19 for drjit (Debian's libLLVM 15 crashes it) ...")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "libllvm19"]):
        if subprocess.call(sudo + cmd, env=env) != 0:
            print(f"error: `{' '.join(sudo + cmd)}` failed. {INSTALL_HINT}", file=sys.stderr)
            return 1
    found = find_libllvm()
    if not found:
        print(f"error: libllvm19 installed but not found. {INSTALL_HINT}", file=sys.stderr)
        return 1
    print(f"libLLVM for drjit: {found}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
