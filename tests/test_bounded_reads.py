"""Every whole-file read of a dataset, publication or report file is bounded by what the file
should be: the size its record gives it, or a declared budget where nothing records one
(pipeline.store.bounded_read.read_bytes). A render grown in place (os.truncate: a sparse file, no
disk used) is refused by preview, train and evaluate as validate refuses it, in its words,
before a byte of it is read; so are a grown file under the publication reader, a grown
publication manifest and an EXR read from its path.

The commands run in their own processes under an address-space limit (RLIMIT_AS) of their
peak on good data plus HEADROOM: a command that read the 8 GiB render whole would fail with
a MemoryError there, after at most HEADROOM of memory, instead of taking 8 GB of the machine."""

from __future__ import annotations

import ast
import json
import os
import resource
import shutil
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
FIRST = "m000000_l0"
RENDER = f"shards/s00000/{FIRST}.render.exr"
#: The render's size once grown: sparse, so it costs nothing on disk.
GROWN = 8 << 30
#: Address space a command may take beyond its peak on good data.
HEADROOM = 512 << 20
#: How much a command's resident peak on the grown render may exceed its peak on good data
#: (run-to-run noise of a Python process's peak; each refusal reads less than the good run).
MARGIN = 24 << 20
TRAIN = ["--loss", "l1", "--resolution", "32", "--batch-size", "4", "--lr", "1e-3", "--seed", "3", "--epochs", "1"]

#: ``python -c`` this, a note file, then shaderball's arguments: the command, and the process's
#: own VmPeak and VmHWM (bytes) in the note when it exits.
PEAKS = """
import atexit, sys
def peaks():
    with open("/proc/self/status") as fh:
        status = dict(line.split(":", 1) for line in fh if line.startswith(("VmPeak:", "VmHWM:")))
    with open(sys.argv[1], "w") as out:
        out.write(" ".join(str(int(status[k].split()[0]) * 1024) for k in ("VmPeak", "VmHWM")))
atexit.register(peaks)
import cli
cli.main(args=sys.argv[2:], prog_name="shaderball")
"""


def shaderball(args: list, note: Path, address_space: int | None = None):
    """(the finished process, its VmPeak, its VmHWM) of ``shaderball ARGS`` in its own process,
    under an RLIMIT_AS of ``address_space`` bytes when given."""

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (address_space, address_space))

    done = subprocess.run(
        [sys.executable, "-c", PEAKS, str(note), *map(str, args)],
        capture_output=True,
        text=True,
        cwd=REPO,
        preexec_fn=limit if address_space else None,
    )
    vm_peak, vm_hwm = (int(n) for n in note.read_text().split())
    return done, vm_peak, vm_hwm


@pytest.fixture(scope="module")
def grown(reference, tmp_path_factory):
    """A copy of the smoke dataset whose first render is grown in place to 8 GiB, and the size
    its records give it."""
    root = tmp_path_factory.mktemp("grown") / "ds"
    shutil.copytree(reference, root)
    recorded = (root / RENDER).stat().st_size
    os.truncate(root / RENDER, GROWN)
    assert (root / RENDER).stat().st_blocks * 512 < 1 << 20  # sparse: no disk taken
    yield root, recorded
    os.truncate(root / RENDER, recorded)


# --------------------------------------------------------------------------- the helper


def test_a_read_outside_its_bound_is_refused_before_anything_is_read(tmp_path):
    from pipeline.store.bounded_read import OverBound, Recorded, read_bytes, read_chunks

    path = tmp_path / "m000000_l0.render.exr"
    path.write_bytes(b"x" * 1000)
    assert read_bytes(str(path), Recorded(1000)) == b"x" * 1000
    assert read_bytes(str(path), 1000) == b"x" * 1000
    os.truncate(path, GROWN)
    tracemalloc.start()
    try:
        for bound, words in (
            (Recorded(1000, "manifest.jsonl"), f"{GROWN} bytes, manifest.jsonl says 1000: the file was grown"),
            (1 << 20, f"{GROWN} bytes, over the 1048576-byte bound for this file"),
        ):
            with pytest.raises(OverBound) as caught:
                read_bytes(str(path), bound)
            assert caught.value.strerror == words and caught.value.filename == str(path)
            assert (caught.value.size, caught.value.bound) == (GROWN, bound)
            with pytest.raises(OverBound):
                read_chunks(str(path), bound)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20, peak
    os.truncate(path, 10)
    with pytest.raises(OverBound, match="10 bytes, its record says 1000: the file was truncated"):
        read_bytes(str(path), Recorded(1000))
    with pytest.raises(TypeError, match="needs a bound"):
        read_bytes(str(path), None)


