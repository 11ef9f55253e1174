"""`shaderball evaluate`: the network against the dataset's path-traced references, and
beside it path tracing at low spp, alone and denoised (the paper's Table 1 comparison).

Per sample and on average: PSNR and SSIM on 8-bit sRGB (both images through
:mod:`pipeline.image.tonemap`; SSIM in its standard form, :mod:`pipeline.image.metrics`),
relMSE and HDR-FLIP on linear HDR (the network's HDR is the inverse tone map of its
output), and the time per image. Low-spp renders use the sample's own material (its
texture-space maps file), lighting, settings and a seed of their own; denoising is Intel
Open Image Denoise (``pyoidn``) in HDR mode, fed the noise-free first-hit albedo and normal
(:mod:`pipeline.neural.denoise`), and on the colour alone as a second row. The dataset may be
a dataset folder or its publication (:func:`pipeline.neural.data.open_dataset`); the run's
split applies to the dataset it was trained on, found by content whatever folder holds it
(:func:`same_dataset`). The Mitsuba variant is resolved once, from the dataset's.
Everything goes into one folder (the request's ``out``, default the run's
evaluation-<split>): results.json, results.md (Table 1-shaped, with the CPU times the
equal-time row matched) and grid.png (the maps, the reference, the network, path tracing at
equal time and at 2 spp with and without the denoiser, error maps; two samples per material
class); with ``report`` also report.md, report.json and the learning curve
(:mod:`pipeline.neural.report`).

Path tracing beside the network (low spp, equal time) is pipeline.neural.equal_time; the
scores and their table, pipeline.neural.scores.
"""

from __future__ import annotations

import contextlib
import datetime
import functools
import json
import os
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from pipeline.check.snapshot import published_snapshot, read_snapshot, spec_differences
from pipeline.errors import ShaderballError, quoted
from pipeline.fields import FieldError
from pipeline.fields.rules import format_value
from pipeline.image import metrics
from pipeline.image.denoise import denoise
from pipeline.image.tonemap import hdr_to_srgb8, to_srgb8
from pipeline.neural import report, runfiles
from pipeline.neural.config import EvaluateRequest
from pipeline.neural.data import ResolutionMismatch, box_downsample, open_dataset
from pipeline.neural.denoise import AuxBuffers
from pipeline.neural.equal_time import EQUAL_TIME_PROBE_SPP, PathTracer, measure_equal_time
from pipeline.neural.file_sources import dataset_refused
from pipeline.neural.infer import load_run_model, refuse_nonfinite, run_network
from pipeline.neural.nearest import MaterialKinds, nearest_sample
from pipeline.neural.scene_groups import SCENE_KEYS, scene_fields, scene_results, scene_table
from pipeline.neural.scene_inputs import InputPlan, NetworkInputs, SampleScene
from pipeline.neural.scores import NETWORK_Y_CAP, image_scores, ldr_scores, markdown_table, method_label, method_means
from pipeline.neural.splits import split_samples
from pipeline.neural.train import mean_image, pick_device
from pipeline.neural.train_summary import SATURATED_FRACTION
from pipeline.render.mitsuba_env import machine_fingerprint, resolve_variant
from pipeline.store.atomic import atomic_file
from pipeline.store.record_fields import json_type_name, short_json

__all__ = ["EvaluateRequest", "EvaluateSummary", "MaterialKinds", "evaluate", "nearest_sample", "same_dataset"]
GRID_SPP = 2
#: A compared path-tracing row with more than this fraction of the references' spp shares
#: much of their noise: its scores are optimistic, and a note says so.
REFERENCE_SPP_FRACTION = 0.25
DENOISER = (
    "Intel Open Image Denoise (pyoidn), RT filter, HDR; '+ OIDN': with the noise-free first-hit albedo "
    "(material: d(1-s)+s; pedestal 0.5, ground 0.3) and world-space shading normal, each taken at 4x4 "
    "pixel centres per pixel and box-averaged, clean_aux; '+ OIDN, colour only': the colour alone"
)


def machine_line(device) -> str:
    """The machine an evaluation ran on, as its report's heading names it."""
    cpu = machine_fingerprint()
    return f"{cpu['cpu_model']} ({os.cpu_count()} CPUs, {cpu['arch']}), torch device {device}"


