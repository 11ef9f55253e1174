"""Building one shard: the unit of work, idempotent under at-least-once execution.

A shard task may run twice, even at the same time, or be killed at any instant:

- every file is written atomically (temp file, fsync, rename) and its bytes are a
  pure function of the plan, so two runs write identical files;
- a sample's record (``<sample>.json``) is written only after its files are durable;
  a sample whose record verifies (files present with recorded sizes and SHA-256) is
  not rendered again;
- the shard's marker (``COMPLETE.json``), written last, lists every record. A shard
  with a marker is complete and is trusted by later builds (``validate`` checks it).
"""

from __future__ import annotations

import os
import socket
import time
from dataclasses import dataclass

from geometry import build_shaderball, default_camera
from pipeline.dataset.materialize import make_material
from pipeline.dataset.plan import MaterialPlan, SamplePlan, ShardPlan
from pipeline.dataset.spec import DatasetSpec
from pipeline.errors import ShaderballError
from pipeline.render.gbuffer import load_gbuffer
from pipeline.render.mitsuba_env import load_mitsuba
from pipeline.render.raster import project_material
from pipeline.render.renderer import RenderSettings, model_record, render_sample
from pipeline.store.atomic import write_text_atomic
from pipeline.store.exr import write_exr
from pipeline.store.folder import complete_marker, real_dir, record_problem
from pipeline.store.layout import Layout
from pipeline.store.records import SCHEMA_VERSION, dumps, file_entry, file_ok, read_json
from sky import Light

MAP_META_KEYS = ("id", "material")


@dataclass
class WorkerContext:
    """Per-process state reused across samples: geometry, camera, G-buffer, Mitsuba."""

    ball: object
    camera: object
    gbuffer: object
    settings: object
    variant: str


_CONTEXTS: dict[tuple, WorkerContext] = {}


def worker_context(spec: DatasetSpec, variant: str) -> WorkerContext:
    """This process's context for ``spec``; ``variant`` is the one the build's driver resolved."""
    r = spec.render
    key = (r.resolution, r.spp, r.max_depth, r.integrator, variant, spec.lighting.sun, r.sampler, r.rr_depth,
           r.clamp, r.target_error, spec.materials.model)
    if key not in _CONTEXTS:
        load_mitsuba(variant)
        ball, camera = build_shaderball(), default_camera()
        settings = RenderSettings(resolution=r.resolution, spp=r.spp, max_depth=r.max_depth,
                                  integrator=r.integrator, variant=variant, sun=spec.lighting.sun,
                                  sampler=r.sampler, rr_depth=r.rr_depth, clamp=r.clamp,
                                  target_error=r.target_error, model=spec.materials.model)
        _CONTEXTS[key] = WorkerContext(ball, camera, load_gbuffer(ball, camera, r.resolution, variant),
                                       settings.check(), variant)
    return _CONTEXTS[key]


def record_matches_plan(record: dict, sample: SamplePlan) -> bool:
    """The identity, seeds and requested lighting of ``record`` are the plan's."""
    try:
        requested = record["lighting"]["requested"]
        seeds = record["seeds"]
        return (record["id"] == sample.sample_id and record["material_index"] == sample.material_index
                and record["light_index"] == sample.light_index and record["shard"] == sample.shard_id
                and seeds["material"] == sample.material_seed and seeds["light"] == sample.light_seed
                and seeds["render"] == sample.render_seed
                and requested["elevation_deg"] == sample.elevation_deg
                and requested["azimuth_deg"] == sample.azimuth_deg
                and requested["turbidity"] == sample.turbidity)
    except (KeyError, TypeError):
        return False


def files_where_the_layout_says(record: dict, sample: SamplePlan) -> bool:
    """Every file ``record`` lists is at the path the layout gives its role (a render, the
    material's maps or texture file): a record naming any other path (``..``, absolute,
    another shard's file) is not this sample's, whatever its checksums say."""
    files = record.get("files")
    if not isinstance(files, list) or not files or record_problem(record, sample.shard_id):
        return False
    where = {"render": Layout.render_rel(sample.shard_id, sample.sample_id),
             "maps": Layout.maps_rel(sample.shard_id, sample.material_id),
             "texture": Layout.texture_rel(sample.shard_id, sample.material_id)}
    roles = [entry["role"] for entry in files]
    return roles[0] == "render" and len(set(roles)) == len(roles) and \
        all(where.get(entry["role"]) == entry["path"] for entry in files)


