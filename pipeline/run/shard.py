"""Building one shard: the unit of work, idempotent under at-least-once execution.

A shard task may run twice, even at the same time, or be killed at any instant:

- every file is written atomically (temp file, fsync, rename) and its bytes are a
  pure function of the plan, so two runs write identical files;
- a sample's record (``<sample>.json``) is written only after its files are durable;
  a sample whose record verifies (files present with recorded sizes and SHA-256) is
  not rendered again;
- the shard's marker (``COMPLETE.json``), written last, lists every record. A shard
  with a marker is complete and is trusted by later builds (``validate`` checks it).

Rendering and writing overlap: the maps' raster projection, EXR encoding, SHA-256, fsync
and records run on one writer thread (:class:`OrderedWriter`), in the order a synchronous
build would write them, while the next render runs; the next material's maps are made
on a thread of their own. A scene is loaded once and moved from material to material and
lighting to lighting (:class:`pipeline.render.renderer.MaterialScene`): across a shard,
and across every shard of an in-process build.
"""

from __future__ import annotations

import contextlib
import os
import socket
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

from geometry.objects import build_object, object_camera
from pipeline.dataset.materialize import make_material
from pipeline.dataset.plan import MaterialPlan, SamplePlan, ShardPlan
from pipeline.dataset.record import model_record
from pipeline.dataset.spec import DEFAULT_OBJECTS, DatasetSpec
from pipeline.dataset.spec_file import source_file_digests
from pipeline.errors import ShaderballError, quoted
from pipeline.render.gbuffer import load_gbuffer
from pipeline.render.mitsuba_env import load_mitsuba, machine_fingerprint
from pipeline.render.raster import project_material
from pipeline.render.renderer import MaterialScene, RenderSettings, render_sample
from pipeline.store.atomic import write_text_atomic
from pipeline.store.exr import MATERIAL_MAP_LAYERS, write_exr
from pipeline.store.folder import complete_marker, real_dir
from pipeline.store.layout import Layout
from pipeline.store.record_fields import record_problem
from pipeline.store.records import SCHEMA_VERSION, dumps, file_entry, file_ok, read_json
from sky import Light
from sky.environment import EnvironmentLight

MAP_META_KEYS = ("id", "material")


@dataclass
class WorkerContext:
    """Per-process state reused across samples: an object, its camera and G-buffer, Mitsuba."""

    ball: object  # the object the material is shown on (geometry.objects: the shaderball or another)
    camera: object
    gbuffer: object
    settings: object
    variant: str


_CONTEXTS: dict[tuple[RenderSettings, str], WorkerContext] = {}


def worker_context(spec: DatasetSpec, variant: str, object_name: str = DEFAULT_OBJECTS[0]) -> WorkerContext:
    """This process's context for ``spec`` and one of its objects (a built-in name or a mesh
    file's path: built, or read from the geometry cache, once per process); ``variant`` is the
    one the build's driver resolved."""
    settings = spec.render.resolved(variant)  # the spec's [render] with lighting.sun and materials.model
    key = (settings, object_name)
    if key not in _CONTEXTS:
        load_mitsuba(variant)
        ball = build_object(object_name)
        camera = object_camera(ball)
        gbuffer = load_gbuffer(ball, camera, settings.resolution, variant)
        _CONTEXTS[key] = WorkerContext(ball, camera, gbuffer, settings, variant)
    return _CONTEXTS[key]


