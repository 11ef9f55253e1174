"""Install a headless browser for the `shaderball serve` page test (tests/test_serve_browser.py)
where one can.

Run by `make test`. Does nothing when `chromium` is found. Otherwise, as root with apt-get
(Debian/Ubuntu), installs Debian's `chromium` without recommended packages; the test drives
it over the DevTools protocol through a pipe, so no driver binary is needed. Anywhere else,
or when the install fails, it says so in one line and exits 0: the test is then skipped, and
pytest's summary (-ra) gives the reason. Standard library only (it runs before .venv exists).
"""

import os
import shutil
import subprocess
import sys

PROGRAMS = ("chromium", "chromium-browser")
PACKAGES = ("chromium",)


def found() -> bool:
    return any(shutil.which(name) for name in PROGRAMS)


def main() -> int:
    if found():
        return 0
    if os.environ.get("SHADERBALL_NO_CHROMIUM"):
        print("chromium: not installed (SHADERBALL_NO_CHROMIUM is set); the browser test will be skipped")
        return 0
    if os.geteuid() != 0 or not shutil.which("apt-get"):
        print(
            "chromium: not found and cannot be installed here (needs root and apt-get); the browser test will be skipped"
        )
        return 0
    print(f"installing {' '.join(PACKAGES)} for the browser test of `shaderball serve` ...")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for cmd in (
        ["apt-get", "update", "-qq"],
        ["apt-get", "install", "-y", "-qq", "--no-install-recommends", *PACKAGES],
    ):
        run = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if run.returncode != 0:
            tail = (run.stderr or run.stdout).strip().splitlines()[-3:]
            print(
                f"chromium: `{' '.join(cmd)}` failed (exit {run.returncode}): {' / '.join(tail)}; "
                "the browser test will be skipped"
            )
            return 0
    if not found():
        print("chromium: installed, but not found on PATH; the browser test will be skipped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
