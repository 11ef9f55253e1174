"""The dataset card's loading recipes (pipeline.publish.card) are code users copy: each of them
(`datasets`, webdataset, tarfile + OpenEXR) reads an EXR member's header and refuses what the
published spec does not allow before OpenEXR decodes a pixel. Every recipe of a generated
card runs, in a process of its own, on the smoke publication (it works) and on copies whose
first render or first maps member is a bomb: a render declaring 4096 x 4096 pixels (201 MB
decoded from 0.2 MB) and maps whose channel list comes 251 times (OpenEXR merges them: 262 MB
decoded from 0.6 MB). Each is refused naming the member, its process's peak memory no more
than on the good publication; run as a user's own script, a recipe that refuses ends with one
`error:` line and exit status 2, not a traceback."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.publish.request import PublishRequest
from pipeline.publish.writer import publish
from support.bombs import exr_bomb
from support.exrcraft import merged_channels_bomb
from support.publishing import hf_env, members, rewrite_tar, smoke_build

pytestmark = pytest.mark.slow  # a smoke build (once per session), a publish, nine recipe processes

MAPS = (
    "diffuse.R diffuse.G diffuse.B specular.R specular.G specular.B roughness.Y normal.X normal.Y normal.Z mask.Y"
).split()
#: Runs argv[1] (a recipe) in this process; prints {"n", "error", "peak_mb"}.
RUN = r"""
import json, sys
code = open(sys.argv[1]).read()
namespace = {}
try:
    exec(compile(code, "recipe", "exec"), namespace)
    out = {"n": namespace.get("n"), "error": None}
except SystemExit as exc:  # a recipe's refusal: its message is on stderr
    out = {"n": None, "error": f"exit {exc.code}"}
except Exception as exc:
    out = {"n": None, "error": f"{type(exc).__name__}: {exc}"[:500]}
with open("/proc/self/status") as fh:
    out["peak_mb"] = next(int(line.split()[1]) for line in fh if line.startswith("VmHWM:")) / 1024
print(json.dumps(out))
"""
BOMBS = {
    "render": ("renders", ".render.exr", lambda: exr_bomb(4096, 4096, {"render": ("R", "G", "B")})),
    "maps": ("materials", ".maps.exr", lambda: merged_channels_bomb(MAPS, 250)),
}


@pytest.fixture(scope="module")
def pub(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("recipes") / "pub"
    publish(PublishRequest(str(smoke_build(tmp_path_factory)), str(out), shard_bytes=300_000))
    return out


def recipes(pub: Path) -> dict[str, str]:
    """The card's recipes that decode with OpenEXR, by the library they load with."""
    blocks = re.findall(r"```python\n(.*?)```", (pub / "README.md").read_text(), flags=re.S)
    found = {}
    for block in blocks:
        for name in ("datasets", "webdataset", "tarfile"):
            if f"import {name}" in block and "OpenEXR" in block:
                found.setdefault(name, block)
    assert sorted(found) == ["datasets", "tarfile", "webdataset"]
    return found