class OrderedWriter:
    """Runs a shard's writes on one thread, in submission order, beside the next render.

    Crash safety is the synchronous build's: the jobs run one at a time in the order they
    were submitted, and each render job writes its EXR (temp file, fsync, rename) before its
    record, after the material files it lists (submitted earlier); the marker is written
    only after :meth:`close`. A process killed at any instant leaves what a synchronous
    build killed at some instant would. After a job fails no later job runs (a record must
    not follow a write that failed); the error is raised in the caller at the next
    :meth:`submit` or at :meth:`close`. At most ``max_pending`` jobs wait (memory bound: a
    job holds one render's pixels).
    """

    def __init__(self, max_pending: int = 4):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="shard-writer")
        self._pending: deque[Future] = deque()
        self._max_pending = max_pending
        self._failed: BaseException | None = None

    def _run(self, fn, args):
        if self._failed is not None:
            raise RuntimeError("skipped: an earlier write of this shard failed")
        try:
            return fn(*args)
        except BaseException as exc:
            self._failed = exc
            raise

    def submit(self, fn, *args) -> Future:
        """Queue ``fn(*args)``; its future holds what it returns."""
        self._raise_failure()
        while len(self._pending) >= self._max_pending:
            self._pending.popleft().exception()
            self._raise_failure()
        future = self._pool.submit(self._run, fn, args)
        self._pending.append(future)
        return future

    def _raise_failure(self) -> None:
        if self._failed is not None:
            raise self._failed

    def close(self) -> None:
        """Wait for every job; raise the first failure."""
        self._pool.shutdown(wait=True)
        self._pending.clear()
        self._raise_failure()

    def __enter__(self) -> OrderedWriter:
        return self

    def __exit__(self, *exc) -> None:
        if exc[0] is None:
            self.close()
        else:  # the caller failed: finish the writes already queued, keep its error
            self._pool.shutdown(wait=True)


def _resolved(records: list) -> list[dict]:
    return [r.result() if isinstance(r, Future) else r for r in records]


def record_matches_plan(record: dict, sample: SamplePlan) -> bool:
    """The identity, seeds and requested lighting of ``record`` are the plan's."""
    try:
        requested = record["lighting"]["requested"]
        seeds = record["seeds"]
        return (
            record["id"] == sample.sample_id
            and record["material_index"] == sample.material_index
            and record["light_index"] == sample.light_index
            and record["shard"] == sample.shard_id
            and seeds["material"] == sample.material_seed
            and seeds["light"] == sample.light_seed
            and seeds["render"] == sample.render_seed
            and all(requested[key] == value for key, value in sample.requested_lighting().items())
            and record.get("object", {}).get("name", DEFAULT_OBJECTS[0]) == sample.object_name
        )
    except (KeyError, TypeError, AttributeError):
        return False


def sample_light(spec: DatasetSpec, sample: SamplePlan):
    """What lights ``sample``: a ``sky.Light`` or an ``EnvironmentLight`` (its map digested)."""
    if sample.environment is None:
        return Light(sample.elevation_deg, sample.azimuth_deg, sample.turbidity)
    digest = source_file_digests(spec)[sample.environment]
    return EnvironmentLight(sample.environment, digest, sample.rotation_deg, sample.intensity)


def files_where_the_layout_says(record: dict, sample: SamplePlan) -> bool:
    """Every file ``record`` lists is at the path the layout gives its role (a render, the
    material's maps or texture file): a record naming any other path (``..``, absolute,
    another shard's file) is not this sample's, whatever its checksums say."""
    files = record.get("files")
    if not isinstance(files, list) or not files or record_problem(record, sample.shard_id):
        return False
    where = {
        "render": Layout.render_rel(sample.shard_id, sample.sample_id),
        "maps": Layout.maps_rel(sample.shard_id, sample.material_id),
        "texture": Layout.texture_rel(sample.shard_id, sample.material_id),
    }
    roles = [entry["role"] for entry in files]
    return (
        roles[0] == "render"
        and len(set(roles)) == len(roles)
        and all(where.get(entry["role"]) == entry["path"] for entry in files)
    )


def sample_verified(
    root: str,
    record: dict | None,
    sample: SamplePlan,
    checked: dict[str, bool] | None = None,
    *,
    render_only: bool = False,
) -> bool:
    """``record`` is the plan's and its files are present with their recorded size and SHA-256.

    ``checked`` memoises file checks: a material's maps are shared by its lightings.
    ``render_only``: its render file only (the material's files are judged apart).
    """
    if not record or not record_matches_plan(record, sample) or not files_where_the_layout_says(record, sample):
        return False
    checked = {} if checked is None else checked
    for entry in record["files"][:1] if render_only else record["files"]:
        key = dumps(entry)
        if key not in checked:
            checked[key] = file_ok(root, entry)
        if not checked[key]:
            return False
    return True


