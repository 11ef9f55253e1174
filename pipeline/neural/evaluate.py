"""`shaderball evaluate`: the network against the dataset's path-traced references, and
beside it path tracing at low spp, alone and denoised (the paper's Table 1 comparison).

Per sample and on average: PSNR and SSIM on 8-bit sRGB (both images through
:mod:`pipeline.image.tonemap`; SSIM in its standard form, :mod:`pipeline.image.metrics`),
relMSE and HDR-FLIP on linear HDR (the network's HDR is the inverse tone map of its
output), and the time per image. Low-spp renders use the sample's own material (its
texture-space maps file), lighting, settings and a seed of their own; denoising is Intel
Open Image Denoise (``pyoidn``) in HDR mode, fed the noise-free first-hit albedo and normal
(:mod:`pipeline.neural.denoise`), and on the colour alone as a second row. DATASET may be
a dataset folder or its publication (:func:`pipeline.neural.data.open_dataset`). The
Mitsuba variant is resolved once, from the dataset's. Writes results.json, results.md
(Table 1-shaped) and grid.png (reference, network, 2 spp, 2 spp + denoiser).
"""

from __future__ import annotations

import io
import os
import time
from dataclasses import dataclass, field

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from geometry import build_shaderball, default_camera
from materials import MaterialMaps
from materials.brdf_ref import DEFAULT_MODEL
from pipeline.errors import ShaderballError, bad_value
from pipeline.image import metrics
from pipeline.image.denoise import denoise
from pipeline.image.tonemap import hdr_to_srgb8, inverse_tonemap, to_srgb8
from pipeline.neural import runfiles
from pipeline.neural.data import ResolutionMismatch, box_downsample, open_dataset
from pipeline.neural.denoise import AuxBuffers
from pipeline.neural.infer import load_run_model, run_network
from pipeline.neural.train import pick_device
from pipeline.render.mitsuba_env import resolve_variant
from pipeline.render.renderer import RenderSettings, render_sample
from pipeline.store.atomic import write_bytes_atomic
from sky import Light

SPLITS = ("test", "train", "all")
DEFAULT_SPP = (1, 2, 4, 16)
#: Each low spp of the path tracing compared with (--spp), defined once (check; the CLI help).
SPP_LADDER_RANGE = (1, 4096)
#: Low-spp renders get seeds of their own: this plus the spp, beside the record's seed.
PT_SEED_OFFSET = 0x5EED
GRID_SPP = 2
DENOISER = (
    "Intel Open Image Denoise (pyoidn), RT filter, HDR; '+ OIDN': with the noise-free first-hit albedo "
    "(material: d(1-s)+s; pedestal 0.5, ground 0.3) and world-space shading normal, each taken at 4x4 "
    "pixel centres per pixel and box-averaged, clean_aux; '+ OIDN, colour only': the colour alone"
)


@dataclass(frozen=True)
class EvaluateRequest:
    run: str  # training run folder
    dataset: str  # dataset folder with the references
    split: str = "test"  # test or train (the run's split by material; same dataset only) or all
    out_dir: str | None = None  # where results.json, results.md and grid.png go; default RUN/evaluation-SPLIT
    json_path: str | None = None  # also write the results JSON here
    spp: tuple[int, ...] = DEFAULT_SPP  # low-spp path tracing to compare with; () for none
    denoise: bool = True  # also denoise each low-spp render with pyoidn
    limit: int | None = None  # evaluate at most this many samples (in manifest order)
    device: str = "auto"
    check_hashes: bool = True
    grid_rows: int = 4
    checkpoint: str = "last"  # last, best (chosen on the held-out split: optimistic on it), or a file


@dataclass
class EvaluateSummary:
    out_dir: str
    samples: int
    means: dict
    notes: list = field(default_factory=list)
    table: str = ""

    def lines(self) -> list[str]:
        return [
            f"evaluated {self.samples} samples; wrote {self.out_dir}/results.md, results.json, grid.png",
            *self.table.splitlines(),
            *self.notes,
        ]


