"""`shaderball sweep`: the data-size table from several runs' reports, paired
differences with the baselines, seeds pooled, and runs on other held-out sets refused."""

import json

import numpy as np
import pytest

from pipeline.errors import ShaderballError
from pipeline.neural import sweep
from pipeline.neural.config import SweepRequest


def _report(tmp_path, seed, renders, offset, materials=6, lights=2):
    rng = np.random.default_rng(seed * 100 + renders)
    rows = []
    for m in range(materials):
        for li in range(lights):
            base = 15 + rng.normal(0, 1)
            rows.append(
                {
                    "id": f"m{m:06d}_l{li}",
                    "material_id": f"m{m:06d}",
                    "class": "svbrdf",
                    "network": {"psnr": base + offset},
                    "mean_image": {"psnr": base},
                    "nearest_sample": {"psnr": base + 0.5},
                }
            )
    mean = {
        k: {"psnr": float(np.mean([r[k]["psnr"] for r in rows])), "ci95": {"psnr": [0.0, 99.0]}}
        for k in ("network", "mean_image", "nearest_sample")
    }
    doc = {
        "samples": rows,
        "mean": mean,
        "run_options": {"seed": seed},
        "run_split": {"train": ["a"] * (renders // 5)},
        "train_renders": renders,
        "history": [{"epoch": 3, "train_psnr": 20.0}],
    }
    path = tmp_path / f"r{seed}-{renders}.json"
    path.write_text(json.dumps(doc))
    return str(path)


def test_a_sweep_orders_runs_pairs_differences_and_pools_seeds(tmp_path):
    paths = [_report(tmp_path, s, n, off) for s in (1, 2) for n, off in ((100, 1.0), (400, 3.0))]
    out = tmp_path / "out"
    command = " ".join(["shaderball sweep", *paths, "--out", str(out)])  # as the command line spells the request
    summary, text = sweep.write_sweep(SweepRequest(tuple(paths), str(out)), command=command)
    assert summary == json.loads((out / "sweep.json").read_text()) and text == (out / "sweep.md").read_text()
    data = json.loads((out / "sweep.json").read_text())
    assert [(r["train_renders"], r["seed"]) for r in data["runs"]] == [(100, 1), (100, 2), (400, 1), (400, 2)]
    for r in data["runs"]:  # the network is the mean image + offset on every sample: the difference is exact
        diff = r["network_minus_mean_image"]
        assert diff["psnr"] == pytest.approx(1.0 if r["train_renders"] == 100 else 3.0)
        assert diff["ci95"][0] == pytest.approx(diff["psnr"]) and diff["ci95"][1] == pytest.approx(diff["psnr"])
        assert r["network_minus_nearest_sample"]["psnr"] == pytest.approx(diff["psnr"] - 0.5)
    pooled = {p["train_renders"]: p for p in data["pooled"]}
    assert pooled[100]["seeds"] == 2 and pooled[400]["seeds"] == 2
    lo, hi = pooled[400]["network"]["ci95"]
    assert lo <= pooled[400]["network"]["psnr"] <= hi
    assert (out / "data-size.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = (out / "sweep.md").read_text()
    assert "| 400 | 2 |" in text
    # headed by the command that wrote it, the machine and the date
    assert text.splitlines()[2].startswith(f"Written by `{command}` on 20") and "CPUs" in text.splitlines()[2]


def test_reports_on_other_held_out_samples_are_refused(tmp_path):
    a = _report(tmp_path, 1, 100, 1.0)
    b = _report(tmp_path, 2, 100, 1.0, materials=5)
    with pytest.raises(ShaderballError, match="different samples"):
        sweep.summarise([(p, sweep._load(p)) for p in (a, b)])
    with pytest.raises(ShaderballError, match="different samples"):
        sweep.write_sweep(SweepRequest((a, b), str(tmp_path / "o")))
    assert not (tmp_path / "o").exists()
