"""Memory bounded by structure: the build's manifest, info, validate (fast and full), preview, publish, verify,
unpack and the training loader over a dataset at two sizes, each in its own process, its peak of traced
memory taken (``tracemalloc``: every Python object and numpy array); the growth per extra
render must stay under ~1 KB (a record is ~11 kB as Python objects: a command that held
them all grew ~5-45 kB a render). A ratio from one run, not a timing. Traced memory, not
the resident set: the resident set's peak moves by ~1 MB with the allocator's arenas, more
than the bound over a few hundred renders; traced memory is the same from run to run
within a few kB."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Largest growth of a command's peak memory per extra render.
BYTES_PER_RENDER = 1024
#: Materials (5 lightings each, 4 materials a shard): 200 and 1,000 renders, 10 and 50 shards.
SIZES = (40, 200)
#: Runs the CLI with its arguments under tracemalloc; prints the peak on stderr's last line.
TRACED = (
    "import runpy, sys, tracemalloc; tracemalloc.start(); sys.argv = ['cli', *sys.argv[1:]]\n"
    "try:\n    runpy.run_module('cli', run_name='__main__')\nexcept SystemExit as exc:\n    code = exc.code\n"
    "else:\n    code = 0\n"
    "print('PEAK', tracemalloc.get_traced_memory()[1], file=sys.stderr); sys.exit(code)"
)


def _tiny_spec(materials: int, folder: Path) -> Path:
    """The paper's spec at 16 px, 1 spp, 16-px textures, ``materials`` materials."""
    text = (ROOT / "manifests" / "paper.toml").read_text()
    for key, value in (
        ("materials", materials),
        ("resolution", 16),
        ("spp", 1),
        ("texture_resolution", 16),
        ("shard_size", 4),
    ):
        text, n = re.subn(rf"(?m)^{key} = \d+", f"{key} = {value}", text)
        assert n == 1, key
    path = folder / f"tiny{materials}.toml"
    path.write_text(text)
    return path


def _peak_bytes(args: list, cwd: Path) -> int:
    """Run ``shaderball ARGS`` (or, when the first is a program, that program with the rest) in
    a new process; its peak of traced memory (it must succeed)."""
    program, args = (args[0], args[1:]) if "\n" in str(args[0]) else (TRACED, args)
    done = subprocess.run(
        [sys.executable, "-c", program, *map(str, args)], cwd=ROOT, capture_output=True, text=True, env=os.environ
    )
    assert done.returncode == 0, (args, done.stdout[-1000:], done.stderr[-2000:])
    return int(done.stderr.strip().splitlines()[-1].split()[1])


#: The training loader: a dataset opened and read once through a DataLoader, its maps cache
#: at 4 materials (the default 64 would grow the peak by design until 64 materials are cached).
LOADER = (
    "import sys, tracemalloc; tracemalloc.start()\n"
    "from torch.utils.data import DataLoader\n"
    "from pipeline.neural.data import collate_samples, open_dataset\n"
    "dataset = open_dataset(sys.argv[1], cache_materials=4)\n"
    "for batch in DataLoader(dataset, batch_size=16, num_workers=0, collate_fn=collate_samples):\n"
    "    pass\n"
    "print('PEAK', tracemalloc.get_traced_memory()[1], file=sys.stderr)"
)


#: Publishing alone (``publish`` validates first: its peak may be validate's).
WRITE = (
    "import sys, tracemalloc; tracemalloc.start()\n"
    "from pipeline.publish.writer import write_publication\n"
    "write_publication(sys.argv[1], sys.argv[2], contact_sheet=False)\n"
    "print('PEAK', tracemalloc.get_traced_memory()[1], file=sys.stderr)"
)


#: The manifest written again from the shards' markers, as a build ends (streamed a shard at a
#: time; held whole, ~2 kB a render twice over, it was the build's growth). The build's whole
#: peak is not compared here: its render loop's threads make it vary by ~2 MB with timing under
#: load (124.48-126.25 MB over four runs of 1,000 renders), more than the bound allows over 800
#: renders; `shaderball bench --scale` measures the build's resident peak at 1,000-50,000 renders.
MANIFEST = (
    "import sys, tracemalloc\n"
    "from pipeline.dataset.plan import plan_dataset\n"
    "from pipeline.run.build import read_spec_text, write_manifest\n"
    "plans = plan_dataset(read_spec_text(sys.argv[1] + '/spec.toml')[0])\n"
    "tracemalloc.start()\n"
    "write_manifest(sys.argv[1], plans)\n"
    "print('PEAK', tracemalloc.get_traced_memory()[1], file=sys.stderr)"
)


def _commands(data: Path, scratch: Path) -> dict[str, list]:
    return {
        "build's manifest": [MANIFEST, data],
        "info": ["info", data],
        "validate --fast": ["validate", data, "--fast"],
        "validate": ["validate", data],
        "preview": ["preview", data, "--out", scratch / "sheet.png"],
        "publish": ["publish", data, "--out", scratch / "pub"],
        "publishing alone": [WRITE, data, scratch / "pub-alone"],
        "verify": ["verify", scratch / "pub"],
        "unpack": ["unpack", scratch / "pub", "--out", scratch / "unpacked"],
        "training loader": [LOADER, data],
    }


@pytest.mark.slow
def test_every_command_grows_under_a_kilobyte_per_render(tmp_path):
    peaks, renders = {}, {}
    for materials in SIZES:
        data, scratch = tmp_path / f"d{materials}", tmp_path / f"s{materials}"
        scratch.mkdir()
        spec = _tiny_spec(materials, tmp_path)
        build = subprocess.run(
            [sys.executable, "-m", "cli", "build", spec, "--out", data, "--workers", "0"],
            cwd=ROOT,
            capture_output=True,
            text=True,
        )
        assert build.returncode == 0, build.stderr[-2000:]
        renders[materials] = materials * 5
        for name, args in _commands(data, scratch).items():
            peaks[name, materials] = _peak_bytes(args, scratch)
    small, large = SIZES
    extra = renders[large] - renders[small]
    slopes = {name: (peaks[name, large] - peaks[name, small]) / extra for name in _commands(tmp_path, tmp_path)}
    table = ", ".join(f"{name} {peaks[name, small]}->{peaks[name, large]} B" for name in slopes)
    assert all(slope < BYTES_PER_RENDER for slope in slopes.values()), f"bytes per extra render {slopes}; {table}"
