"""Install libLLVM 19 for drjit when no usable libLLVM is on the machine (Debian/Ubuntu).

Run by `make setup`; does nothing when a usable libLLVM (major >= 16) exists.
"""

import os
import shutil
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
from pipeline.render.mitsuba_env import INSTALL_HINT, find_libllvm  # noqa: E402


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
