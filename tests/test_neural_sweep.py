"""`shaderball sweep`: the data-size table from several runs' reports, paired
differences with the baselines, seeds pooled, and runs on other held-out sets refused; a
report read bounded and every field sweep uses checked (missing, of another type, not a
finite number), refused naming the file and the field."""

import json
import os
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cli import main
from pipeline.errors import ShaderballError
from pipeline.fields import FieldError
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


#: Reports spoilt one field at a time, and the words of the refusal (after the file's name).
SPOILT = [
    ("no mean", lambda d: d.pop("mean"), "no mean (a report"),
    ("a sample without its id", lambda d: d["samples"][3].pop("id"), "no samples[3].id (a report"),
    ("no ci95", lambda d: d["mean"]["network"].pop("ci95"), "no mean.network.ci95 (a report"),
    (
        "a PSNR as text",
        lambda d: d["mean"]["network"].update(psnr="20.5"),
        'mean.network.psnr is a string ("20.5"), not a finite number',
    ),
    ("samples an object", lambda d: d.update(samples={}), "samples is an object ({}), not an array"),
    ("a sample a number", lambda d: d["samples"].__setitem__(0, 5), "samples[0] is an integer (5), not an object"),
    ("no samples", lambda d: d.update(samples=[]), "samples is an empty array"),
    (
        "a NaN PSNR",
        lambda d: d["samples"][2]["network"].update(psnr=float("nan")),
        "samples[2].network.psnr is a number (NaN), not a finite number",
    ),
    (
        "an infinite mean",
        lambda d: d["mean"]["mean_image"].update(psnr=float("inf")),
        "mean.mean_image.psnr is a number (Infinity), not a finite number",
    ),
    (
        "a baseline null",
        lambda d: d["samples"][1].update(nearest_sample=None),
        "samples[1].nearest_sample is null, not an object",
    ),
    (
        "an interval of one value",
        lambda d: d["mean"]["network"]["ci95"].update(psnr=[1.0]),
        "mean.network.ci95.psnr is an array ([1.0]), not null or an array of two finite numbers",
    ),
    (
        "a seed as text",
        lambda d: d["run_options"].update(seed="1"),
        'run_options.seed is a string ("1"), not an integer',
    ),
    ("an epoch without its number", lambda d: d["history"][-1].pop("epoch"), "no history[-1].epoch (a report"),
    (
        "more training renders than any machine holds",
        lambda d: d.update(train_renders=10**30),
        f"train_renders is {10**30}, not in [0, 1000000000000]",
    ),
]


@pytest.mark.parametrize("spoil, words", [(s, w) for _name, s, w in SPOILT], ids=[n for n, _s, _w in SPOILT])
def test_a_report_missing_a_field_or_holding_a_bad_value_is_refused_naming_both(tmp_path, spoil, words):
    good = _report(tmp_path, 1, 100, 1.0)
    doc = json.loads(Path(good).read_text())
    spoil(doc)
    bad = tmp_path / "spoilt.json"
    bad.write_text(json.dumps(doc))
    result = CliRunner().invoke(main, ["sweep", good, str(bad), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, (result.output, result.exception)
    assert result.output.startswith(f"error: REPORT.json: {bad}: {words}"), result.output
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "text, words",
    [
        (b"[[],[]," * 150_000 + b"[]]", "JSON arrays/objects and"),  # ~30x its size to parse
        (b"[" * 3000 + b"]" * 3000, "nested 3000 deep"),
        (b'[{"a": "[[[[" }, ' + b"[" * 40 + b"]" * 41, "nested 41 deep"),
    ],
    ids=["brackets", "nested", "nested-beside-a-string"],
)
def test_a_report_whose_parse_would_cost_more_than_its_size_is_not_parsed(tmp_path, text, words):
    path = tmp_path / "report.json"
    path.write_bytes(text)
    with pytest.raises(FieldError) as caught:
        sweep._load(str(path))
    assert str(caught.value).startswith(f"reports: {path}: ") and words in str(caught.value)


def test_a_report_larger_than_a_report_can_be_is_refused_before_it_is_read(tmp_path):
    """A report grown to 65 MiB (sparse) is refused from its size, not read (a 1.5 GB one was
    read whole, 3.3 GB of memory)."""
    path = Path(_report(tmp_path, 1, 100, 1.0))
    os.truncate(path, 65 << 20)
    tracemalloc.start()
    try:
        with pytest.raises(FieldError) as caught:
            sweep._load(str(path))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert f"reports: {path}: cannot be read ({65 << 20} bytes, over the" in str(caught.value)
    assert peak < 1 << 20, peak