def run_shard(root: str, spec: DatasetSpec, shard: ShardPlan, variant: str, scene: MaterialScene | None = None) -> dict:
    """Build ``shard`` under ``root``; return a summary. Safe to run again or concurrently.

    ``scene``: a :class:`MaterialScene` held across shards (an in-process build's); None: one
    for this shard, released at its end."""
    layout = Layout(root)
    if complete_marker(layout, shard.shard_id, [s.sample_id for s in shard.samples]) is not None:
        return {"shard": shard.shard_id, "rendered": 0, "skipped": shard.n_renders, "seconds": 0.0}
    start = time.perf_counter()
    make_shard_dir(layout, shard.shard_id)
    slots: list[list] = []  # each material's records, in plan order
    work = []  # (slot, material, verified records or None, records whose render alone verifies)
    checked: dict[str, bool] = {}
    for material in shard.materials:
        existing = [read_json(layout.path(layout.record_rel(shard.shard_id, s.sample_id))) for s in material.samples]
        verified = [sample_verified(root, r, s, checked) for r, s in zip(existing, material.samples)]
        slots.append(existing)
        if not all(verified):
            render_kept = [
                r if not ok and sample_verified(root, r, s, checked, render_only=True) else None
                for r, ok, s in zip(existing, verified, material.samples)
            ]
            work.append(
                (len(slots) - 1, material, [r if ok else None for r, ok in zip(existing, verified)], render_kept)
            )
    # The next material's maps are made and checked on their own thread while this one
    # renders (numpy: ~65 ms a material, a tenth of a material's renders on a GPU).
    with (
        OrderedWriter() as writer,
        ThreadPoolExecutor(1, thread_name_prefix="material-maps") as maker,
        contextlib.nullcontext(scene) if scene is not None else MaterialScene() as held,
    ):
        made = [maker.submit(checked_material, material, spec) for _slot, material, _e, _r in work[:1]]
        for k, (slot, material, existing, render_kept) in enumerate(work):
            if k + 1 < len(work):
                made.append(maker.submit(checked_material, work[k + 1][1], spec))
            ctx = worker_context(spec, variant, material.object)
            slots[slot] = queue_material(layout, spec, ctx, material, existing, writer, render_kept, made[k], held)
    new = [r for slot in slots for r in slot]
    rendered = sum(isinstance(r, Future) for r in new)
    write_marker(layout, shard, _resolved(new))
    return {
        "shard": shard.shard_id,
        "rendered": rendered,
        "skipped": shard.n_renders - rendered,
        "seconds": time.perf_counter() - start,
    }


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
                    "and run the build again"
                ) from None


def run_shard_in_process(
    out: str, spec: DatasetSpec, shard: ShardPlan, variant: str, threads: int, scene: MaterialScene | None = None
) -> dict:
    """Run one shard in this process with ``threads`` Mitsuba threads (a worker's task);
    ``scene`` as :func:`run_shard` takes it.

    Refuses to start where the dataset folder is not visible: a worker without the shared
    filesystem would write a dataset of its own.
    """
    if not os.path.isfile(Layout(out).spec):
        raise ShaderballError(
            f"worker on {socket.gethostname()}: the dataset directory {quoted(out)} is not visible "
            "here (no spec.toml); every worker needs it at the same path on a shared filesystem"
        )
    load_mitsuba(variant)
    import drjit as dr

    if dr.thread_count() != threads:
        dr.set_thread_count(threads)
    return dict(run_shard(out, spec, shard, variant, scene), pid=f"{socket.gethostname()}:{os.getpid()}")


def write_marker(layout: Layout, shard: ShardPlan, records: list[dict]) -> None:
    marker = {
        "schema": SCHEMA_VERSION,
        "shard": shard.shard_id,
        "complete": True,
        # the CPU that rendered the shard: recorded, not compared (docs/build.md, "What is
        # reproducible where"); a heterogeneous cluster's shards say which machine made them
        "machine": machine_fingerprint(),
        "samples": [r["id"] for r in records],
        "records": records,
    }
    write_text_atomic(layout.marker(shard.shard_id), dumps(marker) + "\n")


def checked_material(material: MaterialPlan, spec: DatasetSpec):
    """``make_material(material, spec)`` with its maps checked (:meth:`MaterialMaps.check`
    raises on a bad value): the maps and the material's description."""
    maps, description = make_material(material, spec)
    return maps.check(), description


def build_material(
    layout: Layout, spec: DatasetSpec, ctx: WorkerContext, material: MaterialPlan, existing: list[dict | None]
) -> list[dict]:
    """Write a material's maps (once) and every render it lacks; return all its records."""
    with OrderedWriter() as writer:
        records = queue_material(layout, spec, ctx, material, existing, writer)
    return _resolved(records)