def test_read_exr_from_a_path_reads_no_more_than_a_file_of_its_bounds_holds(tmp_path):
    from pipeline.errors import ShaderballError
    from pipeline.store.exr import layer_bounds, read_exr, write_exr

    path = tmp_path / "render.exr"
    write_exr(str(path), {"render": np.ones((64, 64, 3), np.float32)})
    bounds = layer_bounds(64, ("render",), exact=True)
    assert read_exr(path, bounds=bounds).layers["render"].shape == (64, 64, 3)
    size = path.stat().st_size
    os.truncate(path, size + (64 << 20))  # trailing zeros: OpenEXR would decode it as before
    tracemalloc.start()
    try:
        with pytest.raises(ShaderballError) as caught:
            read_exr(path, bounds=bounds)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert f"cannot decode EXR {path}: {size + (64 << 20)} bytes, over the" in str(caught.value)
    assert peak < 1 << 20, peak


def _unbounded_reads(tree: ast.AST, strict: bool):
    """(line, call) of each whole-file read in ``tree`` without a bound: a store reader
    (read_bytes, read_chunks, file_digest, iter_lines) given no bound; where ``strict``, also
    ``f.read()``, ``Path.read_bytes()`` / ``read_text()`` and ``json.load``."""
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        name = func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else None
        given = len(node.args) + len(node.keywords)
        if name in ("read_bytes", "read_chunks", "file_digest", "iter_lines") and isinstance(func, ast.Name):
            if given < 2:
                yield node.lineno, name
        elif strict and isinstance(func, ast.Attribute):
            if name in ("read", "read_bytes", "read_text") and given == 0:
                yield node.lineno, f".{name}()"
            elif name == "load" and isinstance(func.value, ast.Name) and func.value.id == "json":
                yield node.lineno, "json.load"


#: The readers of dataset, publication and report files, which read nothing whole but
#: through the store's bounded readers.
STRICT = (
    "pipeline/check/preview.py",
    "pipeline/neural/data.py",
    "pipeline/neural/file_sources.py",
    "pipeline/neural/manifest_index.py",
    "pipeline/neural/sweep.py",
    "pipeline/neural/evaluate.py",
    "pipeline/publish/reader.py",
    "pipeline/publish/rows.py",
    "pipeline/publish/small_files.py",
    "pipeline/store/exr.py",
)


def test_whole_file_reads_of_data_name_their_bound():
    """Every call of the store's whole-file readers in pipeline/ names a bound; the readers of
    dataset, publication and report files (:data:`STRICT`) read no file whole another way."""
    unbounded = []
    for path in sorted((REPO / "pipeline").rglob("*.py")):
        rel = path.relative_to(REPO).as_posix()
        tree = ast.parse(path.read_text(encoding="utf-8"))
        unbounded += [f"{rel}:{line} {call}" for line, call in _unbounded_reads(tree, rel in STRICT)]
    assert unbounded == []


# --------------------------------------------------------------------------- the commands


@pytest.fixture(scope="module")
def trained(reference, tmp_path_factory):
    """A run trained one epoch on the good dataset (the run evaluate evaluates), and that
    command's VmPeak and VmHWM: train's figures on good data."""
    base = tmp_path_factory.mktemp("trained")
    done, vm_peak, vm_hwm = shaderball(["train", reference, "--out", base / "run", *TRAIN], base / "note.txt")
    assert done.returncode == 0, done.stderr[-2000:]
    return base / "run", vm_peak, vm_hwm


def _arguments(command: str, data: Path, out: Path, run: Path) -> list:
    return {
        "validate": ["validate", data],
        "preview": ["preview", data, "--out", out],
        "train": ["train", data, "--out", out, *TRAIN],
        "evaluate": ["evaluate", run, data, "--split", "all", "--spp", "none", "--limit", "1", "--out", out],
    }[command]


