"""The downstream study's measurements: references of the held-out samples (two halves at half
the reference spp each, re-rendered from the build's own records and texture maps, so the very
samples the networks saw) and each network's scores against them.

Scores of a network on a sample (the figures of `evaluate`, pipeline.neural.scores): relMSE on
the ball (the study's figure, pipeline.study.measure) and on the frame, of the network's picture
taken back to linear radiance; PSNR and SSIM of its 8-bit sRGB picture; HDR-FLIP where asked
and installed; the ball's mean luminance relative to the reference's (``bias_ball``). Never against the network's own (noisy) training targets.
"""

from __future__ import annotations

import json
import os
import time

import numpy as np

from pipeline.image.tonemap import hdr_to_srgb8
from pipeline.neural.data import box_downsample, open_dataset
from pipeline.neural.equal_time import PathTracer
from pipeline.neural.evaluate import dataset_variant, read_render
from pipeline.neural.infer import load_run_model, run_network
from pipeline.neural.scores import ldr_scores, network_hdr
from pipeline.neural.train import mean_image, pick_device
from pipeline.store.atomic import write_text_atomic
from pipeline.study import measure as m
from pipeline.study.run import derived_seed, load_reference, save_reference


def kept_rows(path: str, compute) -> list[dict]:
    """The rows kept in ``path`` by an earlier run, or ``compute()``'s, written there first."""
    if os.path.exists(path):
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    rows = compute()
    write_text_atomic(path, json.dumps(rows, indent=1) + "\n")
    return rows


def held_out(dataset, test_materials: list[str]):
    """The held-out part of an opened dataset (its samples of ``test_materials``)."""
    return dataset.subset(test_materials)


def mask_of(item) -> np.ndarray:
    """The ball's pixels of a dataset item, (H, W) bool."""
    mask = np.asarray(item["mask"].numpy() if hasattr(item["mask"], "numpy") else item["mask"])
    return mask.reshape(mask.shape[-2:]) > 0.5


def ensure_references(folder: str, dataset, spp: int, tick) -> dict:
    """{sample id: reference} of every sample of ``dataset`` (the held-out part of a build),
    read from ``folder`` or rendered there first (a killed study keeps what it rendered).
    A reference: the mean of two halves of ``spp / 2`` with seeds of their own, its floor (its
    own relMSE, from the halves' difference) and its CPU time."""
    os.makedirs(folder, exist_ok=True)
    tracer = PathTracer(dataset, dataset_variant(dataset))
    out = {}
    for index, sample in enumerate(dataset.samples):
        path = os.path.join(folder, f"{sample.id}.npz")
        ref = load_reference(path)
        if ref is None:
            record = dataset.records[sample.id]
            maps = tracer.material(sample)
            started, wall = time.process_time(), time.perf_counter()
            halves = [
                tracer.render(
                    record, maps, spp // 2, seed=derived_seed(int(record["seeds"]["render"]), "reference", h)
                )[0]
                for h in (1, 2)
            ]
            cpu_s, wall_s = time.process_time() - started, time.perf_counter() - wall
            image = (halves[0] + halves[1]) / 2.0
            terms = m.relmse_terms(halves[0], halves[1]) / 4.0  # the mean of two halves: a quarter of theirs
            ball = mask_of(dataset[index]).ravel()
            floor = {"floor_ball": float(terms[ball].mean()), "floor_frame": float(terms.mean())}
            ref = {"image": image, "variance": np.zeros(image.shape[:2]), "half1": halves[0], "half2": halves[1]}
            ref.update(floor=floor, cpu_s=cpu_s, wall_s=wall_s)
            save_reference(path, ref)
        out[sample.id] = ref
        tick(f"reference {sample.id} ({spp} spp)")
    return out


def score_run(
    run_dir: str, root: str, test_materials: list[str], references: dict, flip: bool, path: str
) -> list[dict]:
    """One network's rows (one per held-out sample), read from ``path`` or scored and written there."""
    return kept_rows(path, lambda: _score(run_dir, root, test_materials, references, flip))


def _score(run_dir: str, root: str, test_materials: list[str], references: dict, flip: bool) -> list[dict]:
    device = pick_device("auto")
    model, config = load_run_model(run_dir, device)
    exposure = float(config["tonemap"]["exposure"])
    dataset = held_out(open_dataset(root, resolution=model.resolution, exposure=exposure), test_materials)
    rows = []
    for index, sample in enumerate(dataset.samples):
        item = dataset[index]
        pred = run_network(model, item["maps"].numpy(), sample.lighting_vector, device)
        rows.append(image_row(sample.id, pred, references[sample.id]["image"], mask_of(item), exposure, flip))
    return rows


def image_row(
    sample_id: str, y: np.ndarray, ref_hdr: np.ndarray, mask: np.ndarray, exposure: float, flip: bool
) -> dict:
    """A [0, 1] network picture's figures against a reference."""
    scores = ldr_scores(y, ref_hdr, hdr_to_srgb8(ref_hdr, exposure), exposure, 0.0, flip)
    hdr = network_hdr(y, exposure)
    return {
        "sample_id": sample_id,
        "relmse_ball": m.relmse(hdr, ref_hdr, mask),
        "relmse_frame": m.relmse(hdr, ref_hdr),
        "psnr": scores["psnr"],
        "ssim": scores["ssim"],
        "flip": scores.get("flip"),
        # the ball's mean luminance against the reference's: an L1 network on noisy targets learns
        # their median, darker than their mean where the noise is skewed
        "bias_ball": m.ball_bias(hdr, ref_hdr, mask, None, np.zeros(mask.shape))[0],
    }


def target_rows(root: str, test_materials: list[str], resolution: int, references: dict, path: str) -> list[dict]:
    """A level's own renders of the held-out samples against the references: the noise its
    networks' targets carry (relMSE and luminance bias on the ball)."""
    return kept_rows(path, lambda: _targets(root, test_materials, resolution, references))


def _targets(root: str, test_materials: list[str], resolution: int, references: dict) -> list[dict]:
    dataset = held_out(open_dataset(root, resolution=resolution), test_materials)
    rows = []
    for index, sample in enumerate(dataset.samples):
        hdr = box_downsample(read_render(dataset, sample), dataset.factor)
        ref, mask = references[sample.id]["image"], mask_of(dataset[index])
        bias = m.ball_bias(hdr, ref, mask, None, np.zeros(mask.shape))[0]
        rows.append({"sample_id": sample.id, "relmse_ball": m.relmse(hdr, ref, mask), "bias_ball": bias})
    return rows


def mean_image_rows(
    root: str,
    train_materials: list[str],
    test_materials: list[str],
    resolution: int,
    references: dict,
    flip: bool,
    path: str,
) -> list[dict]:
    """The trivial baseline's rows: the mean training image of ``root`` (its training split)
    against every reference."""
    return kept_rows(path, lambda: _mean_image(root, train_materials, test_materials, resolution, references, flip))


def _mean_image(root, train_materials, test_materials, resolution: int, references: dict, flip: bool) -> list[dict]:
    source = open_dataset(root, resolution=resolution)
    mean_y = mean_image(source.subset(train_materials), workers=0)
    test = held_out(source, test_materials)
    rows = [
        image_row(sample.id, mean_y, references[sample.id]["image"], mask_of(test[i]), test.exposure, flip)
        for i, sample in enumerate(test.samples)
    ]
    return rows