@dataclass
class EvaluateSummary:
    out_dir: str
    samples: int
    means: dict
    notes: list = field(default_factory=list)
    table: str = ""
    report: bool = False

    def lines(self) -> list[str]:
        return [
            f"evaluated {self.samples} samples; wrote {self.out_dir}/results.md, results.json, grid.png"
            + (", report.md, report.json, learning-curve.png/.csv" if self.report else ""),
            *self.table.splitlines(),
            *self.notes,
        ]


class _Progress:
    """``progress(dict)`` with done/total samples, rate, elapsed, ETA and what runs now."""

    def __init__(self, progress, total: int):
        self.progress, self.total, self.done = progress, total, 0
        self.started = time.perf_counter()

    def __call__(self, what: str) -> None:
        if self.progress is None:
            return
        elapsed = time.perf_counter() - self.started
        rate = self.done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else None
        self.progress(
            {"done": self.done, "total": self.total, "rate": rate, "elapsed_s": elapsed, "eta_s": eta, "what": what}
        )


def evaluate(req: EvaluateRequest, progress=None, command: str | None = None) -> EvaluateSummary:
    """Evaluate a run on a dataset; everything is checked before anything is written.
    ``progress(dict)``: done and total samples, samples/s, elapsed and ETA seconds, and what
    runs now (the first sample also compiles kernels and measures equal time). ``command``:
    how the caller spells ``req`` (the command line that makes it), the report's heading."""
    refuse_output_links(req)
    refuse_earlier_evaluation(req)
    run = _Evaluation(req)
    rows, grid_rows = [], []
    show = _Progress(progress, len(run.indices))
    per_class: dict[str, int] = {}
    for n, index in enumerate(run.indices, start=1):
        row, pictures, maps_chw = run.score(index, show)
        rows.append(row)
        if per_class.get(row["class"], 0) < report.GRID_PER_CLASS:
            per_class[row["class"]] = per_class.get(row["class"], 0) + 1
            title = f"{row['id']}\n{row['class']}\nnet {row['network']['psnr']:.1f} dB"
            grid_rows.append((title, report.grid_pictures(maps_chw, pictures)))
        show.done = n
        show(f"{row['id']}: done")
    means = method_means([{k: v for k, v in row.items() if k not in SCENE_KEYS} for row in rows])
    run.notes += _result_notes(means, run)
    result = _results(req, run, rows, means, command)
    table = markdown_table(means, len(rows), run.model.resolution, run.ref_spp, run.equal_time)
    table += scene_table(result, run.split_record.get("held_out_objects"))
    out_dir = req.folder
    refuse_output_links(req)  # again: the evaluation took a while
    os.makedirs(out_dir, exist_ok=True)
    write_all_or_none(
        out_dir,
        {
            "grid.png": report.picture_grid(grid_rows, report.GRID_COLUMNS),
            "results.md": table.encode(),
            "results.json": (json.dumps(result, indent=2, sort_keys=True) + "\n").encode(),  # as runfiles.write_json
        },
    )
    if req.json_out:
        runfiles.write_json(req.json_out, result, inside=req.network.run)
    if req.report:
        report.write_report(
            out_dir, result, table, report.class_table(result["by_class"], method_label), req.network.run
        )
    else:  # --overwrite: an earlier evaluation's report would stand beside these results as theirs
        for name in report.REPORT_FILES:
            with contextlib.suppress(FileNotFoundError):
                os.remove(os.path.join(out_dir, name))
    return EvaluateSummary(out_dir, len(rows), means, run.notes, table, req.report)


#: The files an evaluation writes into its folder (with ``report``, also report.REPORT_FILES).
EVALUATION_FILES = ("results.json", "results.md", "grid.png")


def refuse_output_links(req: EvaluateRequest) -> None:
    """Refuse (exit 2, naming it) an output that is, or passes through, a symbolic link inside
    the run folder (the default folder ``RUN/evaluation-<split>`` among them) or inside the
    output folder: nothing is written through a link."""
    names = EVALUATION_FILES + (report.REPORT_FILES if req.report else ())
    files = [os.path.join(req.folder, name) for name in names]
    runfiles.refuse_links(EvaluateRequest, "out", req.folder, [req.network.run, req.folder], files)
    if req.json_out:
        runfiles.refuse_links(EvaluateRequest, "json_out", req.json_out, [req.network.run], [req.json_out])