def sample_verified(root: str, record: dict | None, sample: SamplePlan,
                    checked: dict[str, bool] | None = None) -> bool:
    """``record`` is the plan's and its files are present with their recorded size and SHA-256.

    ``checked`` memoises file checks: a material's maps are shared by its lightings.
    """
    if not record or not record_matches_plan(record, sample) or not files_where_the_layout_says(record, sample):
        return False
    checked = {} if checked is None else checked
    for entry in record["files"]:
        key = dumps(entry)
        if key not in checked:
            checked[key] = file_ok(root, entry)
        if not checked[key]:
            return False
    return True


def run_shard(root: str, spec: DatasetSpec, shard: ShardPlan, variant: str) -> dict:
    """Build ``shard`` under ``root``; return a summary. Safe to run again or concurrently."""
    layout = Layout(root)
    if complete_marker(layout, shard.shard_id, [s.sample_id for s in shard.samples]) is not None:
        return {"shard": shard.shard_id, "rendered": 0, "skipped": shard.n_renders, "seconds": 0.0}
    start = time.perf_counter()
    make_shard_dir(layout, shard.shard_id)
    records, rendered = [], 0
    ctx = None
    checked: dict[str, bool] = {}
    for material in shard.materials:
        existing = [read_json(layout.path(layout.record_rel(shard.shard_id, s.sample_id)))
                    for s in material.samples]
        verified = [sample_verified(root, r, s, checked) for r, s in zip(existing, material.samples)]
        if all(verified):
            records.extend(existing)
            continue
        ctx = ctx or worker_context(spec, variant)
        existing = [r if ok else None for r, ok in zip(existing, verified)]
        new = build_material(layout, spec, ctx, material, existing)
        rendered += sum(1 for r, old in zip(new, existing) if r is not old)
        records.extend(new)
    write_marker(layout, shard, records)
    return {"shard": shard.shard_id, "rendered": rendered, "skipped": shard.n_renders - rendered,
            "seconds": time.perf_counter() - start}


def make_shard_dir(layout: Layout, shard_id: str) -> None:
    """Create ``shards/<shard_id>`` (and ``shards``) as real folders: a symbolic link in their
    place would send this shard's writes outside the dataset folder, so it is refused."""
    for path in (os.path.dirname(layout.shard_dir(shard_id)), layout.shard_dir(shard_id)):
        try:
            os.mkdir(path)
        except FileExistsError:
            if not real_dir(path):
                raise ShaderballError(
                    f"{path}: a symbolic link or not a folder where the dataset's shard folder belongs; "
                    "nothing is written through it: remove it (`shaderball validate --repair` does) "
                    "and run the build again") from None


def run_shard_in_process(out: str, spec: DatasetSpec, shard: ShardPlan, variant: str,
                         threads: int) -> dict:
    """Run one shard in this process with ``threads`` Mitsuba threads (a worker's task).

    Refuses to start where the dataset folder is not visible: a worker without the shared
    filesystem would write a dataset of its own.
    """
    if not os.path.isfile(Layout(out).spec):
        raise ShaderballError(
            f"worker on {socket.gethostname()}: the dataset directory {out!r} is not visible "
            "here (no spec.toml); every worker needs it at the same path on a shared filesystem")
    load_mitsuba(variant)
    import drjit as dr

    if dr.thread_count() != threads:
        dr.set_thread_count(threads)
    return dict(run_shard(out, spec, shard, variant), pid=f"{socket.gethostname()}:{os.getpid()}")


def write_marker(layout: Layout, shard: ShardPlan, records: list[dict]) -> None:
    marker = {
        "schema": SCHEMA_VERSION,
        "shard": shard.shard_id,
        "complete": True,
        "samples": [r["id"] for r in records],
        "records": records,
    }
    write_text_atomic(layout.marker(shard.shard_id), dumps(marker) + "\n")


def build_material(layout: Layout, spec: DatasetSpec, ctx: WorkerContext, material: MaterialPlan,
                   existing: list[dict | None]) -> list[dict]:
    """Write a material's maps (once) and every render it lacks; return all its records."""
    maps, description = make_material(material, spec)
    maps.check()
    material_files = write_material_files(layout, spec, ctx, material, maps, description)
    records = []
    for sample, old in zip(material.samples, existing):
        if old is not None and old.get("files", [])[1:] == material_files:
            records.append(old)
            continue
        records.append(render_and_record(layout, spec, ctx, sample, maps, description, material_files))
    return records


