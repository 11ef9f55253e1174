"""What opening a dataset keeps of its manifest, read a line at a time, each record checked
(a ShaderballError naming the line): the records by id, parsed again when asked for
(:class:`ManifestRecords`: a byte offset and length each), every sample's files and lighting
vector as columns (:class:`SampleColumns`), the renders' resolutions and the digest of what
the manifest says of the samples (:func:`sample_digest_line`); with the dataset folder's
description and manifest, checked readable (:func:`folder_manifest`)."""

from __future__ import annotations

import hashlib
import json
import os
from array import array
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.errors import ShaderballError, quoted, short_repr
from pipeline.neural.file_sources import FolderFiles, dataset_refused
from pipeline.store.bounded_read import read_json_checked, read_line_at, structure_problem
from pipeline.store.folder import iter_manifest
from pipeline.store.layout import Layout
from pipeline.store.record_fields import record_problem


def read_json_file(path: str, root: str):
    """A small JSON file of the dataset folder ``root`` (a regular file, bounded: pipeline.store.bounded_read)."""
    value, why = read_json_checked(path)
    if why == "missing":
        raise dataset_refused(root, f"{quoted(root)} has no {os.path.basename(path)}")
    if why is not None:
        raise ShaderballError(f"{path}: not readable JSON ({why}); check the folder with `shaderball validate`")
    return value


def expected_renders(description: dict) -> int | None:
    counts = description.get("counts") if isinstance(description.get("counts"), dict) else {}
    return counts.get("renders") if isinstance(counts.get("renders"), int) else None


def folder_manifest(root: str) -> tuple[dict, str]:
    """dataset.json of a complete dataset folder and its manifest's path (checked readable)."""
    layout = Layout(root)
    if not os.path.isdir(root):
        raise dataset_refused(
            root, f"{quoted(root)} does not exist" if not os.path.lexists(root) else f"{quoted(root)} is not a folder"
        )
    description = read_json_file(layout.description, root)
    if not isinstance(description, dict):
        raise ShaderballError(f"{layout.description}: not a JSON object; check the folder with `shaderball validate`")
    if not os.path.lexists(layout.manifest):
        raise dataset_refused(
            root,
            f"{quoted(root)} is incomplete: no {os.path.basename(layout.manifest)} (written when a build completes)",
            "finish it with `shaderball build SPEC --out DIR`",
        )
    try:
        for _line in iter_manifest(layout, expected_renders(description)):
            break  # opened and within its bound: read a line at a time by index_records
    except OSError as exc:
        raise ShaderballError(
            f"{layout.manifest} cannot be read ({exc.strerror}); check the folder with `shaderball validate`"
        ) from None
    return description, layout.manifest


def parse_records(data: bytes, description: dict, root: str, where: str, checker: str) -> list[dict]:
    """The records of a manifest's bytes, each checked (pipeline.store.record_fields.record_problem),
    as many as ``dataset.json`` counts."""
    records = [checked_record(line, number, where, checker) for number, _offset, line in byte_lines(data)]
    return _count_check(records, description, root)


def byte_lines(data: bytes):
    """(line number, offset, line) of every non-empty line of ``data``."""
    offset = 0
    for number, line in enumerate(data.split(b"\n"), start=1):
        if line.strip():
            yield number, offset, line
        offset += len(line) + 1


def _count_check(records, description: dict, root: str):
    expected = expected_renders(description)
    if expected is not None and len(records) != expected:
        raise dataset_refused(
            root,
            f"{quoted(root)} is incomplete: the manifest lists {len(records)} of {expected} renders",
            "finish it with `shaderball build`",
        )
    if not records:
        raise dataset_refused(root, f"{quoted(root)} has no renders", "a dataset of one render or more")
    return records


def checked_record(line: bytes, number: int, where: str, checker: str) -> dict:
    """The record on manifest line ``number``, checked (a ShaderballError naming the line)."""
    too_much = structure_problem(line)
    if too_much:
        raise ShaderballError(f"{where} line {number}: {too_much}; check it with {checker}")
    try:
        record = json.loads(line)
    except (ValueError, RecursionError):
        raise ShaderballError(f"{where} line {number} is not JSON; check it with {checker}") from None
    problem = record_problem(record)
    if problem:
        raise ShaderballError(f"{where} line {number}: {problem}; check it with {checker}")
    return record