def refuse_earlier_evaluation(req: EvaluateRequest) -> None:
    """Refuse (``out``, exit 2) a folder that holds an earlier evaluation's files, unless
    ``overwrite``: an evaluation takes minutes and its folder is a record (the default one
    is the same for every evaluation of a run's split), so it is replaced only when asked,
    and the refusal comes before anything runs."""
    names = EVALUATION_FILES + report.REPORT_FILES
    found = [name for name in names if os.path.lexists(os.path.join(req.folder, name))]
    if found and not req.overwrite:
        raise EvaluateRequest.field_error(
            "out",
            req.folder,
            "give {overwrite} to replace it, or name another {out}",
            what=f"{format_value(req.folder)} holds an earlier evaluation ({', '.join(found)})",
        )


def write_all_or_none(folder: str, files: dict[str, bytes]) -> None:
    """Write ``files`` (name -> bytes) into ``folder``: all of them, or none (a full disk).
    Each is written whole to its temporary file and made durable before any is renamed
    (pipeline.store.atomic), so a failed write leaves no new file beside older ones; the
    failure names the file that could not be written."""
    with contextlib.ExitStack() as stack:
        for name, data in files.items():
            path = os.path.join(folder, name)
            fh = stack.enter_context(atomic_file(path, inside=folder))
            try:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            except OSError as exc:
                if exc.filename is None:
                    exc.filename = path  # not the name of another file of the stack
                raise


def content_problem(content) -> str | None:
    """Why a run's ``dataset_content`` cannot be compared (None: it can, or it is absent or
    null: a run made before it was recorded). Another type is a damaged config, never taken
    for "not recorded"."""
    if content is None:
        return None
    if not isinstance(content, dict):
        return f"dataset_content is {json_type_name(content)} ({short_json(content)}), not an object"
    for key in ("spec_digest", "samples_sha256"):
        value = content.get(key)
        if value is not None and not isinstance(value, str):
            return f"dataset_content.{key} is {json_type_name(value)} ({short_json(value)}), not a string"
    return None


def same_dataset(run_config: dict, source, config_path: str = runfiles.CONFIG) -> tuple[bool, str]:
    """Whether ``source`` holds the data the run was trained on, and how that was found: by
    content, whatever folder holds it (the spec's digest and every sample's id, material,
    lighting and files' SHA-256: :func:`pipeline.neural.manifest_index.sample_digest_line`), so a
    rebuild of the same spec, a copy or the publication is the same dataset; a run that
    recorded no content (made before it was recorded) by its manifest's SHA-256. A content
    record of another shape is refused (a ShaderballError naming ``config_path``)."""
    content = run_config.get("dataset_content")
    problem = content_problem(content)
    if problem:
        raise ShaderballError(
            f"{config_path}: {problem}; the run folder is damaged (train a new run with `shaderball train`)"
        )
    if isinstance(content, dict) and content.get("samples_sha256"):
        if getattr(source, "content", None) == content:
            return True, "the same spec digest and the same samples (ids, materials, lighting, files' SHA-256)"
        if (getattr(source, "content", None) or {}).get("spec_digest") != content.get("spec_digest"):
            return False, "it was built from another spec (its spec digest differs from the run's)"
        return False, "its samples differ from the run's (ids, materials, lighting or files' SHA-256)"
    if source.identity == (run_config.get("identity") or {}).get("dataset"):
        return True, "the same manifest (SHA-256)"
    return False, (
        "its manifest's SHA-256 differs from the run's, and the run (trained before shaderball recorded "
        "its dataset's content) records nothing else to compare"
    )


