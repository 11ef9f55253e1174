"""A command that fails removes what it made and nothing else (pipeline.publish.output): the
files it wrote, then the folders it created, deepest first, each only if empty. Another
process writes into those folders, and beside them, while the command runs; its files, and
the folders holding them, survive the cleanup. Exercised through ``unpack`` (its publication
stubbed: the cleanup is what is tested) and through publish's ``held_output``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import pipeline.publish.unpack as unpack_module
from pipeline.publish.output import held_output
from pipeline.publish.refusal import Refused
from pipeline.publish.request import UnpackRequest
from pipeline.store.layout import LOCK_FILE

#: Run as another process: write argv[2] into the file argv[1] (its folders made as needed),
#: or with argv[3] == "replace", put a new file in its place (a rename over it).
FOREIGN = r"""
import os, sys
path, text = sys.argv[1], sys.argv[2]
os.makedirs(os.path.dirname(path), exist_ok=True)
target = path + ".tmp" if sys.argv[3:] == ["replace"] else path
with open(target, "w") as fh:
    fh.write(text)
if target != path:
    os.replace(target, path)
"""


def foreign(path: Path, text: str = "precious", replace: bool = False) -> None:
    """``path`` written by a process other than this one."""
    args = [sys.executable, "-c", FOREIGN, str(path), text] + (["replace"] if replace else [])
    subprocess.run(args, check=True, timeout=60)


def tree(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() + ("/" if p.is_dir() else "") for p in root.rglob("*"))


@pytest.fixture
def stubbed_unpack(monkeypatch, tmp_path):
    """unpack() with its publication stubbed: ``writes(output, out)`` runs where the members
    would be written, then the unpack is refused (as a member found bad would refuse it)."""
    pub = tmp_path / "pub"
    pub.mkdir()
    monkeypatch.setattr(unpack_module, "open_publication", lambda *a, **k: object())
    monkeypatch.setattr(unpack_module, "verify_publication", lambda *a, **k: None)

    def run(out: Path, writes) -> None:
        def write_then_refuse(publication, output, progress):
            writes(output, out)
            raise Refused("member_checksum", "a member changed since verify; refused")

        monkeypatch.setattr(unpack_module, "_write_in_completion_order", write_then_refuse)
        with pytest.raises(Refused):
            unpack_module.unpack(UnpackRequest(str(pub), str(out), validate=False))

    return run


def test_a_refused_unpack_leaves_what_another_process_wrote_meanwhile(stubbed_unpack, tmp_path):
    new = tmp_path / "NEW"
    out = new / "a" / "ds"

    def writes(output, out):
        output.write("spec.toml", b"[dataset]\n")
        output.write("shards/s00000/m000000.maps.exr", b"maps")
        output.write("shards/s00001/m000001.maps.exr", b"maps")
        foreign(new / "other" / "precious.txt")  # beside the folders unpack created
        foreign(out / "shards" / "s00000" / "notes.txt", "mine")  # inside one of them

    stubbed_unpack(out, writes)
    assert (new / "other" / "precious.txt").read_text() == "precious"
    assert (out / "shards" / "s00000" / "notes.txt").read_text() == "mine"
    assert tree(new) == [
        "a/",
        "a/ds/",
        "a/ds/shards/",
        "a/ds/shards/s00000/",
        "a/ds/shards/s00000/notes.txt",
        "other/",
        "other/precious.txt",
    ]  # its own files and its empty folders (shards/s00001) gone; no lock file left


def test_a_refused_unpack_with_nobody_else_removes_every_folder_it_created(stubbed_unpack, tmp_path):
    out = tmp_path / "NEW" / "a" / "ds"
    stubbed_unpack(out, lambda output, out: output.write("shards/s00000/m000000.maps.exr", b"maps"))
    assert not (tmp_path / "NEW").exists()


def test_a_refused_unpack_into_an_empty_folder_leaves_it_and_foreign_files(stubbed_unpack, tmp_path):
    out = tmp_path / "ds"
    out.mkdir()

    def writes(output, out):
        output.write("spec.toml", b"[dataset]\n")
        foreign(out / "README.txt", "theirs")

    stubbed_unpack(out, writes)
    assert tree(out) == ["README.txt"]


def test_a_failed_publish_removes_only_its_own(tmp_path):
    new = tmp_path / "NEW"
    out = new / "a" / "pub"
    with pytest.raises(RuntimeError, match="disk full"):
        with held_output(str(out), "publish", "PUB") as output:
            output.write("README.md", b"card")
            output.write("SHA256SUMS", b"sums")
            output.write("shards/renders-000000.tar", b"tar")
            path = output.path("shards/materials-000000.tar")  # written through the path, not adopted
            Path(path).write_bytes(b"half a tar")
            foreign(new / "other" / "precious.txt")
            foreign(out / "shards" / "theirs.tar", "theirs")
            foreign(out / "SHA256SUMS", "replaced by another process", replace=True)
            assert (out / LOCK_FILE).exists()
            raise RuntimeError("disk full")
    assert tree(new) == [
        "a/",
        "a/pub/",
        "a/pub/SHA256SUMS",
        "a/pub/shards/",
        "a/pub/shards/theirs.tar",
        "other/",
        "other/precious.txt",
    ]
    assert (out / "SHA256SUMS").read_text() == "replaced by another process"  # not the file it wrote