def _scores(hdr: np.ndarray, srgb8: np.ndarray, ref_hdr: np.ndarray, ref8: np.ndarray, time_s: float) -> dict:
    return {
        "psnr": metrics.psnr8(srgb8, ref8),
        "ssim": metrics.ssim8(srgb8, ref8),
        "relmse": metrics.relmse(hdr, ref_hdr),
        "flip": metrics.hdr_flip(hdr, ref_hdr),
        "time_s": time_s,
    }


TEXTURE_LAYERS = ("diffuse", "specular", "roughness", "normal")


class PathTracer:
    """Low-spp renders of a dataset's sample, with the sample's material, light and settings,
    under ``variant`` (resolved once by the caller)."""

    def __init__(self, dataset, variant: str):
        self.dataset, self.factor, self.variant = dataset, dataset.factor, variant
        self.ball, self.camera = build_shaderball(), default_camera()
        self.warm = False

    def material(self, sample) -> MaterialMaps | None:
        """The sample's texture-space maps (its texture file), or None if the dataset stores none."""
        if sample.texture is None:
            return None
        layers = self.dataset.read_layers(sample.texture, TEXTURE_LAYERS)
        return MaterialMaps(layers["diffuse"], layers["specular"], layers["roughness"][..., 0], layers["normal"])

    def render(self, record: dict, maps, spp: int) -> tuple[np.ndarray, float]:
        r = record["render"]
        settings = RenderSettings(
            resolution=r["resolution"],
            spp=spp,
            max_depth=r["max_depth"],
            integrator=r["integrator"],
            sun=r["sun"],
            variant=self.variant,
            model=r.get("model", DEFAULT_MODEL),
        )  # absent: the default model
        light = Light.from_dict(record["lighting"]["requested"])
        seed = (int(record["seeds"]["render"]) + PT_SEED_OFFSET + spp) % 2**32
        if not self.warm:  # the first render compiles kernels: keep that out of the timings
            render_sample(self.ball, self.camera, maps, light, settings, seed)
            self.warm = True
        result = render_sample(self.ball, self.camera, maps, light, settings, seed)
        image = box_downsample(np.asarray(result.image, dtype=np.float32), self.factor)
        return image, float(result.stats["time_s"])


def _check(req: EvaluateRequest) -> None:
    if req.split not in SPLITS:
        raise bad_value("--split", req.split, ", ".join(SPLITS))
    lo, hi = SPP_LADDER_RANGE
    if any(isinstance(s, bool) or not isinstance(s, int) or not lo <= s <= hi for s in req.spp):
        raise bad_value("--spp", ",".join(map(str, req.spp)), f"comma-separated integers from {lo} to {hi}")
    if req.limit is not None and (isinstance(req.limit, bool) or not isinstance(req.limit, int) or req.limit < 1):
        raise bad_value("--limit", req.limit, "an integer >= 1")
    if req.json_path is not None and not req.json_path.lower().endswith(".json"):
        raise bad_value("--json", req.json_path, "a file name ending in .json")


