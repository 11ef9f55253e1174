"""What the writer knows about a publication once its shards are written: the input of the
dataset card (pipeline.publish.card) and of the Croissant metadata (pipeline.publish.croissant)."""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.dataset.spec import DatasetSpec

#: Hugging Face license identifiers accepted by --license, and their Croissant URLs.
LICENSES = {
    "cc-by-4.0": "https://creativecommons.org/licenses/by/4.0/",
    "cc-by-sa-4.0": "https://creativecommons.org/licenses/by-sa/4.0/",
    "cc-by-nc-4.0": "https://creativecommons.org/licenses/by-nc/4.0/",
    "cc0-1.0": "https://creativecommons.org/publicdomain/zero/1.0/",
    "mit": "https://opensource.org/licenses/MIT",
    "bsd-3-clause": "https://opensource.org/licenses/BSD-3-Clause",
    "apache-2.0": "https://www.apache.org/licenses/LICENSE-2.0",
    "other": "other",
}

CITATION = """@inproceedings{kt2019flexible,
  title     = {A Flexible Neural Renderer for Material Visualization},
  author    = {KT, Aakash and Sakurikar, Parikshit and Saini, Saurabh and Narayanan, P. J.},
  booktitle = {SIGGRAPH Asia 2019 Technical Briefs},
  year      = {2019},
  eprint    = {1908.09530},
  archivePrefix = {arXiv}
}"""


@dataclass(frozen=True)
class TarFacts:
    path: str
    kind: str  # materials or renders (pipeline.publish.names)
    bytes: int
    sha256: str
    members: int
    samples: int
    materials: int
    first: str
    last: str

    def to_dict(self) -> dict:
        return {
            "path": self.path,
            "kind": self.kind,
            "bytes": self.bytes,
            "members": self.members,
            "samples": self.samples,
            "materials": self.materials,
            "first": self.first,
            "last": self.last,
        }


@dataclass
class PublicationFacts:
    spec: DatasetSpec
    description: dict
    records: list[dict]
    rows: list[dict]
    tars: list[TarFacts]
    license_id: str
    url: str | None
    shard_bytes: int
    files: dict[str, str]  # rel -> sha256 of the files written so far
    sizes: dict[str, int]
    source_bytes: int
    member_bytes: int
    repeated_maps_extra_bytes: int
    materials: int
    has_preview: bool

    @property
    def name(self) -> str:
        return str(self.description.get("name") or self.spec.dataset.name)
