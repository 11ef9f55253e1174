"""What the writer knows about a publication once its shards are written: the input of the
dataset card (pipeline.publish.card) and of the Croissant metadata (pipeline.publish.croissant)."""

from __future__ import annotations

from array import array
from dataclasses import asdict, dataclass, field

from pipeline.dataset.spec import DatasetSpec
from pipeline.publish.scene_fields import SceneSummary

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
        """Every field but the SHA-256 (SHA256SUMS lists each file's)."""
        return {k: v for k, v in asdict(self).items() if k != "sha256"}


def _number(value) -> bool:
    return isinstance(value, (int, float))


@dataclass
class RecordSummary:
    """What the card and the Croissant metadata say of the published records, summed one
    record (and its samples-table row) at a time: no record is kept."""

    samples: int = 0
    policy_changed: int = 0  # suns the low-sun policy raised
    flagged: list = field(default_factory=list)  # ids of flagged renders (few)
    noise: array = field(default_factory=lambda: array("d"))  # stats.noise_relative, 8 bytes a render
    elevation: tuple | None = None  # (least, greatest) rendered elevation, degrees
    turbidity: tuple | None = None
    effects_off: dict = field(default_factory=dict)  # effect -> renders without it
    has_texture: bool = False  # a row lists a texture-space maps file
    scene: SceneSummary = field(default_factory=SceneSummary)  # objects and maps (the card lists them)

    def add(self, record: dict, row: dict, effects) -> None:
        self.samples += 1
        lighting = record.get("lighting") or {}
        stats = record.get("stats") or {}
        self.policy_changed += bool((lighting.get("policy") or {}).get("changed"))
        if stats.get("flagged"):
            self.flagged.append(record["id"])
        if _number(stats.get("noise_relative")):
            self.noise.append(stats["noise_relative"])
        self.elevation = _widen(self.elevation, lighting.get("elevation_deg"))
        self.turbidity = _widen(self.turbidity, lighting.get("turbidity"))
        for key in effects:
            self.effects_off[key] = self.effects_off.get(key, 0) + ((record.get("effects") or {}).get(key) is False)
        self.has_texture = self.has_texture or bool(row.get("texture"))
        self.scene.add(record)


def _widen(span: tuple | None, value) -> tuple | None:
    if not _number(value):
        return span
    return (value, value) if span is None else (min(span[0], value), max(span[1], value))


@dataclass
class PublicationFacts:
    spec: DatasetSpec
    description: dict
    summary: RecordSummary
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
