"""Hostile publications, forged here by hand: each is refused by `shaderball verify` and by
`shaderball unpack` with its own kind and a message naming the file and member, exit code 1,
and unpack writes nothing, inside --out or outside it.

Most forgeries re-seal the checksums (publication.json, croissant.json, SHA256SUMS), as an
attacker who controls the whole folder would: checksums catch corruption, the structural
checks catch malice.
"""

from __future__ import annotations

import gzip
import json
import random
import shutil
from pathlib import Path

import OpenEXR
import pytest
from click.testing import CliRunner

from cli import main
from pipeline.publish.reader import open_publication
from pipeline.publish.refusal import Limits, Refused
from pipeline.publish.request import PublishRequest, VerifyRequest
from pipeline.publish.verify import verify
from pipeline.publish.writer import publish, write_publication
from pipeline.store.exr import encode_exr, read_exr
from support.publishing import entry, files_of, members, rerecord, reseal, rewrite_tar, sha

pytestmark = pytest.mark.slow  # a smoke build (once per session)

TAR = "shards/renders-000000.tar"
RENDER = "m000000_l0.render.exr"


@pytest.fixture(scope="module")
def good(smoke, tmp_path_factory) -> Path:
    pub = tmp_path_factory.mktemp("hostile") / "good"
    publish(PublishRequest(str(smoke), str(pub), shard_bytes=300_000))
    return pub


@pytest.fixture
def pub(good, tmp_path) -> Path:
    copy = tmp_path / "work" / "pub"
    shutil.copytree(good, copy)
    return copy


# --------------------------------------------------------------------------- forgeries


def with_extra(pub: Path, *extra: bytes) -> None:
    path = pub / TAR
    rewrite_tar(path, members(path), list(extra))
    reseal(pub)


def symlink(pub):
    with_extra(pub, entry("m000000_l9.render.exr", typeflag=b"2", linkname=b"/etc/passwd"))


def hardlink(pub):
    with_extra(pub, entry("m000000_l9.render.exr", typeflag=b"1", linkname=RENDER.encode()))


def char_device(pub):
    with_extra(pub, entry("m000000_l9.render.exr", typeflag=b"3"))


def block_device(pub):
    with_extra(pub, entry("m000000_l9.render.exr", typeflag=b"4"))


def fifo(pub):
    with_extra(pub, entry("m000000_l9.render.exr", typeflag=b"6"))


def directory(pub):
    with_extra(pub, entry("m000000_l9/", typeflag=b"5"))


def gnu_sparse(pub):
    with_extra(pub, entry("m000000_l9.render.exr", b"x" * 600, typeflag=b"S", magic=b"ustar ", version=b" \x00"))


def pax_sparse(pub):
    pax = b"30 GNU.sparse.major=1\n30 GNU.sparse.minor=0\n"
    with_extra(pub, entry("././@PaxHeader", pax, typeflag=b"x"), entry("m000000_l9.render.exr", b"x" * 600))


def pax_path(pub):
    pax = b"30 path=../../../etc/cron.d/x\n"
    with_extra(pub, entry("././@PaxHeader", pax, typeflag=b"x"), entry("m000000_l9.render.exr", b"x"))


def absolute(pub):
    with_extra(pub, entry("/etc/cron.d/shaderball", b"* * * * * root true\n"))


def dotdot(pub):
    with_extra(pub, entry("../../../tmp/shaderball-escape.exr", b"x"))


def backslash(pub):
    with_extra(pub, entry("..\\..\\m000000_l9.render.exr", b"x"))


def off_layout(pub):
    with_extra(pub, entry("run.sh", b"#!/bin/sh\n"))


def duplicate(pub):
    items = members(pub / TAR)
    with_extra(pub, entry(RENDER, dict(items)[RENDER]))


def huge_member(pub):
    header = bytearray(entry(RENDER, b"")[:512])
    header[124:136] = b"%011o\x00" % (3 << 30)  # 3 GiB, over the 1 GiB cap, and past the end
    header[148:156] = b" " * 8
    header[148:156] = b"%06o\x00 " % sum(header)
    with_extra(pub, bytes(header))


def owned_member(pub):
    header = bytearray(entry("m000000_l9.render.exr", b"x")[:512])
    header[108:116] = b"0001750\x00"  # uid 1000
    header[265:270] = b"alice"  # a user name
    header[148:156] = b" " * 8
    header[148:156] = b"%06o\x00 " % sum(header)
    with_extra(pub, bytes(header) + b"x" + bytes(511))


def trailing(pub):
    path = pub / TAR
    path.write_bytes(path.read_bytes() + b"\x01" * 512)
    reseal(pub)