class _Evaluation:
    """One evaluation's setting: the run's network, the dataset and its split, what is
    compared (the mean image and nearest sample where the dataset is the run's, path tracing
    and the denoiser where asked and installed) and the notes saying what was left out."""

    def __init__(self, req: EvaluateRequest):
        self.req = req
        self.device = pick_device(req.device)
        self.model, self.config = load_run_model(req.network.run, self.device, req.network.checkpoint)
        self.inputs, self.split_record = InputPlan.of_network(self.config["network"]), self.config.get("split") or {}
        if req.report:
            runfiles.read_log(req.network.run)  # the report's learning curve: checked before anything is written
        self.exposure = float(self.config["tonemap"]["exposure"])
        self.source = _open_for_run(req, self.model.resolution, self.exposure)
        self.references = _reference_for(req, self.source, self.model.resolution, self.exposure)
        self.same, self.compared = same_dataset(
            self.config, self.source, os.path.join(req.network.run, runfiles.CONFIG)
        )
        self.dataset = self._split()
        self.indices = list(range(len(self.dataset)))[: req.limit]
        self.records = self.source.records
        ref_records = (self.references or self.source).records
        spps = sorted({int(ref_records[self.dataset.samples[i].id]["render"]["spp"]) for i in self.indices})
        self.reference_spp, self.ref_spp = (spps[0] if len(spps) == 1 else spps), min(spps)
        self.notes = self._left_out()
        self.kinds = MaterialKinds(self.records)
        self._baselines()
        self._path_tracing()
        self.scores = functools.partial(image_scores, flip=req.flip)
        self.ldr_scores = functools.partial(ldr_scores, flip=req.flip)
        self.equal_time = None
        self.aux_albedo = (None, None)  # (material id, its albedo buffer): a material's lightings are adjacent

    def _split(self):
        """The samples evaluated: the run's split of its own dataset, or all of any dataset."""
        req, source = self.req, self.source
        if req.split == "all":
            return source
        if not self.same:
            raise EvaluateRequest.field_error(
                "dataset",
                req.dataset,
                "the run's dataset (the same spec and files, in any folder), or {split} all",
                what=f"{quoted(req.dataset)} is not the dataset the run was trained on: {self.compared}, so the run's "
                f"{req.split} split does not apply",
            )
        dataset = split_samples(source, self.split_record, req.split)
        if len(dataset) == 0:
            raise EvaluateRequest.field_error(
                "split",
                req.split,
                "all, or a run that holds materials out",
                what=f"the run's {req.split} split holds no samples",
            )
        return dataset

    def _left_out(self) -> list[str]:
        """The notes of what is left out (HDR-FLIP, the denoiser); sets ``want_denoise``."""
        req, notes = self.req, []
        if not req.flip:
            notes.append("HDR-FLIP: left out (--no-flip)")
        elif not metrics.flip_available():
            notes.append("HDR-FLIP: flip-evaluator is not installed (pip install flip-evaluator); left out")
        self.want_denoise = req.denoise and bool(req.spp)
        if self.want_denoise:
            try:
                import pyoidn  # noqa: F401
            except ImportError:
                self.want_denoise = False
                notes.append("denoising: pyoidn is not installed (pip install pyoidn); left out")
        return notes

    def _baselines(self) -> None:
        """The run's training images, for the mean image and the nearest sample: only where
        the dataset is the run's."""
        self.mean_y, self.training = None, None
        if self.same and (self.config.get("split") or {}).get("train"):
            self.training = split_samples(self.source, self.split_record, "train")
            self.mean_y = mean_image(self.training, workers=0)
        else:
            self.notes.append(
                f"mean_image, nearest_sample: the dataset is not the run's ({self.compared}), so the run's "
                "training images are not here; left out"
            )

    def _path_tracing(self) -> None:
        self.tracer = self.aux = None
        if self.req.spp:
            variant = resolve_variant(dataset_variant(self.source))  # once; every render and buffer takes it
            self.tracer = PathTracer(self.dataset, variant)
            if self.want_denoise:
                side = self.dataset.resolution * self.dataset.factor
                self.aux = AuxBuffers(self.tracer.ball, self.tracer.camera, side, variant, self.dataset.factor)

    def score(self, index: int, show) -> tuple[dict, dict, np.ndarray]:
        """One sample's row of scores, its grid pictures and its maps (C, H, W)."""
        dataset, exposure = self.dataset, self.exposure
        item, sample = dataset[index], dataset.samples[index]
        show(f"{sample.id}: network")
        ref_hdr = self._reference(sample)
        ref8 = hdr_to_srgb8(ref_hdr, exposure)
        maps_chw, record = item["maps"].numpy(), self.records[sample.id]
        net_maps, environment = self._network_inputs(sample, maps_chw, record)
        run_network(self.model, net_maps, sample.lighting_vector, self.device, environment)  # warm-up
        started, cpu_started = time.perf_counter(), time.process_time()
        pred = run_network(self.model, net_maps, sample.lighting_vector, self.device, environment)
        net_s, net_cpu_s = time.perf_counter() - started, time.process_time() - cpu_started
        refuse_nonfinite(pred, f"the network of {self.req.network.run}, sample {sample.id}")
        row = {
            "id": sample.id,
            "material_id": sample.material_id,
            "class": report.material_class(record),
            **scene_fields(record, self.split_record),
            "network": self.ldr_scores(pred, ref_hdr, ref8, exposure, net_s, cpu_s=net_cpu_s),
        }
        if self.mean_y is not None:
            row["mean_image"] = self.ldr_scores(self.mean_y, ref_hdr, ref8, exposure, 0.0)
            neighbour = nearest_sample(sample, self.training.samples, self.kinds)
            if neighbour is not None:
                near_hdr = box_downsample(read_render(self.training, neighbour), self.training.factor)
                row["nearest_sample"] = self.scores(
                    near_hdr, hdr_to_srgb8(near_hdr, exposure), ref_hdr, ref8, 0.0, neighbour=neighbour.id
                )
        pictures = {"reference": ref8, "network": to_srgb8(pred)}
        self._path_traced(row, pictures, dict(item, maps=torch.from_numpy(net_maps)), sample, ref_hdr, ref8, show)
        return row, pictures, maps_chw

    def _network_inputs(self, sample, maps_chw, record) -> tuple[np.ndarray, int | None]:
        """The sample's input as the run's network takes it: the maps with the geometry channels
        of a run trained with them, and its map's code row (None: a network without codes)."""
        if self.inputs.geometry:
            if getattr(self, "geometry_view", None) is None:
                self.geometry_view = NetworkInputs(self.dataset, self.inputs)
            maps_chw = np.concatenate([maps_chw, self.geometry_view.geometry(sample).numpy()])
        if not self.inputs.code_size:
            return maps_chw, None
        return maps_chw, self.inputs.environment_index(SampleScene.of(record))

    def _reference(self, sample) -> np.ndarray:
        """The sample's path-traced reference: its render in ``--reference``'s build, else its own."""
        if self.references is None:
            return box_downsample(read_render(self.dataset, sample), self.dataset.factor)
        return box_downsample(read_render(self.references, self.references.by_id[sample.id]), self.references.factor)

    def _path_traced(self, row: dict, pictures: dict, item, sample, ref_hdr, ref8, show) -> None:
        """Path tracing at equal time and at each of ``spp`` (and denoised) into ``row``."""
        maps = self.tracer.material(sample) if self.tracer else None
        if self.tracer and maps is None and "no texture" not in " ".join(self.notes):
            self.notes.append(
                "path tracing: the dataset stores no texture maps (storage.texture_maps = false); left out"
            )
        if maps is None:
            return
        record, exposure = self.records[sample.id], self.exposure
        if self.equal_time is None:  # measured once, on this machine, in this run
            show(f"{sample.id}: equal time (the network's CPU time, path tracing at {EQUAL_TIME_PROBE_SPP} spp)")
            self.equal_time = measure_equal_time(self.model, item, sample, self.tracer, record, maps, self.device)
        spp = self.equal_time["spp"]
        image, t = self.tracer.render(record, maps, spp)
        pictures["equal time"] = hdr_to_srgb8(image, exposure)
        row["pt_equal_time"] = self.scores(image, pictures["equal time"], ref_hdr, ref8, t, spp=spp)
        if self.want_denoise:
            clean, t_dn, _cpu = denoise(image, self._albedo(sample, maps), self.aux.normal)
            row["pt_equal_time+oidn"] = self.scores(
                clean, hdr_to_srgb8(clean, exposure), ref_hdr, ref8, t + t_dn, spp=spp
            )
        for spp in self.req.spp:
            show(f"{sample.id}: path tracing {spp} spp" + (", denoising" if self.want_denoise else ""))
            image, t = self.tracer.render(record, maps, spp)
            row[f"pt{spp}"] = self.scores(image, hdr_to_srgb8(image, exposure), ref_hdr, ref8, t)
            if spp == GRID_SPP:
                pictures[f"{spp} spp"] = hdr_to_srgb8(image, exposure)
            if self.want_denoise:
                clean, t_dn, _cpu = denoise(image, self._albedo(sample, maps), self.aux.normal)
                row[f"pt{spp}+oidn"] = self.scores(clean, hdr_to_srgb8(clean, exposure), ref_hdr, ref8, t + t_dn)
                alone, t_alone, _cpu = denoise(image)
                row[f"pt{spp}+oidn-colour"] = self.scores(
                    alone, hdr_to_srgb8(alone, exposure), ref_hdr, ref8, t + t_alone
                )
                if spp == GRID_SPP:
                    pictures[f"{spp} spp + OIDN"] = hdr_to_srgb8(clean, exposure)

    def _albedo(self, sample, maps):
        """The denoiser's albedo buffer of the sample's material (made once per material)."""
        if self.aux_albedo[0] != sample.material_id:
            self.aux_albedo = (sample.material_id, self.aux.albedo(maps))
        return self.aux_albedo[1]