@pytest.mark.slow
@pytest.mark.parametrize("command, code", [("validate", 1), ("preview", 1), ("train", 2), ("evaluate", 2)])
def test_a_grown_render_is_refused_as_validate_refuses_it(reference, grown, trained, tmp_path, command, code):
    """Each command on the grown render: validate's verdict (problems found, or refused: exit
    2) in validate's words, nothing written by a refusal, and a resident peak no higher than
    on good data."""
    root, recorded = grown
    run, train_peak, train_resident = trained
    if command == "train":
        vm_peak, vm_hwm = train_peak, train_resident
    else:
        good, vm_peak, vm_hwm = shaderball(
            _arguments(command, reference, tmp_path / "good.png", run), tmp_path / "good.txt"
        )
        assert good.returncode == 0, good.stderr[-2000:]
    out = tmp_path / ("bad.png" if command == "preview" else "bad")
    done, _peak, resident = shaderball(_arguments(command, root, out, run), tmp_path / "bad.txt", vm_peak + HEADROOM)
    output = done.stdout + done.stderr
    listed_by = "its record" if command == "preview" else "manifest.jsonl"  # where each reads the size
    assert done.returncode == code, output[-2000:]
    assert f"{RENDER}: {GROWN} bytes, {listed_by} says {recorded}: the file was grown" in output, output[-2000:]
    assert "Traceback" not in output and "MemoryError" not in output, output[-2000:]
    assert resident < vm_hwm + MARGIN, (vm_hwm, resident)
    if command in ("train", "evaluate"):
        assert not out.exists()  # refused: nothing written
    if command == "preview":
        assert out.stat().st_size > 0  # the sheet, the grown render's tile "unreadable"


@pytest.mark.slow
def test_preview_that_leaves_a_file_out_exits_1_and_still_writes_the_sheet(reference, tmp_path):
    """A render that does not decode (its recorded size, other bytes): validate's "problems
    found" (exit 1, ``ok`` false), the sheet written with the tile marked, the file named."""
    data = tmp_path / "ds"
    shutil.copytree(reference, data)
    render = data / RENDER
    render.write_bytes(b"not an EXR".ljust(render.stat().st_size, b"\0"))
    done, _peak, _resident = shaderball(["preview", data, "--out", tmp_path / "p.png", "--json"], tmp_path / "note.txt")
    assert done.returncode == 1, done.stderr[-2000:]
    doc = json.loads(done.stdout)
    assert doc["ok"] is False and doc["exit"] == 1
    assert any(f"cannot decode EXR {RENDER}" in problem for problem in doc["problems"]), doc["problems"]
    assert (tmp_path / "p.png").stat().st_size > 0
    clean, _peak, _resident = shaderball(["preview", reference, "--out", tmp_path / "q.png"], tmp_path / "n.txt")
    assert clean.returncode == 0, clean.stderr[-2000:]


# --------------------------------------------------------------------------- the publication reader


@pytest.mark.slow
def test_the_folder_reader_refuses_a_grown_file_without_reading_it(reference, tmp_path):
    from pipeline.publish.reader import iter_folder_samples
    from pipeline.publish.refusal import Refused

    data = tmp_path / "ds"
    shutil.copytree(reference, data)
    recorded = (data / RENDER).stat().st_size
    os.truncate(data / RENDER, recorded + (64 << 20))
    tracemalloc.start()
    try:
        with pytest.raises(Refused) as caught:
            for _sample in iter_folder_samples(str(data)):
                pass
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert caught.value.kind == "size_mismatch"
    assert f"{RENDER}: {recorded + (64 << 20)} bytes, manifest.jsonl says {recorded}: the file was grown" in str(
        caught.value
    )
    assert peak < 16 << 20, peak


@pytest.mark.slow
def test_a_publication_manifest_grown_after_it_was_checked_is_not_read(reference, tmp_path):
    from pipeline.publish.reader import open_publication
    from pipeline.publish.refusal import Refused
    from pipeline.publish.writer import write_publication

    pub = tmp_path / "pub"
    write_publication(str(reference), str(pub), contact_sheet=False)
    publication = open_publication(str(pub))
    manifest = pub / "dataset" / "manifest.jsonl"
    checked = manifest.stat().st_size
    os.truncate(manifest, checked + (64 << 20))
    tracemalloc.start()
    try:
        with pytest.raises(Refused) as caught:
            b"".join(publication.manifest_chunks())
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert caught.value.kind == "changed" and f"{checked + (64 << 20)} bytes, {checked} when it was checked" in str(
        caught.value
    )
    assert peak < 16 << 20, peak
