"""GPUs without a GPU: each local worker pinned to its device through CUDA_VISIBLE_DEVICES in its
own environment (read back from the worker processes), the batch jobs' GPU request and per-GPU
worker lines (dask-jobqueue's own script), and the refusals. docs/cluster.md, "GPUs"."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from pipeline.errors import ShaderballError
from pipeline.run.cluster.connection import connect, job_script
from pipeline.run.cluster.options import ClusterOptions
from pipeline.run.cluster.worker_env import gpu_pins

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
JOB = dict(jobs=2, cores=4, memory="8GiB", walltime="01:00:00")


def test_one_worker_per_visible_gpu_with_cuda_and_none_pinned_otherwise(monkeypatch):
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "2,5,7")
    assert gpu_pins(ClusterOptions(), "cuda_ad_rgb") == ["2", "5", "7"]
    assert gpu_pins(ClusterOptions(), "llvm_ad_rgb") is None
    assert gpu_pins(ClusterOptions(gpus=2), "cuda_ad_rgb") == ["2", "5"]
    assert gpu_pins(ClusterOptions(gpus=(0, 2)), "llvm_ad_rgb") == ["2", "7"]
    assert gpu_pins(ClusterOptions(gpus=(1,), workers=3), "cuda_ad_rgb") == ["5", "5", "5"]
    assert gpu_pins(ClusterOptions(gpus=2, workers=4), "cuda_ad_rgb") == ["2", "5", "2", "5"]


def test_gpus_beyond_the_visible_ones_are_refused_naming_the_field(monkeypatch):
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0,1")
    with pytest.raises(ShaderballError, match=r"gpus.*2 GPU\(s\) visible"):
        gpu_pins(ClusterOptions(gpus=3), "cuda_ad_rgb")
    with pytest.raises(ShaderballError, match=r"gpus.*no GPU 4 here"):
        gpu_pins(ClusterOptions(gpus=(0, 4)), "cuda_ad_rgb")


@pytest.mark.parametrize(
    "options, field",
    [
        (dict(gpus=2, cluster="slurm", **JOB), "gpus"),
        (dict(gpus=2, scheduler="tcp://127.0.0.1:8786"), "gpus"),
        (dict(gpus=2, workers=0), "gpus"),
        (dict(gpus_per_job=2), "gpus_per_job"),
        (dict(gpus=(0, 0)), "gpus"),
        (dict(gpus=0), "gpus"),
    ],
)
def test_misplaced_gpu_options_are_refused(options, field):
    with pytest.raises(ShaderballError) as caught:
        ClusterOptions(**options)
    assert getattr(caught.value, "name", field) == field


def test_the_gpus_option_reads_a_count_or_ids():
    from pipeline.run.cluster.options import Gpus

    assert Gpus().parse("4") == 4
    assert Gpus().parse("0,2") == (0, 2)
    assert Gpus().parse("3,") == (3,)


def test_slurm_jobs_ask_for_gres_and_pin_one_worker_per_gpu():
    script = job_script(ClusterOptions(cluster="slurm", gpus_per_job=2, **JOB))
    assert "#SBATCH --gres=gpu:2" in script
    assert "export SHADERBALL_RENDER_THREADS=2" in script  # the job's cores shared by its 2 workers
    workers = [line for line in script.splitlines() if "dask_worker" in line]
    assert len(workers) == 2 and script.rstrip().endswith("wait")
    for i, line in enumerate(workers):
        assert f'CUDA_VISIBLE_DEVICES="${{SHADERBALL_GPUS[{i}]:-{i}}}"' in line
        assert f"--name shaderball-worker-{i} " in line and "--nworkers" not in line
        assert "--lifetime 3300s" in line and line.endswith("&")  # retires before the walltime


def test_pbs_jobs_ask_for_ngpus_in_their_select():
    script = job_script(ClusterOptions(cluster="pbs", gpus_per_job=4, **JOB))
    assert "#PBS -l select=1:ncpus=4:ngpus=4:mem=8192MB" in script
    assert sum("dask_worker" in line for line in script.splitlines()) == 4


def test_a_job_without_gpus_keeps_its_one_worker_line():
    script = job_script(ClusterOptions(cluster="slurm", **JOB))
    assert "gres" not in script and "SHADERBALL_GPUS" not in script
    assert "export SHADERBALL_RENDER_THREADS=4" in script


def _worker_env() -> tuple[str | None, str | None]:
    return os.environ.get("CUDA_VISIBLE_DEVICES"), os.environ.get("SHADERBALL_GPU")


def test_each_local_worker_process_sees_its_own_gpu(monkeypatch):
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "3,6")
    with connect(ClusterOptions(gpus=2, start_timeout=120), "llvm_ad_rgb") as conn:
        conn.client.wait_for_workers(2, timeout=120)
        seen = conn.client.run(_worker_env)
        assert "GPU(s) 3, 6" in conn.where
    assert sorted(seen.values()) == [("3", "3"), ("6", "6")]


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    from conftest import crash_module

    return crash_module().shared_reference(tmp_path_factory)[0]


@pytest.mark.slow
def test_a_build_on_two_pinned_workers_is_identical_and_names_each_gpus_renders(tmp_path, monkeypatch, reference):
    from conftest import crash_module

    from pipeline.run.build import build

    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0,1")
    out = tmp_path / "ds"
    summary = build(str(SMOKE), str(out), cluster=ClusterOptions(gpus=2))
    assert summary.rendered == 16
    note = next(n for n in summary.notes if n.startswith("renders per GPU"))
    assert "GPU 0:" in note and "GPU 1:" in note
    crash_module().check_complete(out, reference)


def test_plan_scales_the_recorded_gpu_rate_and_names_it():
    from pipeline.bench.gpu_rate import gpu_rate

    rate, source = gpu_rate(200, 150, "llvm_ad_rgb", 7.0)
    assert rate == pytest.approx(3.19 * 4) and "recorded" in source and "docs/results/gpu-rate.json" in source
    rate, source = gpu_rate(400, 150, "cuda_ad_rgb", 0.25)
    assert rate == pytest.approx(4.0) and source.startswith("measured")


def test_plan_gpu_options_are_checked():
    from pipeline.bench.estimate import PlanRequest

    with pytest.raises(ShaderballError):
        PlanRequest(spec=str(SMOKE), gpus_per_job=2)
    with pytest.raises(ShaderballError):
        PlanRequest(spec=str(SMOKE), gpus=2, cluster="slurm", jobs=1, cores=2)
    assert PlanRequest(spec=str(SMOKE), gpus_per_job=2, cluster="pbs", jobs=2, cores=8).gpus_per_job == 2