def queue_material(
    layout: Layout,
    spec: DatasetSpec,
    ctx: WorkerContext,
    material: MaterialPlan,
    existing: list[dict | None],
    writer: OrderedWriter,
    render_kept: list[dict | None] | None = None,
    made: Future | None = None,
    scene: MaterialScene | None = None,
) -> list[dict | Future]:
    """Render every sample of ``material`` that ``existing`` (verified records or None) lacks;
    its files and records are queued on ``writer``. Return the kept records and, for the
    others, futures of their records.

    Nothing that verifies is rewritten, which matters where a re-render would not give the
    same bytes (a dataset whose guarantee is within-noise, docs/manifest.md): a kept record's
    material files verified, so they are not written again; and ``render_kept`` (records
    whose render verifies but whose material files do not: a lost maps file) keep their
    render when the material files written anew are the ones they list (the maps are a pure
    function of the plan). Otherwise the material files are written before the first
    render's record. ``made``: the future of ``checked_material(material, spec)``, when it was
    started ahead. ``scene``: the :class:`MaterialScene` to render in (held by the caller
    across materials); None: one for this material.
    """
    maps, description = made.result() if made is not None else checked_material(material, spec)
    kept = [old for old in existing if old is not None]
    if kept:
        material_files = kept[0]["files"][1:]
    elif any(r is not None for r in render_kept or ()):
        listed = next(r for r in render_kept if r is not None)["files"][1:]
        intact = [entry for entry in listed if file_ok(layout.root, entry)]
        material_files = writer.submit(
            write_material_files, layout, spec, ctx, material, maps, description, intact
        ).result()
        existing = [r if r is not None and r["files"][1:] == material_files else None for r in render_kept]
    else:
        material_files = writer.submit(write_material_files, layout, spec, ctx, material, maps, description)
    records: list[dict | Future] = []
    with contextlib.nullcontext(scene) if scene is not None else MaterialScene() as scene:
        for sample, old in zip(material.samples, existing):
            if old is not None and old.get("files", [])[1:] == material_files:
                records.append(old)
                continue
            records.append(
                render_and_queue(layout, spec, ctx, sample, maps, description, material_files, writer, scene)
            )
    return records


def write_material_files(layout, spec, ctx, material, maps, description, intact=()) -> list[dict]:
    """The screen-space maps (and texture-space maps) of a material, stored once.

    ``intact``: entries of this material's files that verify on disk; those are kept as
    they are, not written again."""

    storage = spec.storage
    intact = {entry["role"]: entry for entry in intact}
    half = MATERIAL_MAP_LAYERS if storage.maps_half else ()
    meta = {
        "id": material.material_id,
        "material": description,
        "colorspace": "linear Rec.709 (sRGB primaries, D65) for diffuse and specular",
    }
    rel = layout.maps_rel(material.shard_id, material.material_id)
    if "maps" in intact:
        files = [intact["maps"]]
    else:
        screen = project_material(maps, ctx.gbuffer, geometry=True)
        layers = {name: screen[name] for name in storage.layers}
        files = [
            file_entry(
                layout.root,
                rel,
                "maps",
                write_exr(layout.path(rel), layers, meta, half=half, compression=storage.compression),
            )
        ]
    if storage.texture_maps and "texture" in intact:
        files.append(intact["texture"])
    elif storage.texture_maps:
        rel = layout.texture_rel(material.shard_id, material.material_id)
        texture = {name: getattr(maps, name) for name in MATERIAL_MAP_LAYERS}
        digest = write_exr(layout.path(rel), texture, meta, half=half, compression=storage.compression)
        files.append(file_entry(layout.root, rel, "texture", digest))
    return files


def non_default_render_options(settings) -> dict:
    """Sampler, Russian roulette, clamp and adaptive target where a spec changed them (what was applied)."""
    defaults = RenderSettings(variant=settings.variant)
    return {
        name: getattr(settings, name)
        for name in ("sampler", "rr_depth", "clamp", "target_error")
        if getattr(settings, name) != getattr(defaults, name)
    }