def run(recipe: str, pub: Path, tmp: Path) -> dict:
    tmp.mkdir(parents=True, exist_ok=True)
    script = tmp / "recipe.py"
    script.write_text(recipe)
    done = subprocess.run(
        [sys.executable, "-c", RUN, str(script)], cwd=pub, env=hf_env(tmp), capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return {**json.loads(done.stdout.splitlines()[-1]), "stderr": done.stderr}


@pytest.fixture(scope="module")
def good(pub, tmp_path_factory) -> dict[str, dict]:
    return {name: run(code, pub, tmp_path_factory.mktemp(f"good-{name}")) for name, code in recipes(pub).items()}


def with_bomb(pub: Path, tmp: Path, role: str) -> tuple[Path, str]:
    """A copy of ``pub`` whose first ``role`` member is a bomb (its tar rewritten; the
    recipes read tars as they are, checksums unchecked); the member's name."""
    kind, suffix, make = BOMBS[role]
    copy = tmp / "pub"
    shutil.copytree(pub, copy)
    index = json.loads((copy / "publication.json").read_text())
    tar = copy / next(s["path"] for s in index["shards"] if s["kind"] == kind)
    items = members(tar)
    name = next(n for n, _ in items if n.endswith(suffix))
    rewrite_tar(tar, [(n, make() if n == name else d) for n, d in items])
    return copy, name


def test_every_recipe_reads_the_good_publication(good):
    for name, result in good.items():
        assert result["error"] is None and result["n"] == 16, (name, result)


@pytest.mark.parametrize("role", sorted(BOMBS))
@pytest.mark.parametrize("library", ["datasets", "tarfile", "webdataset"])
def test_every_recipe_refuses_a_bomb_before_decoding_it(pub, good, tmp_path, library, role):
    bombed, member = with_bomb(pub, tmp_path, role)
    result = run(recipes(bombed)[library], bombed, tmp_path / "run")
    field = BOMBS[role][1][1:]
    assert result["error"] == "exit 2", result
    key = member.split(".")[0]
    if library == "webdataset" and role == "maps":  # the maps are attached to each of its samples
        key = key + "_l0"
    assert result["stderr"].splitlines()[-1].startswith(f"error: {key} {field}: "), result
    assert result["peak_mb"] < good[library]["peak_mb"] + 40, (result, good[library])


@pytest.mark.parametrize("library", ["datasets", "tarfile", "webdataset"])
def test_every_recipe_refuses_a_member_larger_than_the_spec_allows(pub, good, tmp_path, library):
    """A render member padded to 40 MB (a good EXR, decodable, with zeros after it): refused by
    its size, and by the tarfile recipe before a byte of it is read."""
    copy = tmp_path / "pub"
    shutil.copytree(pub, copy)
    index = json.loads((copy / "publication.json").read_text())
    tar = copy / next(s["path"] for s in index["shards"] if s["kind"] == "renders")
    items = members(tar)
    name = next(n for n, _ in items if n.endswith(".render.exr"))
    rewrite_tar(tar, [(n, d + bytes(40 << 20) if n == name else d) for n, d in items])
    result = run(recipes(copy)[library], copy, tmp_path / "run")
    assert result["error"] == "exit 2", result
    assert " bytes, more than " in result["stderr"].splitlines()[-1], result
    if library == "tarfile":
        assert result["peak_mb"] < good[library]["peak_mb"] + 20, (result, good[library])


def _as_a_script(code: str, pub: Path, tmp: Path) -> subprocess.CompletedProcess:
    """``code`` saved as the user's own script and run with this Python, in the publication."""
    tmp.mkdir(parents=True, exist_ok=True)
    script = tmp / "load_shaderball.py"
    script.write_text(code)
    return subprocess.run(
        [sys.executable, str(script)], cwd=pub, env=hf_env(tmp), capture_output=True, text=True, timeout=300
    )


@pytest.mark.parametrize("library", ["datasets", "tarfile", "webdataset", "shaderball"])
def test_a_recipe_run_as_a_users_script_ends_with_one_line_not_a_traceback(pub, tmp_path, library):
    bombed, member = with_bomb(pub, tmp_path, "render")
    if library == "shaderball":  # the project's reader: it checks each member's SHA-256 first
        blocks = re.findall(r"```python\n(.*?)```", (bombed / "README.md").read_text(), flags=re.S)
        code = next(b for b in blocks if "from pipeline.publish import iter_samples" in b)
        expected = "error: "
    else:
        code = recipes(bombed)[library]
        expected = f"error: {member.split('.')[0]} render.exr: its EXR header says other channels or another size"
    done = _as_a_script(code, bombed, tmp_path / "run")
    assert done.returncode == 2, (done.returncode, done.stderr[-3000:])
    assert "Traceback" not in done.stderr, done.stderr[-3000:]
    assert done.stderr.splitlines()[-1].startswith(expected), done.stderr[-3000:]
    if library == "shaderball":  # the rewritten tar is refused whole, by name
        assert "shards/renders-" in done.stderr.splitlines()[-1], done.stderr[-3000:]
