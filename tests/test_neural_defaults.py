"""train's defaults fit the machine it runs on: precision ``auto`` (the default) is bf16 only on
a CPU that computes bfloat16 in hardware (an AVX-512 CPU without AVX512_BF16 emulates it,
slower than fp32), threads 0 honour a cgroup's CPU quota, and ``--minutes`` sets a new run's
length to the epochs that fit a time budget, kept when the run resumes."""

import json
import math
from pathlib import Path

import pytest
import torch

import pipeline.neural.run_clock as run_clock
from pipeline.errors import ShaderballError
from pipeline.neural import runfiles, speed
from pipeline.neural.config import TrainConfig
from pipeline.neural.train import learning_rate, train
from support.neural_fakes import FakeSource, epoch_threads, train_config

torch.set_num_threads(1)

#: /proc/cpuinfo's first lines, cut, of CPUs of each kind.
AVX2_EPYC = "processor\t: 0\nvendor_id\t: AuthenticAMD\nflags\t\t: fpu sse2 avx fma avx2 bmi2\n"
AVX512_NO_BF16 = "processor\t: 0\nflags\t\t: fpu avx2 avx512f avx512dq avx512bw avx512vl avx512_vnni\n"
AVX512_BF16 = "processor\t: 0\nflags\t\t: fpu avx2 avx512f avx512bw avx512vl avx512_bf16\n"
SAPPHIRE_RAPIDS = "processor\t: 0\nflags\t\t: fpu avx2 avx512f avx512bw amx_bf16 amx_tile amx_int8\n"
ARM = "processor\t: 0\nFeatures\t: fp asimd bf16 i8mm\n"


@pytest.mark.parametrize(
    "cpuinfo, environ, native",
    [
        (AVX2_EPYC, {}, False),
        (AVX512_NO_BF16, {}, False),  # torch's own test (oneDNN's bf16 support) is true here: emulated
        (AVX512_BF16, {}, True),
        (SAPPHIRE_RAPIDS, {}, True),
        (AVX512_BF16, {"ONEDNN_MAX_CPU_ISA": "AVX2"}, False),  # oneDNN kept to AVX2
        (AVX512_BF16, {"ONEDNN_MAX_CPU_ISA": "avx512_core"}, False),
        (AVX512_BF16, {"ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16"}, True),
        (ARM, {}, False),  # not measured: fp32
        ("", {}, False),
    ],
    ids=["avx2", "avx512-no-bf16", "avx512-bf16", "amx", "isa-avx2", "isa-avx512-core", "isa-bf16", "arm", "none"],
)
def test_native_bf16_reads_the_cpu_flags(cpuinfo, environ, native):
    assert speed.native_bf16(cpuinfo, environ) is native


def test_auto_is_the_default_and_follows_the_flags(tmp_path, monkeypatch):
    assert TrainConfig(dataset="d", out="o").precision == "auto"
    cpu = torch.device("cpu")
    for flags, want in ((AVX512_NO_BF16, "fp32"), (AVX512_BF16, "bf16")):
        monkeypatch.setattr(speed, "native_bf16", lambda flags=flags: speed.cpu_flags(flags) >= {"avx512_bf16"})
        assert speed.resolve_precision("auto", cpu) == want
    assert speed.resolve_precision("auto", torch.device("cuda")) == "fp32"


@pytest.mark.parametrize(
    "text, cores", [("200000 100000", 2), ("150000 100000", 2), ("50000 100000", 1), ("max 100000", None), ("", None)]
)
def test_a_cgroup_quota_in_cores(text, cores):
    assert speed.cgroup_cores(text) == cores


def test_threads_0_keep_to_the_cgroup_quota(tmp_path, monkeypatch):
    """torch counts the cores of the process's affinity but not its cgroup's CPU quota: a
    container granted 1 CPU trains on 1 thread, not on the host's cores."""
    seen = epoch_threads(monkeypatch)
    monkeypatch.setattr(speed, "_quota_cores", lambda: 1)
    torch.set_num_threads(2)
    try:
        train(train_config(tmp_path, epochs=1, threads=0), source=FakeSource())
        assert seen == [1] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(1)


@pytest.mark.parametrize(
    "left_s, epoch_s, most, epochs", [(100, 10, 60, 11), (100, 30, 60, 4), (-5, 10, 60, 1), (1e9, 1, 60, 60)]
)
def test_the_epochs_a_budget_holds(left_s, epoch_s, most, epochs):
    assert run_clock.budget_epochs(left_s, epoch_s, most) == epochs


