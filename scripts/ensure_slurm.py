"""Install SLURM and munge for the real-SLURM tests (tests/test_slurm_real.py) where one can.

Run by `make setup`. Does nothing when `slurmctld`, `slurmd`, `sbatch` and `munged` are
found. Otherwise, as root with apt-get (Debian/Ubuntu), installs Debian's `slurm-wlm` and
`munge` without recommended packages. The tests start their own daemons in a temporary
folder and need none of the machine's (with systemd, Debian may start its munge service;
slurmd and slurmctld stay down without /etc/slurm/slurm.conf). Anywhere else, or when
the install fails, it says so in one line and exits 0: the tests are then skipped, and
pytest's summary (-ra) gives the reason.
"""

import os
import shutil
import subprocess
import sys

PROGRAMS = ("slurmctld", "slurmd", "sbatch", "squeue", "scontrol", "scancel", "munged")
PACKAGES = ("slurm-wlm", "munge")


def missing() -> list[str]:
    paths = os.environ.get("PATH", "") + os.pathsep + "/usr/sbin" + os.pathsep + "/sbin"
    return [name for name in PROGRAMS if shutil.which(name, path=paths) is None]


def main() -> int:
    absent = missing()
    if not absent:
        return 0
    if os.environ.get("SHADERBALL_NO_SLURM"):
        print("slurm: not installed (SHADERBALL_NO_SLURM is set); the real-SLURM tests will be skipped")
        return 0
    if os.geteuid() != 0 or not shutil.which("apt-get"):
        print(
            f"slurm: {', '.join(absent)} not found and cannot be installed here (needs root and apt-get); "
            "the real-SLURM tests will be skipped"
        )
        return 0
    print(f"installing {' '.join(PACKAGES)} for the real-SLURM tests ...")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for cmd in (
        ["apt-get", "update", "-qq"],
        ["apt-get", "install", "-y", "-qq", "--no-install-recommends", *PACKAGES],
    ):
        run = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if run.returncode != 0:
            tail = (run.stderr or run.stdout).strip().splitlines()[-3:]
            print(
                f"slurm: `{' '.join(cmd)}` failed (exit {run.returncode}): {' / '.join(tail)}; "
                "the real-SLURM tests will be skipped"
            )
            return 0
    absent = missing()
    if absent:
        print(f"slurm: installed, but {', '.join(absent)} still not found; the real-SLURM tests will be skipped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
