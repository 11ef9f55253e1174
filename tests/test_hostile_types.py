"""Hostile input of other types: fields of other types in records, markers and dataset.json,
JSON whose parse would cost far more memory than its size, names with a trailing newline,
and the messages that name them."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from cli import main
from pipeline.check.info import dataset_info
from pipeline.check.preview import write_preview
from pipeline.check.request import PreviewRequest
from pipeline.check.validate import validate
from pipeline.errors import USER_ERRORS
from pipeline.publish import names
from pipeline.publish.reader import open_publication
from pipeline.publish.refusal import Refused
from pipeline.publish.request import PublishRequest
from pipeline.publish.writer import publish, write_publication
from pipeline.run.cluster import options as cluster
from pipeline.store import folder as store_folder
from pipeline.store.record_fields import RECORD_SUBFIELDS
from pipeline.store.records import dumps
from support.bombs import PEAK
from support.publishing import members, reseal, rewrite_tar, sha

pytestmark = pytest.mark.slow  # a smoke build (once per session)

REPO = Path(__file__).resolve().parents[1]
FIRST = "m000000_l0"
MARKER = "shards/s00000/COMPLETE.json"
RECORD_FILE = f"shards/s00000/{FIRST}.json"


@pytest.fixture(scope="module")
def good(smoke, tmp_path_factory) -> Path:
    pub = tmp_path_factory.mktemp("round3") / "good"
    publish(PublishRequest(str(smoke), str(pub)))
    return pub


@pytest.fixture
def pub(good, tmp_path) -> Path:
    copy = tmp_path / "pub"
    shutil.copytree(good, copy)
    return copy


def run(*args: str):
    return CliRunner().invoke(main, list(args))


def shaderball(*args: str):
    return subprocess.run([sys.executable, "-m", "cli", *args], capture_output=True, text=True, timeout=300, cwd=REPO)


# --------------------------------------------------------------------------- record field types


def _set(obj, path: tuple, value):
    for key in path[:-1]:
        obj = obj[key]
    obj[path[-1]] = value


def edit_records(root: Path, path: tuple, value, where: tuple[str, ...]) -> None:
    """Set ``path`` of the first sample's record to ``value`` in the manifest, its marker
    and/or its record file (``where``)."""

    def fix(record):
        if record.get("id") == FIRST:
            _set(record, path, value)
        return record

    if "manifest" in where:
        lines = [fix(json.loads(line)) for line in (root / "manifest.jsonl").read_text().splitlines()]
        (root / "manifest.jsonl").write_text("".join(dumps(r) + "\n" for r in lines))
    if "marker" in where:
        marker = json.loads((root / MARKER).read_text())
        marker["records"] = [fix(r) for r in marker["records"]]
        (root / MARKER).write_text(dumps(marker) + "\n")
    if "record" in where:
        (root / RECORD_FILE).write_text(dumps(fix(json.loads((root / RECORD_FILE).read_text()))) + "\n")


def test_a_record_whose_stats_is_a_list_is_reported_by_every_command(smoke, tmp_path):
    """The issue's case: stats [] in the manifest (the marker keeps the object), and a marker
    record whose stats is a string."""
    for where, value, words in (
        (("manifest",), [], "manifest.jsonl line 1 (m000000_l0): stats is an array ([]), not an object"),
        (("marker",), "fast", f'{MARKER}: record for m000000_l0: stats is a string ("fast"), not an object'),
    ):
        ds = tmp_path / where[0]
        shutil.copytree(smoke, ds)
        edit_records(ds, ("stats",), value, where)
        done = shaderball("validate", str(ds), "--json")
        assert done.returncode == 1, done.stderr[-2000:]
        report = json.loads(done.stdout)
        assert any(words in p["message"] for p in report["problems"]), report["problems"]
        for args in (["validate", str(ds), "--fast"], ["validate", str(ds)]):
            result = run(*args)
            assert result.exit_code == 1 and words in result.output, result.output
        published = run("publish", str(ds), "--out", str(tmp_path / f"pub-{where[0]}"), "--json")
        assert published.exit_code == 1 and json.loads(published.stdout)["ok"] is False
        info = run("info", str(ds), "--json")
        assert info.exit_code == 0 and json.loads(info.stdout)
        repaired = run("validate", str(ds), "--repair", "--json")
        assert repaired.exit_code == 0, repaired.output  # the good copy is kept
        assert json.loads(repaired.stdout)["ok"] is True


def _record_paths(record: dict) -> list[tuple]:
    paths = [(key,) for key in record]
    paths += [(key, name) for key in RECORD_SUBFIELDS for name in record.get(key, {})]
    paths += [("files", 0, name) for name in record["files"][0]]
    paths += [("files", 0)]
    return paths


def test_every_field_of_a_record_of_any_type_is_a_problem_never_a_crash(smoke, tmp_path):
    """Every field of a record (top level, the ones readers use inside, a file entry) set to
    an array, a string, null or a number, in the manifest, or in the marker and the record
    file: validate (fast and full), info and preview report or skip it; none raises anything
    but the project's own errors (validate's "stats is ..." problems are tested above)."""
    ds = tmp_path / "ds"
    shutil.copytree(smoke, ds)
    originals = {rel: (ds / rel).read_bytes() for rel in ("manifest.jsonl", MARKER, RECORD_FILE)}
    record = json.loads(originals["manifest.jsonl"].splitlines()[0])
    checks = {
        "validate --fast": lambda: validate(str(ds), fast=True),
        "validate": lambda: validate(str(ds)),
        "info": lambda: json.dumps(dataset_info(str(ds)).to_dict()),
        "preview": lambda: write_preview(PreviewRequest(str(ds), str(tmp_path / "p.png"), rows=1)),
    }
    crashes = []
    for path in _record_paths(record):
        for value in ([], "x", None, 1.5):
            # the manifest is read by validate alone; markers and record files by all four
            for where, names_ in ((("manifest",), ("validate --fast", "validate")), (("marker", "record"), checks)):
                for rel, data in originals.items():
                    (ds / rel).write_bytes(data)
                edit_records(ds, path, value, where)
                for name in names_:
                    try:
                        checks[name]()
                    except USER_ERRORS:
                        pass
                    except Exception as exc:  # noqa: BLE001 - what this test looks for
                        crashes.append(f"{name}: {path}={value!r} in {where}: {type(exc).__name__}: {exc}")
    assert not crashes, "\n".join(crashes[:20])


def test_every_field_of_dataset_json_and_a_marker_of_any_type_is_never_a_crash(smoke, tmp_path):
    ds = tmp_path / "ds"
    shutil.copytree(smoke, ds)
    crashes = []
    for rel in ("dataset.json", MARKER):
        original = (ds / rel).read_bytes()
        doc = json.loads(original)
        paths = [(k,) for k in doc if k != "records"]
        paths += [(k, n) for k, v in doc.items() if isinstance(v, dict) for n in v]
        for path in paths:
            for value in ([], "x", {}, None, 1.5):
                edited = json.loads(original)
                _set(edited, path, value)
                (ds / rel).write_text(dumps(edited) + "\n")
                for name, call in (
                    ("validate --fast", lambda: validate(str(ds), fast=True)),
                    ("info", lambda: json.dumps(dataset_info(str(ds)).to_dict())),
                    ("preview", lambda: write_preview(PreviewRequest(str(ds), str(tmp_path / "p.png"), rows=2))),
                ):
                    try:
                        call()
                    except USER_ERRORS:
                        pass
                    except Exception as exc:  # noqa: BLE001 - what this test looks for
                        crashes.append(f"{name}: {rel} {path}={value!r}: {type(exc).__name__}: {exc}")
        (ds / rel).write_bytes(original)
    assert not crashes, "\n".join(crashes[:20])


@pytest.mark.parametrize(
    "path, value, words",
    [
        (("counts",), "x", 'counts is a string ("x"), not an object'),
        (("libraries",), 1.5, "libraries is a number (1.5), not an object"),
        (("counts", "svbrdf_sources"), "x", 'counts.svbrdf_sources is a string ("x"), not an object'),
    ],
)
def test_a_dataset_json_field_of_another_type_fails_validation_and_publish(smoke, tmp_path, path, value, words):
    """These crashed the dataset card and Croissant writers; validate now names them."""
    ds = tmp_path / "ds"
    shutil.copytree(smoke, ds)
    description = json.loads((ds / "dataset.json").read_text())
    _set(description, path, value)
    (ds / "dataset.json").write_text(dumps(description) + "\n")
    validated = run("validate", str(ds), "--fast")
    assert validated.exit_code == 1 and f"dataset.json: {words}" in validated.output, validated.output
    published = run("publish", str(ds), "--out", str(tmp_path / "pub"), "--json")
    assert published.exit_code == 1 and words in json.loads(published.stdout)["error"]
    assert not (tmp_path / "pub").exists()


def test_build_resumes_over_a_dataset_json_field_of_another_type(smoke, tmp_path):
    ds = tmp_path / "ds"
    shutil.copytree(smoke, ds)
    description = json.loads((ds / "dataset.json").read_text())
    description["libraries"] = "x"
    (ds / "dataset.json").write_text(dumps(description) + "\n")
    result = run("build", str(REPO / "manifests" / "smoke.toml"), "--out", str(ds), "--workers", "0")
    assert result.exit_code == 0 and "rendered 0" in result.output, result.output


def _edit_published_manifest(pub: Path, edit) -> None:
    rel = pub / "dataset" / "manifest.jsonl"
    records = [json.loads(line) for line in rel.read_text().splitlines()]
    edit(records[0])
    rel.write_text("".join(dumps(r) + "\n" for r in records))
    reseal(pub)


@pytest.mark.parametrize("field, value", [("stats", []), ("lighting", "x"), ("seeds", None), ("files", {})])
def test_a_published_record_field_of_another_type_is_refused(pub, tmp_path, field, value):
    _edit_published_manifest(pub, lambda record: record.__setitem__(field, value))
    with pytest.raises(Refused) as caught:
        open_publication(str(pub))
    assert caught.value.kind == "bad_record" and "dataset/manifest.jsonl line 1" in str(caught.value)
    for args in (["verify", str(pub), "--json"], ["unpack", str(pub), "--out", str(tmp_path / "out"), "--json"]):
        result = run(*args)
        assert result.exit_code == 1 and json.loads(result.stdout)["kind"] == "bad_record"
    assert not (tmp_path / "out").exists()


def test_a_published_marker_record_whose_stats_is_a_string_is_refused(pub):
    rel = pub / "dataset" / "markers.jsonl"
    lines = rel.read_text().splitlines()
    marker = json.loads(lines[0])
    marker["records"][0]["stats"] = "fast"
    lines[0] = dumps(marker)
    rel.write_text("".join(line + "\n" for line in lines))
    reseal(pub)
    with pytest.raises(Refused) as caught:
        open_publication(str(pub))
    assert caught.value.kind == "bad_marker"


# --------------------------------------------------------------------------- memory


def _peak_of_verify(pub: Path, tmp_path: Path) -> tuple[int, float]:
    """(exit code, peak resident memory in MB) of `shaderball verify PUB` in its own process."""
    note = tmp_path / "peak.txt"
    done = subprocess.run(
        [sys.executable, "-c", PEAK, str(note), "verify", str(pub)], capture_output=True, timeout=300, cwd=REPO
    )
    return done.returncode, float(note.read_text())


def test_memory_before_refusal_is_bounded_by_the_structure(good, tmp_path):
    """A re-sealed manifest of one 30 MB line of ``[[],[],...]``: parsing it whole took ~850 MB
    (x28); it is now refused from the counts of its brackets before any parse."""
    code, baseline = _peak_of_verify(good, tmp_path)
    assert code == 0
    for name, line in (("lists", b"[" + b"[]," * 10_000_000 + b"[]]\n"), ("objects", b"{}," * 10_000_000 + b"\n")):
        pub = tmp_path / name
        shutil.copytree(good, pub)
        (pub / "dataset" / "manifest.jsonl").write_bytes(line)
        reseal(pub)
        code, peak = _peak_of_verify(pub, tmp_path)
        assert code == 1
        assert peak < baseline + 3 * len(line) / 1e6, (name, baseline, peak)  # was baseline + ~780 MB
        with pytest.raises(Refused) as caught:
            open_publication(str(pub))
        assert caught.value.kind == "too_large" and "over the cap of 1048576 for one JSON text" in str(caught.value)


@pytest.mark.parametrize(
    "line, kind, words",
    [
        (b"[" + b"[]," * 300 + b"[]]", "too_complex", "302 JSON arrays/objects"),
        (b"[" + b"0," * 5000 + b"0]", "too_complex", "5000 values"),
    ],
)
def test_a_record_line_with_more_structure_than_a_record_is_refused_before_parsing(pub, monkeypatch, line, kind, words):
    (pub / "dataset" / "manifest.jsonl").write_bytes(line + b"\n")
    reseal(pub)
    monkeypatch.setattr("pipeline.publish.small_files.json.loads", lambda *a: pytest.fail("parsed"))
    with pytest.raises(Refused) as caught:
        open_publication(str(pub))
    assert caught.value.kind == kind and words in str(caught.value)


def test_a_folder_manifest_line_with_more_structure_than_a_record_is_reported(smoke, tmp_path):
    ds = tmp_path / "ds"
    shutil.copytree(smoke, ds)
    lines = (ds / "manifest.jsonl").read_bytes().splitlines(keepends=True)
    (ds / "manifest.jsonl").write_bytes(b"[" + b"[]," * 100_000 + b"[]]\n" + b"".join(lines[1:]))
    report = validate(str(ds), fast=True)
    assert any("JSON arrays/objects" in p.message and "not parsed" in p.message for p in report.problems)


def test_the_publication_reads_its_records_again_a_tar_pair_at_a_time(good):
    publication = open_publication(str(good))
    assert (publication.samples, publication.materials) == (16, 8)
    ids = [e.sample_id for t in publication.tars if t.kind == "renders" for e in publication.expected(t)]
    assert ids[0] == FIRST and "m000007_l1" in ids and len(set(ids)) == 16
    assert sum(t.count for t in publication.tars) == sum(1 for t in publication.tars for _ in publication.expected(t))


# --------------------------------------------------------------------------- names


def test_no_name_pattern_accepts_a_trailing_newline_or_other_digits():
    for pattern, good_name in (
        (names.SHARD_ID, "s00000"),
        (names.SAMPLE_ID, "m000000_l0"),
        (names.MATERIAL_ID, "m000000"),
        (names.MEMBER_NAME, "m000000_l0.json"),
        (names.TAR_NAME, "shards/renders-000000.tar"),
        (store_folder.SHARD_NAME, "s00000"),
        (store_folder.RECORD_NAME, "m000000_l0.json"),
    ):
        assert pattern.match(good_name), pattern
        assert not pattern.match(good_name + "\n"), pattern
        assert not pattern.match(good_name.replace("0", "\u0660")), pattern  # Arabic-Indic zero
    for pattern, good_word in (
        (cluster._SHELL_WORD, "gpu"),
        (cluster._WALLTIME, "01:00:00"),
        (cluster._SCRATCH, "/tmp"),
    ):
        assert pattern.match(good_word) and not pattern.match(good_word + "\n"), pattern
    with pytest.raises(USER_ERRORS):
        cluster.ClusterOptions(cluster="slurm", queue="gpu\n#SBATCH --uid=0")


def _rename_shard(root: Path, old: str, new: str) -> None:
    """A consistent forgery: shard ``old`` renamed ``new`` in every record, path and folder."""

    def fix(record):
        if record.get("shard") == old:
            record["shard"] = new
            for item in record["files"]:
                item["path"] = item["path"].replace(f"shards/{old}/", f"shards/{new}/")
        return record

    manifest = root / "manifest.jsonl"
    manifest.write_text("".join(dumps(fix(json.loads(line))) + "\n" for line in manifest.read_text().splitlines()))
    marker = json.loads((root / "shards" / old / "COMPLETE.json").read_text())
    marker["shard"] = new
    marker["records"] = [fix(r) for r in marker["records"]]
    (root / "shards" / old / "COMPLETE.json").write_text(dumps(marker) + "\n")
    for path in (root / "shards" / old).glob("m*_l*.json"):
        path.write_text(dumps(fix(json.loads(path.read_text()))) + "\n")
    (root / "shards" / old).rename(root / "shards" / new)


def test_a_shard_id_with_a_trailing_newline_is_refused(smoke, tmp_path, monkeypatch):
    forged = tmp_path / "forged"
    shutil.copytree(smoke, forged)
    _rename_shard(forged, "s00000", "s00000\n")
    pub = tmp_path / "pub"
    # publish itself refuses the name now: write it as a tool with the old check would
    monkeypatch.setattr("pipeline.publish.table.SHARD_ID", re.compile(r"^s\d{5}$"))
    write_publication(str(forged), str(pub), contact_sheet=False)  # no validation: as a forger would
    monkeypatch.undo()
    verified = shaderball("verify", str(pub), "--json")
    assert verified.returncode == 1, verified.stdout
    refusal = json.loads(verified.stdout)
    assert refusal["kind"] == "bad_record" and "shard 's00000\\n' does not fit the layout" in refusal["error"]
    out = tmp_path / "out"
    unpacked = run("unpack", str(pub), "--out", str(out), "--no-validate")
    assert unpacked.exit_code == 1 and not out.exists()


def test_a_member_name_with_a_trailing_newline_is_refused_and_shown_escaped(pub):
    tar = pub / "shards" / "renders-000000.tar"
    items = members(tar)
    items[0] = (items[0][0] + "\n", items[0][1])
    rewrite_tar(tar, items)
    reseal(pub)
    result = run("verify", str(pub))
    assert result.exit_code == 1
    error = result.stderr.strip().splitlines()[-1]
    assert "member 'm000000_l0.json\\n' does not fit the layout" in error, result.stderr


def test_a_file_name_with_a_newline_is_shown_escaped(pub):
    (pub / "notes\n.txt").write_text("x")
    result = run("verify", str(pub))
    assert result.exit_code == 1 and "'notes\\n.txt': not listed in SHA256SUMS" in result.stderr


# --------------------------------------------------------------------------- messages


def test_a_tar_size_of_another_type_names_the_type(pub):
    index = json.loads((pub / "publication.json").read_text())
    size = index["shards"][0]["bytes"]
    index["shards"][0]["bytes"] = str(size)
    (pub / "publication.json").write_text(json.dumps(index, indent=1, sort_keys=True) + "\n")
    reseal_sums_only(pub)
    with pytest.raises(Refused) as caught:
        open_publication(str(pub))
    assert f'gives its size as a string ("{size}"), not an integer number of bytes (the file has {size})' in str(
        caught.value
    )


def reseal_sums_only(pub: Path) -> None:
    """SHA256SUMS (and croissant.json's copies of it) again, publication.json left as edited."""
    croissant = json.loads((pub / "croissant.json").read_text())
    for obj in croissant["distribution"]:
        if obj["@type"] == "cr:FileObject":
            data = (pub / obj["contentUrl"]).read_bytes()
            obj["sha256"], obj["contentSize"] = sha(data), f"{len(data)} B"
    (pub / "croissant.json").write_text(json.dumps(croissant, indent=2, ensure_ascii=False) + "\n")
    lines = [
        f"{sha(p.read_bytes())}  {p.relative_to(pub).as_posix()}\n"
        for p in sorted(pub.rglob("*"))
        if p.is_file() and p.name != "SHA256SUMS"
    ]
    (pub / "SHA256SUMS").write_text("".join(sorted(lines, key=lambda line: line.split("  ", 1)[1])))


def test_preview_marks_an_undecodable_exr_and_names_the_file(smoke, tmp_path):
    ds = tmp_path / "ds"
    shutil.copytree(smoke, ds)
    render = ds / "shards" / "s00000" / f"{FIRST}.render.exr"
    render.write_bytes(b"not an EXR at all".ljust(render.stat().st_size, b"\0"))  # the size its record gives
    result = run("preview", str(ds), "--out", str(tmp_path / "p.png"))
    assert result.exit_code == 1, result.output  # written, with a problem: validate's "problems found"
    assert f"cannot decode EXR shards/s00000/{FIRST}.render.exr" in result.output
    assert "<bytes>" not in result.output
    assert (tmp_path / "p.png").stat().st_size > 0