def compressed(pub):
    path = pub / TAR
    path.write_bytes(gzip.compress(path.read_bytes(), mtime=0))
    reseal(pub)


def shard_checksum(pub):
    path = pub / TAR
    data = bytearray(path.read_bytes())
    data[2000] ^= 0xFF
    path.write_bytes(bytes(data))  # not re-sealed: SHA256SUMS no longer matches


def member_checksum(pub):
    path = pub / TAR
    items = [(n, d[:-10] + bytes(x ^ 0xFF for x in d[-10:]) if n == RENDER else d) for n, d in members(path)]
    rewrite_tar(path, items)
    reseal(pub)


def missing_member(pub):
    path = pub / TAR
    rewrite_tar(path, [(n, d) for n, d in members(path) if n != RENDER])
    reseal(pub)


def reordered(pub):
    path = pub / TAR
    items = members(path)
    items[2], items[3] = items[3], items[2]
    rewrite_tar(path, items)
    reseal(pub)


def edited_record_member(pub):
    """A record member that says something else than the manifest, with every checksum forged."""
    path = pub / TAR
    name = "m000000_l0.json"
    items = dict(members(path))
    record = json.loads(items[name])
    record["lighting"]["turbidity"] = 9.5
    forged = (json.dumps(record, sort_keys=True, separators=(",", ":")) + "\n").encode()
    rewrite_tar(path, [(n, forged if n == name else d) for n, d in members(path)])
    rows = (pub / "samples.jsonl").read_text().splitlines()
    row = json.loads(rows[0])
    row["record_sha256"], row["record_bytes"] = sha(forged), len(forged)
    rows[0] = json.dumps(row, sort_keys=True, separators=(",", ":"))
    (pub / "samples.jsonl").write_text("\n".join(rows) + "\n")
    reseal(pub)


def escaping_manifest(pub):
    manifest = pub / "dataset" / "manifest.jsonl"
    lines = manifest.read_text().splitlines()
    record = json.loads(lines[0])
    record["files"][0]["path"] = "../../../../tmp/shaderball-escape.render.exr"
    lines[0] = json.dumps(record, sort_keys=True, separators=(",", ":"))
    manifest.write_text("\n".join(lines) + "\n")
    reseal(pub)


def unlisted_file(pub):
    (pub / "notes.txt").write_text("not listed")


def linked_file(pub):
    target = pub / "samples.jsonl"
    moved = pub.parent / "samples.jsonl"
    target.rename(moved)
    target.symlink_to(moved)


def edited_table(pub):
    rows = (pub / "samples.jsonl").read_text().splitlines()
    row = json.loads(rows[1])
    row["turbidity"] = 1.0
    rows[1] = json.dumps(row, sort_keys=True, separators=(",", ":"))
    (pub / "samples.jsonl").write_text("\n".join(rows) + "\n")
    reseal(pub)


CASES = [
    # (forgery, kind, words of the message)
    (symlink, "symlink", "member 'm000000_l9.render.exr' is a symbolic link to '/etc/passwd'"),
    (hardlink, "hardlink", "is a hard link to 'm000000_l0.render.exr'"),
    (char_device, "device", "is a character device"),
    (block_device, "device", "is a block device"),
    (fifo, "fifo", "is a FIFO (named pipe)"),
    (directory, "directory", "member 'm000000_l9/' is a directory"),
    (gnu_sparse, "sparse", "is a GNU sparse file"),
    (pax_sparse, "sparse", "is a pax-described GNU sparse file"),
    (pax_path, "pax_header", "is a pax extended header"),
    (absolute, "absolute_path", "member '/etc/cron.d/shaderball' has an absolute path"),
    (dotdot, "dotdot", "member '../../../tmp/shaderball-escape.exr' climbs out with '..'"),
    (backslash, "backslash", "contains a backslash"),
    (off_layout, "bad_name", "member 'run.sh' does not fit the layout"),
    (duplicate, "duplicate", f"member '{RENDER}' appears twice"),
    (huge_member, "member_too_large", "is 3221225472 bytes, over the cap of 1073741824 bytes per member"),
    (owned_member, "header_fields", "member 'm000000_l9.render.exr' has a header other than the one publish writes"),
    (trailing, "trailing_data", "data after the end of the archive"),
    (compressed, "compressed", "a gzip-compressed file, not a plain tar"),
    (shard_checksum, "checksum", f"{TAR}: SHA-256"),
    (member_checksum, "member_checksum", f"member '{RENDER}': SHA-256"),
    (missing_member, "missing_member", f"member(s) {RENDER} missing"),
    (reordered, "member_order", "members in plan order"),
    (edited_record_member, "bad_record", "member 'm000000_l0.json' is not the manifest's record of m000000_l0"),
    (
        escaping_manifest,
        "manifest_path",
        "render file path '../../../../tmp/shaderball-escape.render.exr' is "
        "not the layout's 'shards/s00000/m000000_l0.render.exr'",
    ),
    (unlisted_file, "unlisted_file", "notes.txt: not listed in SHA256SUMS"),
    (linked_file, "link", "samples.jsonl: a symbolic link inside PUB"),
    (edited_table, "bad_table", "samples.jsonl line 2: differs from the row dataset/manifest.jsonl line 2"),
]