def test_a_budget_shortens_a_run_that_falls_behind_and_never_lengthens_it(monkeypatch):
    """A 60 s budget: the first epoch's 10 s sets 6 epochs; a second of 20 s (15 s a mean, 30 s
    left) cuts them to 4; a fast third does not bring them back."""
    clock = iter([10.0, 30.0, 35.0])
    monkeypatch.setattr(run_clock.time, "perf_counter", lambda: next(clock))
    length = run_clock.RunLength(60, held_epochs=1, minutes=1.0, started=0.0)
    notes = []
    lengths = [length.after_epoch(epoch, 0.0, lambda e: notes.append(e["note"])) for epoch in (1, 2, 3)]
    assert lengths == [6, 4, 4]
    assert notes == [
        "--minutes 1: the first epoch took 10 s with its scoring, 0.8 min are left: the run is 6 epochs",
        "--minutes 1: 15 s an epoch so far, 0.5 min left after epoch 2: the run is 4 epochs (was 6)",
    ]


def test_a_held_first_epoch_then_a_cosine_over_the_rest():
    config = TrainConfig(dataset="d", out="o", epochs=4, lr=1e-3, schedule="cosine")
    steps = 10
    rates = [learning_rate(config, s, steps, held_epochs=1) for s in range(4 * steps)]
    assert rates[:steps] == [1e-3] * steps and rates[steps] == 1e-3
    assert all(a > b for a, b in zip(rates[steps:], rates[steps + 1 :]))
    assert rates[-1] == pytest.approx(1e-3 * 0.5 * (1 + math.cos(math.pi * 29 / 30)))


def _log(run_dir):
    return [json.loads(line) for line in (run_dir / "log.jsonl").read_text().splitlines()]


def test_a_budget_sets_the_length_after_the_first_epoch(tmp_path):
    source = FakeSource()
    notes = []
    # no time left after the first epoch: the run is that epoch
    short = train(
        train_config(tmp_path, "short", epochs=5, schedule="cosine", minutes=1e-6),
        progress=lambda e: notes.append(e.get("note")),
        source=source,
    )
    assert short.epochs_done == 1 and [e["schedule_epochs"] for e in _log(tmp_path / "short")] == [1]
    assert any(
        n and n.startswith("--minutes 1e-06: the first epoch took ") and "the run is 1 epoch" in n for n in notes
    )
    assert "the run is 1 epoch" in "\n".join(short.lines())
    # time to spare: --epochs, the first held at the full rate, then the cosine
    long = train(train_config(tmp_path, "long", epochs=3, schedule="cosine", minutes=600), source=source)
    log = _log(tmp_path / "long")
    assert long.epochs_done == 3 and [e["schedule_epochs"] for e in log] == [3, 3, 3]
    assert log[0]["lr"] == 1e-3 and log[1]["lr"] < 1e-3
    # run again, with another budget or none: the run's length is kept, nothing is trained
    again = train(train_config(tmp_path, "short", epochs=5, schedule="cosine"), source=source)
    assert again.nothing_to_do and again.epochs_done == 1


@pytest.mark.slow
def test_a_budgeted_run_resumed_without_its_budget_keeps_its_schedule(tmp_path):
    source = FakeSource()
    straight = train(train_config(tmp_path, "straight", epochs=3, schedule="cosine", minutes=600), source=source)

    class Stop(Exception):
        pass

    def stop_in_epoch_3(event):
        if event.get("epoch") == 3:
            raise Stop

    with pytest.raises(Stop):
        train(train_config(tmp_path, "resumed", epochs=3, schedule="cosine", minutes=600), stop_in_epoch_3, source)
    resumed = train(train_config(tmp_path, "resumed", epochs=3, schedule="cosine"), source=source)
    assert resumed.resumed_from == 2 and resumed.epochs_done == straight.epochs_done == 3
    a, b = (runfiles.load_checkpoint(str(tmp_path / n))["model"] for n in ("straight", "resumed"))
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert [e["lr"] for e in _log(tmp_path / "resumed")] == [e["lr"] for e in _log(tmp_path / "straight")]


def test_a_budget_is_refused_with_several_processes(tmp_path):
    with pytest.raises(ShaderballError, match="^minutes: 5.0 is not allowed; unset with devices over 1"):
        train(train_config(tmp_path, minutes=5, devices=2, batch_size=2), source=FakeSource())


def test_make_serve_network_leaves_the_machine_to_train():
    """The out-of-the-box network's recipe forces no precision or threads (bf16 on a CPU
    without bf16 instructions ran 5.4x slower than fp32) and trains to a time budget."""
    makefile = (Path(__file__).resolve().parents[1] / "Makefile").read_text()
    recipe = makefile.split("\nserve-network:", 1)[1].split("\n\n", 1)[0]
    assert "shaderball train" in recipe and "--minutes" in recipe
    assert "--precision" not in recipe and "--threads" not in recipe