@dataclass(frozen=True, slots=True)
class SampleFiles:
    id: str
    material_id: str
    render: tuple[str, str, int]  # (key of the file in its source, sha256, bytes)
    maps: tuple[str, str, int]
    lighting_vector: tuple[float, float, float, float]
    texture: tuple[str, str, int] | None = None


def sample_files(files, record: dict) -> SampleFiles:
    """A record's files (``files``: a :class:`FolderFiles` or :class:`PublishedFiles`, or a
    dataset folder's path)."""
    if isinstance(files, str):
        files = FolderFiles(files)
    refs = {}
    for entry in record.get("files", []):
        refs[entry.get("role")] = (files.key(entry.get("path")), entry.get("sha256"), entry.get("bytes"))
    missing = [role for role in ("render", "maps") if role not in refs]
    if missing:
        raise ShaderballError(
            f"manifest: record {short_repr(record.get('id'))} lists no {' and no '.join(missing)} file"
        )
    if not isinstance(record.get("material_id"), str):
        raise ShaderballError(f"manifest: record {short_repr(record.get('id'))} has no material_id")
    vector = record.get("lighting_vector")
    if not (isinstance(vector, list) and len(vector) == 4 and all(isinstance(v, (int, float)) for v in vector)):
        raise ShaderballError(f"manifest: record {short_repr(record.get('id'))} has no 4-value lighting_vector")
    return SampleFiles(
        record["id"],
        record["material_id"],
        refs["render"],
        refs["maps"],
        tuple(float(v) for v in vector),
        refs.get("texture"),
    )


class ManifestRecords(Mapping):
    """The manifest's records by sample id, each parsed when asked for: only where its line
    lies is kept (a byte offset and a length, numpy arrays), in the manifest file of a folder
    or in the manifest's bytes a publication's reader holds."""

    def __init__(self, source: str | bytes, offsets: np.ndarray, lengths: np.ndarray, positions: dict[str, int]):
        self.source, self.offsets, self.lengths, self.positions = source, offsets, lengths, positions

    def __getitem__(self, sample_id: str) -> dict:
        position = self.positions[sample_id]
        offset, length = int(self.offsets[position]), int(self.lengths[position])
        if isinstance(self.source, bytes):
            line = self.source[offset : offset + length]
        else:
            try:
                line = read_line_at(self.source, offset, length)
            except OSError as exc:
                raise ShaderballError(f"{self.source} cannot be read ({exc.strerror})") from None
        try:
            record = json.loads(line)
        except (ValueError, RecursionError):
            record = None
        if not isinstance(record, dict) or record.get("id") != sample_id:
            raise ShaderballError(
                f"{self.source if isinstance(self.source, str) else 'the manifest'}: changed since it "
                f"was opened (no record of {sample_id} where it was); open the dataset again"
            )
        return record

    def __iter__(self):
        return iter(self.positions)

    def __len__(self) -> int:
        return len(self.positions)