def _result_notes(means: dict, run: _Evaluation) -> list[str]:
    """What qualifies the numbers: a saturated network, CPU times matched on a GPU, path
    tracing close to the references' spp."""
    notes = []
    saturated = means["network"].get("saturated")
    if saturated is not None and saturated > SATURATED_FRACTION:
        notes.append(
            f"network: {100 * saturated:.1f}% of its output values are saturated (8-bit 0 or 255): the run has "
            f"not learned (train with a smaller --lr); its relMSE and HDR-FLIP are of outputs capped at "
            f"y = {NETWORK_Y_CAP:.4f} before the inverse tone map, the most an 8-bit 255 says"
        )
    if run.equal_time is not None and run.device.type != "cpu":
        notes.append(
            f"pt_equal_time: the network ran on {run.device.type}, whose CPU time is not its cost; this row matches "
            "CPU times only (untested on a GPU)"
        )
    compared = [(f"pt{spp}", spp) for spp in run.req.spp if f"pt{spp}" in means]
    if run.equal_time is not None:
        compared.append(("pt_equal_time", run.equal_time["spp"]))
    for method, spp in compared:
        if spp > REFERENCE_SPP_FRACTION * run.ref_spp:
            notes.append(
                f"{method}: {spp} spp against references of {run.ref_spp} spp, more than a quarter of theirs: it "
                "shares much of the references' noise, so its scores are optimistic; use references of at "
                f"least {4 * spp} spp to compare it"
            )
    return notes