def render_and_queue(
    layout,
    spec,
    ctx,
    sample: SamplePlan,
    maps,
    description,
    material_files,
    writer: OrderedWriter,
    scene: MaterialScene | None = None,
) -> Future:
    """Render one sample here; queue its EXR and record on ``writer``. ``material_files``: the
    material's file entries, or the future of the job writing them (queued before)."""
    light = sample_light(spec, sample)
    result = render_sample(
        ctx.ball, ctx.camera, maps, light, ctx.settings, sample.render_seed, mask=ctx.gbuffer.mask, scene=scene
    )
    return writer.submit(write_render_and_record, layout, spec, ctx, sample, description, material_files, result)


def object_record(obj, spec: DatasetSpec) -> dict:
    """A record's ``object`` (name, kind, canonical mesh SHA-256, UV source, the file's SHA-256),
    the shaderball's too where the spec names other objects; none where it names only the
    shaderball, whose records are then as they were before other objects existed."""
    if spec.scene.objects == DEFAULT_OBJECTS:
        return {}
    entry = {"name": obj.name, "kind": obj.kind, "sha256": obj.digest, "uv_source": obj.uv_source}
    if obj.source_sha256:
        entry["file_sha256"] = obj.source_sha256
    return {"object": entry}


def lighting_record(spec: DatasetSpec, sample: SamplePlan, lighting: dict) -> dict:
    """A record's ``lighting`` and ``lighting_vector`` from the renderer's lighting record: the
    sun actually used (after the low-sun policy) or the environment map, rotation and scale;
    ``policy``: what the renderer did to it and the emitter it became."""
    if sample.environment is not None:
        fields = dict(lighting["effective"])
        vector = sample_light(spec, sample).lighting_vector()
    else:
        effective = Light.from_dict(lighting["effective"])
        fields = {
            "elevation_deg": effective.elevation_deg,
            "azimuth_deg": effective.azimuth_deg,
            "turbidity": effective.turbidity,
            "direction": [float(x) for x in effective.direction],
        }
        vector = effective.lighting_vector()
    return {
        "lighting": {
            **fields,
            "requested": lighting["requested"],
            "policy": {k: v for k, v in lighting.items() if k not in ("requested", "effective")},
        },
        "lighting_vector": [float(x) for x in vector],
    }


def write_render_and_record(layout, spec, ctx, sample: SamplePlan, description, material_files, result) -> dict:
    """The writer's half of a sample: its render EXR, then (durable) its record."""
    if isinstance(material_files, Future):
        material_files = material_files.result()  # done: it was queued before this job
    stats = dict(result.stats)
    stored_stats = {k: v for k, v in stats.items() if k != "time_s"}
    meta = {
        "id": sample.sample_id,
        "material_id": sample.material_id,
        "lighting": result.lighting,
        "effects": result.effects.to_dict(),
        "stats": stored_stats,
        "colorspace": "linear Rec.709 (sRGB primaries, D65)",
        **model_record(ctx.settings.model),
    }
    rel = layout.render_rel(sample.shard_id, sample.sample_id)
    digest = write_exr(layout.path(rel), {"render": result.image}, meta, compression=spec.storage.compression)
    record = {
        "schema": SCHEMA_VERSION,
        "id": sample.sample_id,
        "material_id": sample.material_id,
        "material_index": sample.material_index,
        "light_index": sample.light_index,
        "shard": sample.shard_id,
        "material": description,
        **object_record(ctx.ball, spec),
        **lighting_record(spec, sample, result.lighting),
        "seeds": {
            "material": sample.material_seed,
            "light": sample.light_seed,
            "render": sample.render_seed,
            "render_used": stats["seed"],
        },
        "effects": result.effects.to_dict(),
        "render": {
            "resolution": ctx.settings.resolution,
            "spp": ctx.settings.spp,
            "max_depth": ctx.settings.max_depth,
            "integrator": ctx.settings.integrator,
            "variant": ctx.variant,
            "sun": ctx.settings.sun,
            **non_default_render_options(ctx.settings),
            **model_record(ctx.settings.model),
        },
        # The render's wall time (`time_s`) is the one run-dependent value of a record: it is
        # kept out of the EXR header (files are a pure function of the plan) and ignored
        # wherever records are compared (pipeline.store.records.RUN_DEPENDENT_STATS).
        "stats": stats,
        "files": [file_entry(layout.root, rel, "render", digest)] + material_files,
    }
    write_text_atomic(layout.path(layout.record_rel(sample.shard_id, sample.sample_id)), dumps(record) + "\n")
    return record
