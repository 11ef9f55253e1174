"""Install a tool that some tests need, where one can: `python3 scripts/ensure_optional.py NAME`.

Run by `make setup` (slurm) and `make test` (chromium) with the machine's python3, before the
virtual environment exists: standard library only. Does nothing when the tool's programs are
found. Otherwise, as root with apt-get (Debian/Ubuntu), installs its Debian packages without
recommended packages. Anywhere else, when its `SHADERBALL_NO_...` variable is set, or when the
install fails, it says so in one line and exits 0: the tests that need it are then skipped,
and pytest's summary (-ra) gives the reason.

- **slurm**: Debian's `slurm-wlm` and `munge`, for the real-SLURM tests
  (tests/test_slurm_real.py). They start their own daemons in a temporary folder and need none
  of the machine's (with systemd, Debian may start its munge service; slurmd and slurmctld stay
  down without /etc/slurm/slurm.conf).
- **chromium**: Debian's `chromium` and `chromium-driver` (both programs, `chromium` and
  `chromedriver`, must be found), for the browser tests of `shaderball serve`
  (tests/test_serve_browser.py). They drive the browser with Selenium through this
  `chromedriver`, named by its path, so Selenium Manager never downloads a driver or a
  browser; the two packages come from one Debian release and match.
"""

import os
import shutil
import subprocess
import sys
from typing import NamedTuple


class Tool(NamedTuple):
    programs: tuple[str, ...]
    every: bool  # every program must be found (else any one)
    packages: tuple[str, ...]
    skip_variable: str
    tests: str  # the tests that need it, as the one-line notes name them
    path: str = ""  # searched besides PATH


TOOLS = {
    "slurm": Tool(
        ("slurmctld", "slurmd", "sbatch", "squeue", "scontrol", "scancel", "munged"),
        True,
        ("slurm-wlm", "munge"),
        "SHADERBALL_NO_SLURM",
        "the real-SLURM tests",
        os.pathsep.join(("/usr/sbin", "/sbin")),
    ),
    "chromium": Tool(
        ("chromium", "chromedriver"),
        True,
        ("chromium", "chromium-driver"),
        "SHADERBALL_NO_CHROMIUM",
        "the browser tests of `shaderball serve`",
    ),
}


def missing(tool: Tool) -> list[str]:
    """The programs of ``tool`` not found (for an any-one tool: all of them, or none)."""
    path = os.pathsep.join(p for p in (os.environ.get("PATH", ""), tool.path) if p)
    absent = [name for name in tool.programs if shutil.which(name, path=path) is None]
    return absent if tool.every or len(absent) == len(tool.programs) else []


def ensure(name: str) -> int:
    tool = TOOLS[name]
    absent = missing(tool)
    if not absent:
        return 0
    skipped = f"{tool.tests} will be skipped"
    if os.environ.get(tool.skip_variable):
        print(f"{name}: not installed ({tool.skip_variable} is set); {skipped}")
        return 0
    if os.geteuid() != 0 or not shutil.which("apt-get"):
        print(f"{name}: {', '.join(absent)} not found and cannot be installed here (needs root and apt-get); {skipped}")
        return 0
    print(f"installing {' '.join(tool.packages)} for {tool.tests} ...")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for cmd in (
        ["apt-get", "update", "-qq"],
        ["apt-get", "install", "-y", "-qq", "--no-install-recommends", *tool.packages],
    ):
        run = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if run.returncode != 0:
            tail = (run.stderr or run.stdout).strip().splitlines()[-3:]
            print(f"{name}: `{' '.join(cmd)}` failed (exit {run.returncode}): {' / '.join(tail)}; {skipped}")
            return 0
    absent = missing(tool)
    if absent:
        print(f"{name}: installed, but {', '.join(absent)} still not found; {skipped}")
    return 0


def main(argv: list[str]) -> int:
    if len(argv) != 1 or argv[0] not in TOOLS:
        print(f"usage: python3 scripts/ensure_optional.py {'|'.join(TOOLS)}", file=sys.stderr)
        return 2
    return ensure(argv[0])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