def run(*args: str):
    return CliRunner().invoke(main, list(args))


def listing(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*"))


@pytest.mark.parametrize("forge, kind, words", CASES, ids=[c[0].__name__ for c in CASES])
def test_hostile_publication_is_refused_and_nothing_is_written(pub, tmp_path, forge, kind, words):
    forge(pub)
    before = listing(tmp_path)
    result = run("verify", str(pub))
    assert result.exit_code == 1, result.output
    error = result.stderr.strip().splitlines()[-1]
    assert error.startswith("error: ") and words in error, result.output
    as_json = run("verify", str(pub), "--json")
    assert as_json.exit_code == 1
    refusal = json.loads(as_json.stdout)
    assert refusal["ok"] is False and refusal["kind"] == kind and words in refusal["message"]
    out = tmp_path / "unpacked"
    unpacked = run("unpack", str(pub), "--out", str(out))
    assert unpacked.exit_code == 1 and words in unpacked.output
    assert not out.exists()
    assert listing(tmp_path) == before  # nothing written anywhere under the test's folder
    assert not Path("/tmp/shaderball-escape.exr").exists()
    assert not Path("/tmp/shaderball-escape.render.exr").exists()


def test_the_cases_have_their_own_kinds_and_messages():
    assert len({c[2] for c in CASES}) == len(CASES)
    assert len({c[1] for c in CASES}) >= len(CASES) - 3  # devices and sparse files share a kind


def test_unpack_into_an_existing_empty_folder_leaves_it_empty(pub, tmp_path):
    symlink(pub)
    out = tmp_path / "empty"
    out.mkdir()
    assert run("unpack", str(pub), "--out", str(out)).exit_code == 1
    assert out.is_dir() and list(out.iterdir()) == []


# --------------------------------------------------------------------------- forged datasets


def absurd_exr(data: bytes) -> bytes:
    """An EXR whose header says its image is 2e9 x 2e9 pixels."""
    key = b"dataWindow\x00box2i\x00" + (16).to_bytes(4, "little")
    at = data.index(key) + len(key)
    big = (2_000_000_000 - 1).to_bytes(4, "little", signed=True)
    return data[: at + 8] + big + big + data[at + 16 :]


def test_an_exr_with_an_absurd_header_is_refused_before_anything_decodes_it(smoke, tmp_path, monkeypatch):
    forged = tmp_path / "forged"
    shutil.copytree(smoke, forged)
    rel = "shards/s00000/m000000_l0.render.exr"
    rerecord(forged, rel, absurd_exr((forged / rel).read_bytes()))
    pub = tmp_path / "pub"
    write_publication(str(forged), str(pub), shard_bytes=300_000, contact_sheet=False)  # no validation

    def no_decoding(*args, **kwargs):
        raise AssertionError("an untrusted EXR reached OpenEXR")

    monkeypatch.setattr(OpenEXR, "File", no_decoding)
    out = tmp_path / "out"
    for args in (["verify", str(pub)], ["unpack", str(pub), "--out", str(out)]):
        result = run(*args)
        assert result.exit_code == 1
        assert (
            f"{TAR}: member '{RENDER}': EXR header says its data window is 2000000000 x 2000000000 pixels"
            in result.output
        ), result.output
    assert not out.exists()


def test_a_consistent_publication_of_an_invalid_dataset_is_unpacked_then_refused(smoke, tmp_path):
    forged = tmp_path / "forged"
    shutil.copytree(smoke, forged)
    rel = "shards/s00001/m000002.maps.exr"
    image = read_exr((forged / rel).read_bytes())
    layers = {name: array.copy() for name, array in image.layers.items()}
    layers["roughness"][0, 0, 0] = 1.5
    half = tuple(n for n in layers if n != "mask")
    rerecord(forged, rel, encode_exr(layers, image.meta, half=half))
    pub = tmp_path / "pub"
    write_publication(str(forged), str(pub), shard_bytes=300_000, contact_sheet=False)
    assert run("verify", str(pub)).exit_code == 0  # every checksum agrees: verify cannot know
    out = tmp_path / "new" / "parents" / "out"
    result = run("unpack", str(pub), "--out", str(out), "--json")
    assert result.exit_code == 1
    refusal = json.loads(result.stdout)
    assert refusal["kind"] == "invalid_dataset" and "m000002.maps.exr" in refusal["message"]
    assert not (tmp_path / "new").exists()  # written, then removed with the parents it made


@pytest.mark.parametrize(
    "limits, kind, words",
    [
        (Limits(member_bytes=20_000), "member_too_large", "over the cap of 20000 bytes per member"),
        (Limits(members=30), "too_many_members", "more than 30 members in the publication"),  # 48 members, 16 rows
        (Limits(total_bytes=100_000), "too_large", "over the cap of 100000"),
        (Limits(text_bytes=10_000), "too_large", "over the cap of 10000 bytes for a file read into memory"),
        (Limits(entries=5), "too_many_files", "more than 5 files and folders"),
        (Limits(exr_side=32), "exr_header", "at most 32 x 32 are accepted"),
    ],
)
def test_caps_refuse_before_reading(good, limits, kind, words):
    with pytest.raises(Refused) as caught:
        verify(VerifyRequest(str(good)), limits=limits)
    assert caught.value.kind == kind and words in str(caught.value) and caught.value.exit_code == 1


def test_the_shard_checksum_is_checked_before_the_tar_is_parsed(pub, monkeypatch):
    shard_checksum(pub)
    scanned = []
    monkeypatch.setattr("pipeline.publish.reader.scan_tar", lambda *a, **k: scanned.append(a) or [])
    publication = open_publication(str(pub))
    with pytest.raises(Refused) as caught:
        list(publication.members(next(t for t in publication.tars if t.rel == TAR)))
    assert caught.value.kind == "checksum" and scanned == []


def test_the_untouched_copy_verifies(pub, good):
    assert run("verify", str(pub)).exit_code == 0
    assert files_of(pub) == files_of(good)


# --------------------------------------------------------------------------- any change


def test_any_changed_byte_of_a_tar_is_refused_even_with_every_checksum_resealed(good, tmp_path):
    size = (good / TAR).stat().st_size
    first_padding = 512 + (len(dict(members(good / TAR))["m000000_l0.json"]))  # inside the first pad
    rng = random.Random(14)
    positions = [0, 100, 108, 124, 136, 148, 156, 257, 265, 345, first_padding, size - 1]  # header fields,
    positions += rng.sample(range(size), 40)  # padding, the end; and anywhere
    kinds = set()
    for position in positions:
        pub = tmp_path / f"p{position}"
        shutil.copytree(good, pub)
        data = bytearray((pub / TAR).read_bytes())
        data[position] ^= 0x20
        (pub / TAR).write_bytes(bytes(data))
        reseal(pub)
        with pytest.raises(Refused) as caught:
            verify(VerifyRequest(str(pub)))
        kinds.add(caught.value.kind)
        shutil.rmtree(pub)
    assert {"not_tar", "member_checksum", "trailing_data"} <= kinds  # a header's own checksum breaks first


@pytest.mark.parametrize(
    "rel",
    [
        "dataset/manifest.jsonl",
        "samples.jsonl",
        "publication.json",
        "dataset/markers.jsonl",
        "croissant.json",
        "SHA256SUMS",
    ],
)
def test_mangled_metadata_is_refused_or_harmless_never_a_crash(good, tmp_path, rel):
    rng = random.Random(rel)
    for attempt in range(15):
        pub = tmp_path / f"p{attempt}"
        shutil.copytree(good, pub)
        data = bytearray((pub / rel).read_bytes())
        at = rng.randrange(len(data))
        if attempt % 3 == 0:
            data = data[:at]
        else:
            data[at] = rng.choice(b'{}[]",:0123456789-eE.ntf \n')
        (pub / rel).write_bytes(bytes(data))
        try:
            reseal(pub)
        except Exception:  # a forger cannot re-seal what no longer parses or names no file; SHA256SUMS alone
            (pub / "SHA256SUMS").write_text(
                "".join(
                    f"{sha(p.read_bytes())}  {p.relative_to(pub).as_posix()}\n"
                    for p in sorted(pub.rglob("*"), key=lambda p: p.relative_to(pub).as_posix())
                    if p.is_file() and p.name != "SHA256SUMS"
                )
            )
        try:
            verify(VerifyRequest(str(pub)))
        except Refused:
            pass  # any other exception fails the test
        shutil.rmtree(pub)