def evaluate(req: EvaluateRequest, progress=None) -> EvaluateSummary:
    """Evaluate a run on a dataset; everything is checked before anything is written."""
    _check(req)
    device = pick_device(req.device)
    model, config = load_run_model(req.run, device, req.checkpoint)
    exposure = float(config["tonemap"]["exposure"])
    source = _open_for_run(req, model.resolution, exposure)
    same = source.identity == config["identity"]["dataset"]
    if req.split != "all":
        if not same:
            raise bad_value(
                "--split",
                req.split,
                "all: DATASET is not the dataset the run was trained on, so the run's split does not apply",
            )
        dataset = source.subset(config["split"][req.split])
    else:
        dataset = source
    if len(dataset) == 0:
        raise ShaderballError(f"--split {req.split}: no samples in {req.dataset}")
    indices = list(range(len(dataset)))[: req.limit]
    out_dir = req.out_dir or os.path.join(req.run, f"evaluation-{req.split}")
    notes = []
    if not metrics.flip_available():
        notes.append("HDR-FLIP: flip-evaluator is not installed (pip install flip-evaluator); left out")
    want_denoise = req.denoise and bool(req.spp)
    if want_denoise:
        try:
            import pyoidn  # noqa: F401
        except ImportError:
            want_denoise = False
            notes.append("denoising: pyoidn is not installed (pip install pyoidn); left out")

    records = source.records
    tracer = aux = None
    if req.spp:
        variant = resolve_variant(dataset_variant(records))  # once; every render and buffer takes it
        tracer = PathTracer(dataset, variant)
        if want_denoise:
            aux = AuxBuffers(tracer.ball, tracer.camera, dataset.resolution * dataset.factor, variant, dataset.factor)
    rows, grid = [], []
    aux_albedo = (None, None)  # (material id, its albedo buffer): a material's lightings are adjacent
    for n, index in enumerate(indices, start=1):
        item = dataset[index]
        sample = dataset.samples[index]
        ref_hdr = box_downsample(_read_render(dataset, sample), dataset.factor)
        ref8 = hdr_to_srgb8(ref_hdr, exposure)
        run_network(model, item["maps"].numpy(), sample.lighting_vector, device)  # warm-up
        started = time.perf_counter()
        pred = run_network(model, item["maps"].numpy(), sample.lighting_vector, device)
        net_s = time.perf_counter() - started
        row = {
            "id": sample.id,
            "material_id": sample.material_id,
            "network": _scores(inverse_tonemap(pred, exposure), to_srgb8(pred), ref_hdr, ref8, net_s),
        }
        pictures = {"reference": ref8, "network": to_srgb8(pred)}
        maps = tracer.material(sample) if tracer else None
        if tracer and maps is None and "no texture" not in " ".join(notes):
            notes.append("path tracing: the dataset stores no texture maps (storage.texture_maps = false); left out")
        for spp in req.spp if maps is not None else ():
            image, t = tracer.render(records[sample.id], maps, spp)
            row[f"pt{spp}"] = _scores(image, hdr_to_srgb8(image, exposure), ref_hdr, ref8, t)
            if spp == GRID_SPP:
                pictures[f"{spp} spp"] = hdr_to_srgb8(image, exposure)
            if want_denoise:
                if aux_albedo[0] != sample.material_id:
                    aux_albedo = (sample.material_id, aux.albedo(maps))
                clean, t_dn, _cpu = denoise(image, aux_albedo[1], aux.normal)
                row[f"pt{spp}+oidn"] = _scores(clean, hdr_to_srgb8(clean, exposure), ref_hdr, ref8, t + t_dn)
                alone, t_alone, _cpu = denoise(image)
                row[f"pt{spp}+oidn-colour"] = _scores(alone, hdr_to_srgb8(alone, exposure), ref_hdr, ref8, t + t_alone)
                if spp == GRID_SPP:
                    pictures[f"{spp} spp + OIDN"] = hdr_to_srgb8(clean, exposure)
        rows.append(row)
        if len(grid) < req.grid_rows:
            grid.append((sample.id, pictures))
        if progress is not None:
            progress({"sample": n, "samples": len(indices), "id": sample.id})

    methods = [k for k in rows[0] if k not in ("id", "material_id")]
    means = {m: {k: _mean([r[m][k] for r in rows if m in r]) for k in rows[0][m]} for m in methods}
    result = {
        "run": os.path.abspath(req.run),
        "dataset": os.path.abspath(req.dataset),
        "split": req.split,
        "resolution": model.resolution,
        "device": str(device),
        "samples": rows,
        "mean": means,
        "notes": notes,
        "tonemap": config["tonemap"],
        "denoiser": DENOISER if want_denoise else None,
        "metrics": "PSNR/SSIM on 8-bit sRGB (SSIM Gaussian 11x11, sigma 1.5); relMSE and HDR-FLIP on linear HDR",
    }
    table = markdown_table(means, len(rows), model.resolution)
    os.makedirs(out_dir, exist_ok=True)
    runfiles.write_json(os.path.join(out_dir, "results.json"), result)
    write_bytes_atomic(os.path.join(out_dir, "results.md"), table.encode())
    write_bytes_atomic(os.path.join(out_dir, "grid.png"), grid_png(grid))
    if req.json_path:
        runfiles.write_json(req.json_path, result)
    return EvaluateSummary(out_dir, len(rows), means, notes, table)


