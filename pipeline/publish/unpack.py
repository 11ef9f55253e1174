"""`shaderball unpack PUB --out DIR`: the dataset folder a publication was made from, byte
for byte, then validated (`shaderball validate`).

The publication is verified in full first (pipeline.publish.verify), so a refused one
writes nothing; the members are then streamed again and checked again as they are written
(a file changed in between is refused too). Every path written is the layout's
(pipeline.store.layout) for ids that fit it, inside DIR. On any refusal or error what the
unpack made is removed again (pipeline.publish.output.Output.discard): the files it wrote,
then the folders it created if nothing else is in them, so DIR is left as it was found
(absent, or empty) and whatever another process wrote meanwhile stays. DIR is held for writing (pipeline.store.lock) while
it is written, as a build holds it: one writer at a time.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

from pipeline.check.validate import validate
from pipeline.errors import filesystem_error
from pipeline.publish.output import FILLED_MEANWHILE, Output, check_out
from pipeline.publish.reader import open_publication
from pipeline.publish.refusal import DEFAULT_LIMITS, Limits, refuse_invalid
from pipeline.publish.request import UnpackRequest, out_refused
from pipeline.publish.verify import verify_publication
from pipeline.store.folder import only_temp_files
from pipeline.store.layout import MANIFEST_FILE, Layout
from pipeline.store.lock import writer_lock


@dataclass(frozen=True)
class UnpackSummary:
    pub: str
    out: str
    files: int
    samples: int
    bytes_written: int
    validated: bool
    seconds: float

    def to_dict(self) -> dict:
        return {**asdict(self), "seconds": round(self.seconds, 3)}

    def lines(self) -> list[str]:
        check = "valid (`shaderball validate`)" if self.validated else "not validated (--no-validate)"
        return [
            f"unpacked {self.pub} into {self.out}: {self.samples} samples, {self.files} files, "
            f"{self.bytes_written / 1e6:.1f} MB in {self.seconds:.1f} s; {check}"
        ]


def unpack(
    request: UnpackRequest, *, limits: Limits = DEFAULT_LIMITS, progress: Callable[[str], None] | None = None
) -> UnpackSummary:
    """Restore the dataset folder of the publication ``request.pub`` into ``request.out`` (new
    or empty), validated after unless ``request.validate`` is False."""
    pub, out, validate_after = request.pub, request.out, request.validate
    start = time.perf_counter()
    check_out(out, pub, owner=UnpackRequest)
    publication = open_publication(pub, limits)
    verify_publication(publication, progress)
    try:
        output = Output(out, listed=False)
        try:
            with writer_lock(out, "unpack"):
                return _unpack_locked(pub, out, publication, output, validate_after, progress, start)
        except BaseException:
            output.discard()  # its files went under the lock; its folders go once the lock file has
            raise
    except OSError as exc:  # what was written is removed again (Output.discard)
        raise filesystem_error(exc, out, "nothing was kept: fix the cause and run the same command again") from None


def _unpack_locked(pub, out, publication, output: Output, validate_after: bool, progress, start) -> UnpackSummary:
    """Write the folder while this process holds it (pipeline.store.lock): a build or a second
    unpack started meanwhile is refused, and one that got there first is not written over."""
    if not only_temp_files(os.listdir(out)):
        raise out_refused(out, FILLED_MEANWHILE, UnpackRequest)
    try:
        _write_in_completion_order(publication, output, progress)
        if validate_after:
            if progress:
                progress(f"validating {out}")
            refuse_invalid(validate(out), "the unpacked folder", "nothing was kept")
    except BaseException:
        output.discard()
        raise
    return UnpackSummary(
        pub=pub,
        out=out,
        files=output.files,
        samples=publication.samples,
        bytes_written=output.bytes,
        validated=validate_after,
        seconds=time.perf_counter() - start,
    )


def _write_in_completion_order(publication, output: Output, progress) -> None:
    """Write the folder so that a kill at any instant leaves one that every reader (info,
    build, validate, preview, publish) sees as incomplete: what a build writes first
    (spec.toml, dataset.json), then every data file, each sample's record file after its
    render, then the shards' markers, and manifest.jsonl last. A marker is written only
    when every file it names is durable, as a build writes one (docs/publish.md)."""
    for name, data in publication.small_files.items():
        output.write(name, data)
    before = 0
    for tar in publication.tars:
        if progress:
            progress(f"unpacking {tar.rel}")
        record = None
        for expected, data in publication.members(tar, before):
            if expected.path is None:  # previews and material rows are the publication's own
                continue
            if expected.role == "record":  # its member comes before the render it names
                record = (expected.path, data)
                continue
            output.write(expected.path, data)
            if expected.role == "render" and record is not None:
                output.write(*record)
                record = None
        if record is not None:  # the members' order is checked: a record is followed by its render
            raise AssertionError(f"{tar.rel}: a record member without its render")
        before += tar.count
    for shard, data in publication.markers():
        output.write(Layout.marker_rel(shard), data)
    output.write_chunks(MANIFEST_FILE, publication.manifest_chunks())  # a piece at a time, never whole
