"""What the page is told, over real HTTP with real renders: an exposure change re-tone-maps the
pictures held without rendering again, the first pass's noise is unknown (never 0), a dataset
sample's stored render comes as the reference, an upload comes back as the canvas shows it."""

from __future__ import annotations

import base64
import io
import json

import numpy as np
import pytest
import torch
from PIL import Image

from pipeline.image.tonemap import hdr_to_srgb8
from pipeline.store.exr import read_exr

torch.set_num_threads(1)
pytestmark = pytest.mark.slow  # a smoke build, a tiny training run and real renders
FINAL = lambda f: "network" in f and f.get("path", {}).get("spp") == 64 and "diff" in f  # noqa: E731


def _pixels(url: str) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB"))


def _post_view(http, client: str, exposure: float, material: dict | None = None, **light):
    doc = {
        "client": client,
        "material": material or {"kind": "uniform", "diffuse": [0.5, 0.3, 0.2], "roughness": 0.4},
        "light": {"azimuth_deg": 200.0, "elevation_deg": 35.0, "turbidity": 3.0, **light},
        "exposure": exposure,
    }
    status, answer = http.json("POST", "/api/view", doc)
    assert status == 200, answer
    return answer["generation"]


def test_an_exposure_change_re_tone_maps_without_rendering_again(http, app):
    generation = _post_view(http, "expo", 4.0)
    before = http.wait_frame("expo", generation, FINAL)
    again = _post_view(http, "expo", 1.0)
    assert again == generation  # the same view: nothing to render
    assert before["path"]["spp"] == 64 and before["path"]["exposure"] == 4.0
    after = http.wait_frame("expo", generation, lambda f: f.get("path", {}).get("exposure") == 1.0)
    assert after["path"]["spp"] == 64 and after["path"]["seconds"] == before["path"]["seconds"]
    for part in ("network", "path", "diff"):
        assert after[part]["png"] != before[part]["png"], part
        assert after[part]["exposure"] == 1.0
    assert _pixels(after["path"]["png"]).mean() < _pixels(before["path"]["png"]).mean()
    held = app.hub.clients["expo"]
    assert np.array_equal(_pixels(after["path"]["png"]), hdr_to_srgb8(held.path_hdr, 1.0))
    assert all(job.client != "expo" for job in app.hub.path_slots.jobs.values())  # nothing queued
    # A light change still renders anew.
    assert _post_view(http, "expo", 1.0, azimuth_deg=120.0) > generation


def test_the_first_pass_reports_its_noise_unknown_and_later_passes_measure_it(http, app, monkeypatch):
    published = []
    publish = app.hub.publish

    def recording(job, part, doc, *args, **kwargs):
        kept = publish(job, part, doc, *args, **kwargs)
        if kept and job.client == "noise":
            published.append((part, json.loads(json.dumps(app.hub.clients["noise"].frame.get("diff") or {})), doc))
        return kept

    monkeypatch.setattr(app.hub, "publish", recording)
    generation = _post_view(http, "noise", 4.0, azimuth_deg=80.0)
    http.wait_frame("noise", generation, FINAL)
    paths = [(doc, diff) for part, diff, doc in published if part == "path"]
    assert [doc["spp"] for doc, _ in paths] == [1, 4, 16, 64]
    first, first_diff = paths[0]
    assert first["noise_rel"] is None and not first["final"]
    assert first_diff == {} or first_diff["noise_psnr_db"] is None
    for doc, diff in paths[1:]:
        assert 0 < doc["noise_rel"] < 10
        assert diff == {} or 0 < diff["noise_psnr_db"] < 100
    noise = [doc["noise_rel"] for doc, _ in paths[1:]]
    assert noise == sorted(noise, reverse=True)  # more samples, less noise
    assert paths[-1][0]["final"]


def test_the_variance_of_a_pixels_mean_is_unbiased_and_unknown_from_one_sample():
    from pipeline.serve.workers import unbiased_variance

    rng = np.random.default_rng(3)
    samples = rng.exponential(0.2, size=(4, 8, 8))  # 4 samples of 8x8 pixels' luminance
    out = np.zeros((8, 8, 8))
    out[..., 4], out[..., 7] = samples.mean(axis=0), (samples**2).mean(axis=0)
    expected = samples.var(axis=0, ddof=1) / 4
    assert np.allclose(unbiased_variance(out, 4), expected, rtol=1e-5)
    assert unbiased_variance(out, 1) is None


def test_a_dataset_sample_comes_with_its_stored_render(http, reference):
    record = json.loads((reference / "manifest.jsonl").read_text().splitlines()[-1])
    material = {"kind": "dataset", "sample": record["id"]}
    light = record["lighting"]["requested"]
    generation = _post_view(http, "ref", 2.0, material=material, **light)
    frame = http.wait_frame("ref", generation, FINAL)
    stored = read_exr(str(reference / next(f["path"] for f in record["files"] if f["role"] == "render")))
    hdr = stored.layers["render"][..., :3]
    ref = frame["reference"]
    assert ref["sample"] == record["id"] and ref["resolution"] == hdr.shape[0]
    assert ref["light"] == {k: light[k] for k in ("elevation_deg", "azimuth_deg", "turbidity")}
    assert np.array_equal(_pixels(ref["png"]), hdr_to_srgb8(hdr, 2.0))
    # Tone-mapped again with the others on an exposure change; gone with another material.
    _post_view(http, "ref", 8.0, material=material, **light)
    frame = http.wait_frame("ref", generation, lambda f: f.get("reference", {}).get("exposure") == 8.0)
    assert np.array_equal(_pixels(frame["reference"]["png"]), hdr_to_srgb8(hdr, 8.0))
    other = _post_view(http, "ref", 8.0, **light)
    assert "reference" not in http.wait_frame("ref", other, lambda f: "path" in f)


def test_an_upload_comes_back_as_its_canvas_shows_it(http):
    buffer = io.BytesIO()
    Image.new("RGB", (8, 8), (51, 102, 153)).save(buffer, format="PNG")
    headers = {"Content-Type": "image/png"}
    status, _, body = http.request("POST", "/api/upload?client=canvas&map=diffuse", buffer.getvalue(), headers)
    doc = json.loads(body)
    assert status == 200, doc
    preview = _pixels(doc["preview"])
    assert preview.shape[:2] == tuple(doc["texels"])
    # value / 255 is the linear albedo; the canvas shows it sRGB-encoded (0.2 -> 124, 0.4 -> 170, 0.6 -> 203).
    assert np.abs(preview[4, 4].astype(int) - [124, 170, 203]).max() <= 1, preview[4, 4]
    status, info = http.json("GET", "/api/info")
    assert info["albedo_png"] == "linear" and info["texture_texels"] == preview.shape[0]


def test_a_publications_stored_render_is_the_folders(reference, tmp_path):
    from click.testing import CliRunner

    from cli import main
    from pipeline.neural.stored import StoredRenders

    pub = tmp_path / "pub"
    result = CliRunner().invoke(main, ["publish", str(reference), "--out", str(pub)])
    assert result.exit_code == 0, result.output
    folder, published = StoredRenders(str(reference)), StoredRenders(str(pub))
    sample = json.loads((reference / "manifest.jsonl").read_text().splitlines()[1])["id"]
    (hdr, doc), (again, doc_again) = folder.reference(sample), published.reference(sample)
    assert np.array_equal(hdr, again) and doc == doc_again
    assert folder.reference("m999999_l0") is None