def write_material_files(layout, spec, ctx, material, maps, description) -> list[dict]:
    """The screen-space maps (and texture-space maps) of a material, stored once."""

    storage = spec.storage
    half = ("diffuse", "specular", "roughness", "normal") if storage.maps_half else ()
    meta = {"id": material.material_id, "material": description,
            "colorspace": "linear Rec.709 (sRGB primaries, D65) for diffuse and specular"}
    screen = project_material(maps, ctx.gbuffer)
    layers = {name: screen[name] for name in storage.layers}
    rel = layout.maps_rel(material.shard_id, material.material_id)
    files = [file_entry(layout.root, rel, "maps",
                        write_exr(layout.path(rel), layers, meta, half=half, compression=storage.compression))]
    if storage.texture_maps:
        rel = layout.texture_rel(material.shard_id, material.material_id)
        texture = {"diffuse": maps.diffuse, "specular": maps.specular,
                   "roughness": maps.roughness, "normal": maps.normal}
        digest = write_exr(layout.path(rel), texture, meta, half=half, compression=storage.compression)
        files.append(file_entry(layout.root, rel, "texture", digest))
    return files


def non_default_render_options(settings) -> dict:
    """Sampler, Russian roulette, clamp and adaptive target where a spec changed them (what was applied)."""
    defaults = RenderSettings(variant=settings.variant)
    return {name: getattr(settings, name) for name in ("sampler", "rr_depth", "clamp", "target_error")
            if getattr(settings, name) != getattr(defaults, name)}


def render_and_record(layout, spec, ctx, sample: SamplePlan, maps, description, material_files) -> dict:

    light = Light(sample.elevation_deg, sample.azimuth_deg, sample.turbidity)
    result = render_sample(ctx.ball, ctx.camera, maps, light, ctx.settings, sample.render_seed,
                           mask=ctx.gbuffer.mask)
    effective = Light.from_dict(result.lighting["effective"])
    stats = dict(result.stats)
    stored_stats = {k: v for k, v in stats.items() if k != "time_s"}
    meta = {"id": sample.sample_id, "material_id": sample.material_id, "lighting": result.lighting,
            "effects": result.effects.to_dict(), "stats": stored_stats,
            "colorspace": "linear Rec.709 (sRGB primaries, D65)", **model_record(ctx.settings.model)}
    rel = layout.render_rel(sample.shard_id, sample.sample_id)
    digest = write_exr(layout.path(rel), {"render": result.image}, meta,
                       compression=spec.storage.compression)
    record = {
        "schema": SCHEMA_VERSION,
        "id": sample.sample_id,
        "material_id": sample.material_id,
        "material_index": sample.material_index,
        "light_index": sample.light_index,
        "shard": sample.shard_id,
        "material": description,
        "lighting": {
            "elevation_deg": effective.elevation_deg,
            "azimuth_deg": effective.azimuth_deg,
            "turbidity": effective.turbidity,
            "direction": [float(x) for x in effective.direction],
            "requested": result.lighting["requested"],
            "policy": {k: v for k, v in result.lighting.items() if k not in ("requested", "effective")},
        },
        "lighting_vector": [float(x) for x in effective.lighting_vector()],
        "seeds": {"material": sample.material_seed, "light": sample.light_seed,
                  "render": sample.render_seed, "render_used": stats["seed"]},
        "effects": result.effects.to_dict(),
        "render": {"resolution": ctx.settings.resolution, "spp": ctx.settings.spp,
                   "max_depth": ctx.settings.max_depth, "integrator": ctx.settings.integrator,
                   "variant": ctx.variant, "sun": ctx.settings.sun, **non_default_render_options(ctx.settings),
                   **model_record(ctx.settings.model)},
        # The render's wall time (`time_s`) is the one run-dependent value of a record: it is
        # kept out of the EXR header (files are a pure function of the plan) and ignored
        # wherever records are compared (pipeline.store.records.RUN_DEPENDENT_STATS).
        "stats": stats,
        "files": [file_entry(layout.root, rel, "render", digest)] + material_files,
    }
    write_text_atomic(layout.path(layout.record_rel(sample.shard_id, sample.sample_id)), dumps(record) + "\n")
    return record
