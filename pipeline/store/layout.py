"""The one place that knows the on-disk layout of a dataset directory.

    DIR/
      spec.toml                      snapshot of the spec the dataset was built from
      dataset.json                   description: versions, variant, counts, spec digest
      manifest.jsonl                 one record per render, in plan order (once complete)
      shards/s00003/
        m000012.maps.exr             screen-space maps of a material (half), stored once
        m000012.texture.exr          texture-space maps of a material (optional)
        m000012_l0.render.exr        one render per lighting (float32)
        m000012_l0.json              the sample's record, written after its files are durable
        COMPLETE.json                the shard's marker: every record, with file checksums
      .shaderball.lock               while a writer runs: who holds the folder (pipeline.store.lock)

Paths inside records are relative to DIR, with forward slashes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

SPEC_FILE = "spec.toml"
DESCRIPTION_FILE = "dataset.json"
MANIFEST_FILE = "manifest.jsonl"
SHARDS_DIR = "shards"
MARKER_FILE = "COMPLETE.json"
#: The writer lock (pipeline.store.lock): present while a build, repair or unpack writes
#: the folder (and after one was killed); no part of the data.
LOCK_FILE = ".shaderball.lock"


@dataclass(frozen=True)
class Layout:
    root: str

    def path(self, rel: str) -> str:
        return os.path.join(self.root, *rel.split("/"))

    @property
    def spec(self) -> str:
        return os.path.join(self.root, SPEC_FILE)

    @property
    def description(self) -> str:
        return os.path.join(self.root, DESCRIPTION_FILE)

    @property
    def manifest(self) -> str:
        return os.path.join(self.root, MANIFEST_FILE)

    def shard_dir(self, shard_id: str) -> str:
        return os.path.join(self.root, SHARDS_DIR, shard_id)

    def marker(self, shard_id: str) -> str:
        return os.path.join(self.shard_dir(shard_id), MARKER_FILE)

    # Relative paths, as stored in records.
    @staticmethod
    def maps_rel(shard_id: str, material_id: str) -> str:
        return f"{SHARDS_DIR}/{shard_id}/{material_id}.maps.exr"

    @staticmethod
    def texture_rel(shard_id: str, material_id: str) -> str:
        return f"{SHARDS_DIR}/{shard_id}/{material_id}.texture.exr"

    @staticmethod
    def render_rel(shard_id: str, sample_id: str) -> str:
        return f"{SHARDS_DIR}/{shard_id}/{sample_id}.render.exr"

    @staticmethod
    def record_rel(shard_id: str, sample_id: str) -> str:
        return f"{SHARDS_DIR}/{shard_id}/{sample_id}.json"

    @staticmethod
    def marker_rel(shard_id: str) -> str:
        return f"{SHARDS_DIR}/{shard_id}/{MARKER_FILE}"