def _open_for_run(req: EvaluateRequest, resolution: int, exposure: float):
    """DATASET at the run's network resolution; a dataset it does not divide is refused with
    what the user can do (evaluate has no --resolution: the run fixes it)."""
    try:
        return open_dataset(req.dataset, resolution=resolution, exposure=exposure, check_hashes=req.check_hashes)
    except ResolutionMismatch as exc:
        raise ShaderballError(
            f"DATASET: {req.dataset!r} has {exc.native}x{exc.native} renders; the run {req.run!r} was trained "
            f"at {resolution}x{resolution} (its config.json), and {resolution} does not divide {exc.native}, "
            f"so its network cannot take these renders. Evaluate it on a dataset whose render resolution is a "
            f"multiple of {resolution} (e.g. the run's own dataset), or train a run for this dataset "
            f"(`shaderball train DATASET --out NEWRUN`, with --resolution a multiple of 16 dividing {exc.native})"
        ) from None


def dataset_variant(records: dict) -> str:
    variants = {(r.get("render") or {}).get("variant") for r in records.values()}
    if len(variants) != 1 or not isinstance(next(iter(variants)), str):
        raise ShaderballError(f"DATASET: renders of several or unknown Mitsuba variants {sorted(map(str, variants))}")
    return next(iter(variants))


def _read_render(dataset, sample) -> np.ndarray:
    return dataset._read(*sample.render, ("render",))["render"].astype(np.float32)


def _mean(values):
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def _label(method: str) -> str:
    if method == "network":
        return "neural renderer"
    spp, _, extra = method[2:].partition("+")
    return f"path tracing, {spp} spp" + {"": "", "oidn": " + OIDN", "oidn-colour": " + OIDN, colour only"}[extra]


def markdown_table(means: dict, samples: int, resolution: int) -> str:
    def fmt(v, spec):
        return "-" if v is None else format(v, spec)

    lines = [
        f"{samples} samples at {resolution}x{resolution}; PSNR/SSIM on 8-bit sRGB, relMSE and HDR-FLIP on "
        "linear HDR; time per image",
        "",
        "| method | PSNR (dB) | SSIM | relMSE | HDR-FLIP | time (ms) |",
        "|---|---|---|---|---|---|",
    ]
    for method, m in means.items():
        lines.append(
            f"| {_label(method)} | {fmt(m['psnr'], '.2f')} | {fmt(m['ssim'], '.4f')} | "
            f"{fmt(m['relmse'], '.4g')} | {fmt(m['flip'], '.4f')} | {fmt(m['time_s'] * 1000, '.1f')} |"
        )
    return "\n".join(lines) + "\n"


def grid_png(rows: list[tuple[str, dict]], scale: int | None = None) -> bytes:
    """Rows of labelled pictures: reference, network, 2 spp, 2 spp + OIDN."""
    columns = ["reference", "network", f"{GRID_SPP} spp", f"{GRID_SPP} spp + OIDN"]
    size = rows[0][1]["reference"].shape[0]
    scale = scale or max(1, 192 // size)
    cell, pad, head = size * scale, 6, 18
    img = Image.new("RGB", (len(columns) * (cell + pad) + pad + 90, len(rows) * (cell + pad) + pad + head), "white")
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    for c, name in enumerate(columns):
        draw.text((90 + pad + c * (cell + pad), 4), name, fill="black", font=font)
    for r, (sample_id, pictures) in enumerate(rows):
        y = head + pad + r * (cell + pad)
        draw.text((4, y + cell // 2 - 6), sample_id, fill="black", font=font)
        for c, name in enumerate(columns):
            x = 90 + pad + c * (cell + pad)
            if name in pictures:
                img.paste(Image.fromarray(pictures[name]).resize((cell, cell), Image.NEAREST), (x, y))
            else:
                draw.rectangle([x, y, x + cell, y + cell], outline="grey")
                draw.text((x + 6, y + 6), "left out", fill="grey", font=font)
    out = io.BytesIO()
    img.save(out, format="PNG")
    return out.getvalue()


__all__ = ["EvaluateRequest", "EvaluateSummary", "evaluate"]