def _results(req: EvaluateRequest, run: _Evaluation, rows: list[dict], means: dict, command: str | None) -> dict:
    """results.json: the request, the setting, every sample's scores, the means and the notes."""
    return {
        "command": command,
        "machine": machine_line(run.device),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "run": os.path.abspath(req.network.run),
        "dataset": os.path.abspath(req.dataset),
        "reference": os.path.abspath(req.reference) if req.reference else None,
        "dataset_compared": run.compared,
        "split": req.split,
        "resolution": run.model.resolution,
        "device": str(run.device),
        "checkpoint": req.network.checkpoint,
        "reference_spp": run.reference_spp,
        "equal_time": run.equal_time,
        "ci95": "percentile bootstrap over materials (2000 resamples, fixed seed): a material's lightings "
        "are correlated, so materials, not samples, are the independent units; null with fewer than 2 materials",
        "relmse_network": f"network and mean image: inverse tone map of the output capped at y = {NETWORK_Y_CAP:.6f} "
        "(8-bit 255 says only 'at least this bright')",
        "nearest_sample": "the training sample of the same material class with the nearest lighting vector "
        "(squared chord of the sun directions + (turbidity difference / 9)^2), its path-traced render as the answer",
        "samples": rows,
        "mean": means,
        "by_class": report.class_means(rows, [k for k in rows[0] if isinstance(rows[0][k], dict)]),
        **scene_results(rows),
        "inputs": {"geometry": run.inputs.geometry, "environment_code": run.inputs.code_size},
        "train_renders": len(run.training) if run.training is not None else None,
        "classes": f"uniform metal: a uniform material whose largest specular (F0) value is above {report.METAL_F0}; "
        "uniform dielectric: the other uniform ones; svbrdf: the spatially varying ones",
        "notes": run.notes,
        "tonemap": run.config["tonemap"],
        "denoiser": DENOISER if run.want_denoise else None,
        "metrics": "PSNR/SSIM on 8-bit sRGB (SSIM Gaussian 11x11, sigma 1.5); relMSE and HDR-FLIP on linear HDR",
    }


