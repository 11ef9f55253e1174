"""Helpers of the publish tests: one smoke build per session, and the tools to forge hostile
publications (raw tar headers, re-sealed checksums, consistently re-recorded files)."""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import tarfile
from pathlib import Path

from pipeline.run.build import build
from pipeline.run.cluster.options import ClusterOptions
from pipeline.store.records import dumps

REPO = Path(__file__).resolve().parents[2]
SMOKE = REPO / "manifests" / "smoke.toml"


def smoke_build(tmp_path_factory) -> Path:
    """The smoke dataset, built once per test session (and once per machine under xdist)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent
    target = base / "publish-smoke"
    with open(base / "publish-smoke.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (target / "manifest.jsonl").exists():
            build(str(SMOKE), str(target), cluster=ClusterOptions(workers=0))
    return target


def hf_env(tmp_path: Path) -> dict[str, str]:
    """The environment of a process that runs Hugging Face's clients offline, with every cache
    under ``tmp_path`` (nothing downloaded, nothing written to the user's cache)."""
    home = tmp_path / "hf-home"
    return {
        **os.environ,
        "HF_HOME": str(home),
        "HF_DATASETS_CACHE": str(home / "datasets"),
        "HF_HUB_CACHE": str(home / "hub"),
        "HF_DATASETS_OFFLINE": "1",
        "HF_HUB_OFFLINE": "1",
        "HF_HUB_DISABLE_TELEMETRY": "1",
    }


def files_of(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


# --------------------------------------------------------------------------- raw tars


def raw_header(
    name: bytes,
    size: int,
    typeflag: bytes = b"0",
    linkname: bytes = b"",
    magic: bytes = b"ustar\x00",
    version: bytes = b"00",
) -> bytes:
    """A 512-byte tar header written by hand (what a hostile tool could write)."""
    header = bytearray(512)
    header[0 : len(name)] = name
    header[100:108] = b"0000644\x00"
    header[108:116] = b"0000000\x00"
    header[116:124] = b"0000000\x00"
    header[124:136] = b"%011o\x00" % size
    header[136:148] = b"%011o\x00" % 0
    header[156:157] = typeflag
    header[157 : 157 + len(linkname)] = linkname
    header[257:263] = magic
    header[263:265] = version
    header[148:156] = b" " * 8
    header[148:156] = b"%06o\x00 " % sum(header)
    return bytes(header)


def entry(name: str | bytes, data: bytes = b"", **header) -> bytes:
    name = name.encode() if isinstance(name, str) else name
    return raw_header(name, len(data), **header) + data + bytes(-len(data) % 512)


def assemble(entries: list[bytes]) -> bytes:
    body = b"".join(entries) + bytes(1024)
    return body + bytes(-len(body) % tarfile.RECORDSIZE)


def members(path: Path) -> list[tuple[str, bytes]]:
    """(name, data) of a tar this test suite trusts (one publish wrote)."""
    with tarfile.open(path, "r:") as tar:
        return [(m.name, tar.extractfile(m).read()) for m in tar.getmembers()]


def rewrite_tar(path: Path, items: list[tuple[str, bytes]], extra: list[bytes] = ()) -> None:
    path.write_bytes(assemble([entry(n, d) for n, d in items] + list(extra)))


# --------------------------------------------------------------------------- sealing


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def reseal(pub: Path) -> None:
    """Make every checksum of PUB agree with its files again, as a forger would: the tar
    sizes in publication.json, the FileObjects of croissant.json, then SHA256SUMS."""
    index_path = pub / "publication.json"
    index = json.loads(index_path.read_text())
    for shard in index["shards"]:
        shard["bytes"] = (pub / shard["path"]).stat().st_size
    index_path.write_text(json.dumps(index, indent=1, sort_keys=True) + "\n")
    croissant_path = pub / "croissant.json"
    croissant = json.loads(croissant_path.read_text())
    for obj in croissant["distribution"]:
        if obj["@type"] == "cr:FileObject":
            data = (pub / obj["contentUrl"]).read_bytes()
            obj["sha256"], obj["contentSize"] = sha(data), f"{len(data)} B"
    croissant_path.write_text(json.dumps(croissant, indent=2, ensure_ascii=False) + "\n")
    lines = []
    for path in sorted(p for p in pub.rglob("*") if p.is_file() and p.name != "SHA256SUMS"):
        lines.append(f"{sha(path.read_bytes())}  {path.relative_to(pub).as_posix()}\n")
    (pub / "SHA256SUMS").write_text("".join(sorted(lines, key=lambda line: line.split("  ", 1)[1])))


def rerecord(folder: Path, rel: str, data: bytes) -> None:
    """Replace a dataset file and every record of it (manifest, marker, record files), so the
    folder's checksums agree again: a consistent forgery for publish to pack."""
    (folder / rel).write_bytes(data)

    def fix(record: dict) -> dict:
        for item in record["files"]:
            if item["path"] == rel:
                item["sha256"], item["bytes"] = sha(data), len(data)
        return record

    manifest = folder / "manifest.jsonl"
    records = [fix(json.loads(line)) for line in manifest.read_text().splitlines()]
    manifest.write_text("".join(dumps(r) + "\n" for r in records))
    for marker_path in folder.glob("shards/*/COMPLETE.json"):
        marker = json.loads(marker_path.read_text())
        marker["records"] = [fix(r) for r in marker["records"]]
        marker_path.write_text(dumps(marker) + "\n")
    for record_path in folder.glob("shards/*/m*_l*.json"):
        record_path.write_text(dumps(fix(json.loads(record_path.read_text()))) + "\n")
