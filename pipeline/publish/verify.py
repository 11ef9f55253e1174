"""`shaderball verify PUB`: every checksum and every tar member of a publication, checked
without extracting anything (pipeline.publish.reader); the first problem refuses it."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

from pipeline.publish.reader import Publication, open_publication
from pipeline.publish.refusal import DEFAULT_LIMITS, Limits
from pipeline.publish.request import VerifyRequest


@dataclass(frozen=True)
class VerifyReport:
    pub: str
    files: int
    tars: int
    members: int
    samples: int
    materials: int
    bytes_checked: int
    seconds: float

    def to_dict(self) -> dict:
        return {"pub": self.pub, "ok": True, **asdict(self), "seconds": round(self.seconds, 3)}

    def lines(self) -> list[str]:
        return [
            f"{self.pub}: {self.files} files and {self.members} members of {self.tars} tar(s) checked "
            f"({self.bytes_checked / 1e6:.1f} MB, {self.seconds:.1f} s)",
            f"verified: {self.samples} samples of {self.materials} materials, every SHA-256 as listed, "
            "every member as the manifest says",
        ]


def verify_publication(publication: Publication, progress: Callable[[str], None] | None = None) -> VerifyReport:
    """Stream every member of every tar of an opened publication; raise Refused on the first problem."""
    start = time.perf_counter()
    members = 0
    for tar in publication.tars:
        if progress:
            progress(f"checking {tar.rel}")
        for _expected, _data in publication.members(tar, members):
            members += 1
    return VerifyReport(
        pub=publication.root,
        files=len(publication.sums) + 1,
        tars=len(publication.tars),
        members=members,
        samples=publication.samples,
        materials=publication.materials,
        bytes_checked=sum(publication.sizes.values()),
        seconds=time.perf_counter() - start,
    )


def verify(
    request: VerifyRequest, *, limits: Limits = DEFAULT_LIMITS, progress: Callable[[str], None] | None = None
) -> VerifyReport:
    """`shaderball verify`: every file of the publication ``request.pub`` checked, without
    extracting it; raise Refused on the first problem."""
    start = time.perf_counter()
    report = verify_publication(open_publication(request.pub, limits), progress)
    return VerifyReport(**{**report.__dict__, "seconds": time.perf_counter() - start})
