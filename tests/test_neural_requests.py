"""The neural commands are made from their requests (pipeline.neural.config): the gaps a user
met, each closed. --json given a value names --json-out; old spellings name the new ones
(`evaluate --samples`: --limit; `neural-bench denoise --limit/--samples`: --draws);
`neural-bench loaders` names DIR and PUB; `train` says its loss once and how long it will
take; `evaluate` takes a rebuild of the run's dataset (the same files, another folder and
manifest) as the run's, and says how it compared a dataset it refuses."""

from __future__ import annotations

import json
import shutil

import click
import pytest
from click.testing import CliRunner

from cli import main
from pipeline.errors import ShaderballError
from pipeline.neural.evaluate import same_dataset

TINY = ["--loss", "l1", "--resolution", "16", "--width", "0.25", "--batch-size", "4", "--threads", "1", "--seed", "1"]
NEURAL = ("train", "infer", "evaluate", "export", "sweep", "neural-bench loaders", "neural-bench collate")
NEURAL += ("neural-bench denoise", "neural-bench train-options")
NUMBERS = (click.types.IntParamType, click.types.FloatParamType)


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _command(name: str) -> click.Command:
    command = main
    for word in name.split():
        command = command.commands[word]
    return command


@pytest.mark.parametrize("args", [["evaluate", "RUN", "DS", "--json=out.json"], ["train", "DS", "--json=out.json"]])
def test_json_given_a_value_is_one_document_naming_json_out(args, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    doc = json.loads(result.stdout)  # exactly one document
    assert doc["ok"] is False and doc["error"].startswith("--json=out.json: --json is a flag"), doc
    if args[0] == "evaluate":  # it writes a file of results with --json-out; train none
        assert "write the file with --json-out out.json" in doc["error"], doc  # the name given
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "args, new",
    [
        (["evaluate", "RUN", "DS", "--samples", "2"], "--limit"),
        (["neural-bench", "denoise", "DS", "--samples", "1"], "--draws"),
        (["neural-bench", "denoise", "DS", "--limit", "1"], "--draws"),  # --limit is "the first N" only
    ],
)
def test_an_old_spelling_exits_2_naming_the_new_one(args, new, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2 and f"{args[-2]}: renamed; use {new}" in result.output, result.output


def test_limit_is_the_first_n_samples_and_draws_are_spread():
    evaluate = {p.name: p for p in _command("evaluate").params}
    assert "first N samples" in evaluate["limit"].help
    options = [p for p in _command("neural-bench denoise").params if isinstance(p, click.Option) and not p.hidden]
    denoise = {o: p for p in options for o in p.opts}
    assert "spread over the dataset" in denoise["--draws"].help and "--limit" not in denoise


@pytest.mark.parametrize("name", NEURAL)
def test_every_numeric_option_shows_its_range(name):
    result = _invoke(*name.split(), "--help")
    assert result.exit_code == 0, result.output
    for param in _command(name).params:
        if isinstance(param, click.Option) and not param.hidden and not param.is_flag:
            rule = getattr(param.type, "inner", None)
            if getattr(rule, "py_type", None) in (int, float) or isinstance(param.type, NUMBERS):
                assert "Allowed:" in param.help, f"{name} {param.opts[0]}: no range in its help"


def test_loaders_names_its_operands_dir_and_pub(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    missing = _invoke("neural-bench", "loaders", tmp_path / "a", tmp_path / "nope")
    assert missing.exit_code == 2 and "error: PUB: " in missing.output and "does not exist" in missing.output
    empty = _invoke("neural-bench", "loaders", tmp_path / "a", tmp_path / "b")
    assert empty.exit_code == 2, empty.output
    assert f'error: DIR: "{tmp_path / "a"}" has no dataset.json; ' in empty.stderr, empty.output
    assert "DATASET" not in empty.output


@pytest.mark.slow
def test_loaders_names_pub_when_the_publication_is_refused(reference, tmp_path):
    (tmp_path / "b").mkdir()
    result = _invoke("neural-bench", "loaders", reference, tmp_path / "b", "--repeats", 1)
    assert result.exit_code == 2 and f'error: PUB: "{tmp_path / "b"}" has no dataset.json; ' in result.stderr
    assert "DATASET" not in result.output and "DIR" not in result.output


@pytest.fixture(scope="module")
def tiny_run(reference, tmp_path_factory):
    out = tmp_path_factory.mktemp("requests") / "run"
    result = _invoke("train", reference, "--out", out, "--epochs", 1, *TINY)
    assert result.exit_code == 0, result.output
    return out, result


@pytest.mark.slow
def test_train_says_its_loss_once_and_how_long_it_will_take(tiny_run, reference, tmp_path):
    _out, result = tiny_run
    assert result.output.count("loss: l1 (--loss l1)") == 1, result.output
    estimate = [line for line in result.stderr.splitlines() if line.startswith("estimate: about ")]
    assert len(estimate) == 1 and " for 1 epoch (" in estimate[0] and " s scoring an epoch" in estimate[0], (
        result.stderr
    )
    assert "epoch 1/1 done: " in result.stderr, result.stderr
    doc = json.loads(_invoke("train", reference, "--out", tmp_path / "r", "--epochs", 1, *TINY, "--json").stdout)
    assert doc["ok"] and doc["estimated_seconds"] > 0 and doc["estimate"].startswith("estimate: about ")


def _rebuilt(reference, folder):
    """``reference`` as a rebuild of its spec writes it: the same files, in another folder,
    and a manifest whose records hold other render times."""
    shutil.copytree(reference, folder)
    lines = []
    for line in (folder / "manifest.jsonl").read_text().splitlines():
        record = json.loads(line)
        record["stats"]["time_s"] = record["stats"]["time_s"] + 0.001
        lines.append(json.dumps(record, sort_keys=True, separators=(",", ":")))
    (folder / "manifest.jsonl").write_text("\n".join(lines) + "\n")
    return folder


@pytest.mark.slow
def test_evaluate_takes_a_rebuild_of_the_runs_dataset_as_the_runs(tiny_run, reference, tmp_path):
    run, _ = tiny_run
    rebuilt = _rebuilt(reference, tmp_path / "rebuilt")
    assert (rebuilt / "manifest.jsonl").read_bytes() != (reference / "manifest.jsonl").read_bytes()
    args = ["--spp", "none", "--no-flip", "--limit", 1, "--json"]
    result = _invoke("evaluate", run, rebuilt, "--out", tmp_path / "ev", *args)
    assert result.exit_code == 0, result.output
    results = json.loads((tmp_path / "ev" / "results.json").read_text())
    assert results["split"] == "test" and "mean_image" in results["mean"], results["notes"]
    assert results["dataset_compared"].startswith("the same spec digest and the same samples")


@pytest.mark.slow
def test_evaluate_refuses_another_dataset_saying_how_it_compared(tiny_run, reference, tmp_path):
    run, _ = tiny_run
    other = _rebuilt(reference, tmp_path / "other")
    lines = (other / "manifest.jsonl").read_text().splitlines()
    record = json.loads(lines[0])
    record["lighting_vector"][3] += 0.5  # another sample, whatever its files hold
    lines[0] = json.dumps(record)
    (other / "manifest.jsonl").write_text("\n".join(lines) + "\n")
    result = _invoke("evaluate", run, other, "--spp", "none", "--no-flip", "--limit", 1, "--out", tmp_path / "ev")
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f'error: DATASET: "{other}" is not the dataset the run was trained on: ')
    assert "its samples differ from the run's" in result.output and "--split all" in result.output
    assert "--split: " not in result.output  # --split was not given: it is not what is wrong
    assert not (tmp_path / "ev").exists()


class _Source:
    def __init__(self, content, identity=None):
        self.content, self.identity = content, identity or {"manifest_sha256": "m"}


def test_same_dataset_compares_content_and_says_how():
    content = {"spec_digest": "s", "samples_sha256": "x"}
    run = {"dataset_content": content, "identity": {"dataset": {"manifest_sha256": "other"}}}
    assert same_dataset(run, _Source(dict(content))) == (True, same_dataset(run, _Source(content))[1])
    same, how = same_dataset(run, _Source({"spec_digest": "t", "samples_sha256": "y"}))
    assert not same and "another spec" in how
    same, how = same_dataset(run, _Source({"spec_digest": "s", "samples_sha256": "y"}))
    assert not same and "samples differ" in how
    old = {"identity": {"dataset": {"manifest_sha256": "m"}}}  # a run made before content was recorded
    assert same_dataset(old, _Source(content))[0]
    same, how = same_dataset(old, _Source(content, {"manifest_sha256": "n"}))
    assert not same and "manifest's SHA-256" in how


@pytest.mark.parametrize("content", ["abc", ["spec", "samples"], 7, {"spec_digest": "s", "samples_sha256": ["x"]}])
def test_a_dataset_content_of_another_shape_is_a_damaged_config_not_an_absent_one(content):
    """A run's dataset_content that is not an object of strings is refused, naming the field,
    rather than taken for a run that recorded none (and compared by its manifest instead)."""
    run = {"dataset_content": content, "identity": {"dataset": {"manifest_sha256": "m"}}}
    with pytest.raises(
        ShaderballError, match=r"^config\.json: dataset_content(\.samples_sha256)? is .*, not (an object|a string)"
    ):
        same_dataset(run, _Source({"spec_digest": "s", "samples_sha256": "x"}))
    assert same_dataset({**run, "dataset_content": None}, _Source({}))[0]  # recorded none: the manifest's SHA-256