class SampleColumns(Sequence):
    """Every sample's :class:`SampleFiles`, kept as columns (its id, its render's path and
    SHA-256, its lighting vector, its material's number; a material's id and maps once) and
    made when asked for: ~0.2 kB a sample where a list of them holds ~0.7 kB."""

    def __init__(self, files):
        self.files = files
        self.ids: list[str] = []
        self.render_paths: list[str] = []
        self.render_sha256 = bytearray()  # 32 bytes a sample
        self.render_bytes = array("q")  # the render's size, as the manifest records it
        self.odd_bytes: dict[int, int] = {}  # row -> a recorded size outside int64, kept as it is
        self.lighting = array("d")  # 4 a sample
        self.material = array("l")  # index into self.materials
        self.materials: list[tuple] = []  # (material id, maps ref, texture ref)
        self._material_at: dict = {}
        self.odd_sha256: dict[int, object] = {}  # row -> a recorded sha256 that is not 64 lowercase hex digits
        self.rows: range | np.ndarray = range(0)  # the samples of this view, in order

    def append(self, sample: SampleFiles, render_path: str) -> None:
        material = (sample.material_id, sample.maps, sample.texture)
        number = self._material_at.setdefault(material, len(self.materials))
        if number == len(self.materials):
            self.materials.append(material)
        row, sha256, size = len(self.ids), sample.render[1], sample.render[2]
        if not _is_sha256(sha256):  # kept as it is: the file's digest will not match it when read
            self.odd_sha256[row] = sha256
        if not -(1 << 63) <= size < 1 << 63:  # kept as it is: no file has that size, it is refused when read
            self.odd_bytes[row] = size
        self.ids.append(sample.id)
        self.render_paths.append(render_path)
        self.render_sha256 += bytes.fromhex(sha256) if _is_sha256(sha256) else bytes(32)
        self.render_bytes.append(-1 if row in self.odd_bytes else size)
        self.lighting.extend(sample.lighting_vector)
        self.material.append(number)
        self.rows = range(len(self.ids))

    def _one(self, row: int) -> SampleFiles:
        material_id, maps, texture = self.materials[self.material[row]]
        return SampleFiles(
            self.ids[row],
            material_id,
            (
                self.files.key(self.render_paths[row]),
                self._sha256(row),
                self.odd_bytes.get(row, self.render_bytes[row]),
            ),
            maps,
            tuple(self.lighting[4 * row : 4 * row + 4]),
            texture,
        )

    def _sha256(self, row: int):
        if row in self.odd_sha256:
            return self.odd_sha256[row]
        return self.render_sha256[32 * row : 32 * row + 32].hex()

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return self._one(int(self.rows[index]))

    def material_ids(self) -> list[str]:
        return sorted({self.materials[self.material[row]][0] for row in self.rows})

    def of_materials(self, material_ids) -> SampleColumns:
        """The samples of these materials, in order (a view: the columns are shared)."""
        keep = set(material_ids)
        view = SampleColumns.__new__(SampleColumns)
        view.__dict__.update(self.__dict__)
        view.rows = np.asarray([row for row in self.rows if self.materials[self.material[row]][0] in keep], np.int64)
        return view

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_material_at"] = {}  # only needed while appending
        return state


@dataclass
class ManifestIndex:
    """What opening a dataset keeps of its manifest: the records by id (parsed when asked
    for), each sample's files and lighting vector, the renders' resolutions, and the
    digest of what the manifest says of the samples (:func:`sample_digest_line`)."""

    records: ManifestRecords
    samples: SampleColumns
    resolutions: set
    samples_sha256: str = ""


def sample_digest_line(record: dict) -> bytes:
    """What a record says of its sample's data, as canonical JSON: its id, material, lighting
    vector and files (role, path, SHA-256). A rebuild of the same spec writes the same bytes
    in every file, but not the same manifest (each record holds its render's time)."""
    files = sorted((e.get("role"), e.get("path"), e.get("sha256")) for e in record.get("files", []))
    data = [record.get("id"), record.get("material_id"), record.get("lighting_vector"), files]
    return json.dumps(data, separators=(",", ":")).encode() + b"\n"


def index_records(lines, source: str | bytes, files, description: dict, root: str, where: str, checker: str):
    """:class:`ManifestIndex` of the manifest ``lines`` ((number, offset, line) of each line),
    each record checked as :func:`parse_records` checks it, one at a time."""
    offsets, lengths, positions, samples, resolutions = array("q"), array("q"), {}, SampleColumns(files), set()
    content = hashlib.sha256()
    for number, offset, line in lines:
        if not line.strip():
            continue
        record = checked_record(line, number, where, checker)
        sample = sample_files(files, record)  # every path checked now, and again when read
        render_path = [e.get("path") for e in record["files"] if e.get("role") == "render"][-1]
        samples.append(sample, render_path)
        positions[record["id"]] = len(offsets)  # a repeated id: its last record, as a dict of them keeps
        offsets.append(offset)
        lengths.append(len(line))
        resolutions.add((record.get("render") or {}).get("resolution"))
        content.update(sample_digest_line(record))
    _count_check(samples, description, root)
    records = ManifestRecords(source, np.frombuffer(offsets, np.int64), np.frombuffer(lengths, np.int64), positions)
    return ManifestIndex(records, samples, resolutions, content.hexdigest())


def _is_sha256(text) -> bool:
    return isinstance(text, str) and len(text) == 64 and all(c in "0123456789abcdef" for c in text)