def _reference_for(req: EvaluateRequest, source, resolution: int, exposure: float):
    """``--reference``'s build opened at the run's resolution, with ``by_id`` (sample id -> its
    sample), or None; refused unless it holds DATASET's samples: the same spec but for
    render.spp (the same ids, materials and lightings), every one of them rendered."""
    if req.reference is None:
        return None
    references = _open_for_run(req, resolution, exposure, "reference")
    spec_of = {}
    for name, opened in (("dataset", source), ("reference", references)):
        data = opened.spec_bytes
        spec_of[name] = published_snapshot(data, opened.root) if data is not None else read_snapshot(opened.root)
    differ = [f"{s}.{k}" for s, k, _, _ in spec_differences(spec_of["dataset"], spec_of["reference"])]
    differ = [name for name in differ if name != "render.spp"]
    allowed = "a build of {dataset}'s spec with another render.spp (the same samples rendered again)"
    if differ:
        raise EvaluateRequest.field_error(
            "reference",
            req.reference,
            allowed,
            what=f"{quoted(req.reference)} was built from another spec: {', '.join(differ[:4])}"
            f"{' and more' if len(differ) > 4 else ''} differ from {quoted(req.dataset)}'s",
        )
    references.by_id = {sample.id: sample for sample in references.samples}
    missing = [sample.id for sample in source.samples if sample.id not in references.by_id]
    if missing:
        raise EvaluateRequest.field_error(
            "reference", req.reference, allowed, what=f"{quoted(req.reference)} holds no render of {missing[0]}"
        )
    return references


def _open_for_run(req: EvaluateRequest, resolution: int, exposure: float, field: str = "dataset"):
    """The dataset (``field``: or the reference build) at the run's network resolution; a dataset
    it does not divide is refused with what the user can do (evaluate has no --resolution: the
    run fixes it)."""
    root = getattr(req, field)
    try:
        return open_dataset(root, resolution=resolution, exposure=exposure, check_hashes=req.hash_check)
    except ResolutionMismatch as exc:
        raise EvaluateRequest.field_error(
            field,
            root,
            f"a dataset whose render resolution is a multiple of {resolution} (e.g. the run's own dataset), or a "
            f"run trained for this dataset (`shaderball train DATASET --out NEWRUN`, with --resolution a multiple "
            f"of 16 dividing {exc.native})",
            what=f"{quoted(root)} has {exc.native}x{exc.native} renders; the run {quoted(req.network.run)} was trained at "
            f"{resolution}x{resolution} (its config.json), and {resolution} does not divide {exc.native}, so its "
            "network cannot take these renders",
        ) from None
    except FieldError as exc:  # the loader names the folder it opens `dataset`: here it may be --reference
        if exc.name != "dataset" or field == "dataset":
            raise
        raise EvaluateRequest.field_error(field, root, exc.allowed, what=exc.what) from None


def dataset_variant(dataset) -> str:
    """The Mitsuba variant ``dataset``'s renders were made with (one), or a refusal naming it."""
    variants = {(r.get("render") or {}).get("variant") for r in dataset.records.values()}
    if len(variants) != 1 or not isinstance(next(iter(variants)), str):
        raise dataset_refused(
            dataset.root,
            f"{quoted(dataset.root)} has renders of several or unknown Mitsuba variants {sorted(map(str, variants))}",
            "a dataset rendered with one variant; check it with `shaderball validate`",
        )
    return next(iter(variants))


def read_render(dataset, sample) -> np.ndarray:
    """A sample's stored render (linear HDR, the dataset's resolution)."""
    return dataset._read(sample.render, ("render",))["render"].astype(np.float32)
