"""Try every bad input of docs/results/bad-inputs.md; print its table (markdown).

    .venv/bin/python scripts/bad_inputs.py             # print the table
    .venv/bin/python scripts/bad_inputs.py --write     # write docs/results/bad-inputs.md (headed by
                                                       # this command, the machine and the date)
                                                       # and the count of cases in README.md

Each case runs the real CLI (click's CliRunner, in this process) in a fresh folder and
records the exit code, the message, and whether any file was created or changed.
"""

from __future__ import annotations

import json
import os
import re
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))
from scripts.results_page import head, write_flag  # noqa: E402

SMOKE = (REPO / "manifests" / "smoke.toml").read_text()


def spec_with(old: str, new: str) -> str:
    if old not in SMOKE:
        raise AssertionError(f"smoke.toml has no {old!r}")
    return SMOKE.replace(old, new, 1)


#: (what, spec text or None, CLI arguments; {spec} {out} {dir} are filled in)
SPEC_CASES = [
    ("dataset.seed negative", spec_with("seed = 20191117", "seed = -1")),
    ("dataset.materials zero", spec_with("materials = 8 ", "materials = 0 ")),
    ("dataset.svbrdf_fraction above 1", spec_with("svbrdf_fraction = 0.5", "svbrdf_fraction = 1.5")),
    ("dataset.shard_size zero", spec_with("shard_size = 2", "shard_size = 0")),
    ("dataset.name with spaces", spec_with('name = "smoke"', 'name = "my smoke"')),
    ("render.resolution too small", spec_with("\nresolution = 64", "\nresolution = 8")),
    ("render.spp zero", spec_with("spp = 16", "spp = 0")),
    ("render.variant unknown", spec_with('variant = "auto"', 'variant = "vulkan"')),
    ("render.max_depth too large", spec_with("max_depth = 8", "max_depth = 100")),
    ("render.spp as a string", spec_with("spp = 16", 'spp = "16"')),
    ("render key misspelt", spec_with("spp = 16", "sppp = 16")),
    ("lighting.elevation_deg above 90", spec_with("elevation_deg = [5.0, 90.0]", "elevation_deg = [10.0, 95.0]")),
    ("lighting.turbidity below 1", spec_with("turbidity = [1.0, 10.0]", "turbidity = [0.5, 3.0]")),
    ("lighting.scheme unknown", spec_with('scheme = "stratified"', 'scheme = "random"')),
    ("lighting.sun unknown", spec_with('sun = "split"', 'sun = "moon"')),
    ("materials.roughness inverted", spec_with("roughness = [0.05, 1.0]", "roughness = [0.8, 0.2]")),
    ("materials.svbrdf_folders missing", spec_with("svbrdf_folders = []", 'svbrdf_folders = ["/nonexistent/maps"]')),
    ("storage.compression unknown", spec_with('compression = "zip"', 'compression = "lzma"')),
    ("storage.layers unknown", spec_with('layers = ["diffuse"', 'layers = ["albedo"')),
    ("unknown section", SMOKE + "\n[renderer]\nspp = 4\n"),
    ("TOML syntax error", SMOKE.replace("[render]", "[render")),
    ("arrays nested 5,000 deep", spec_with("roughness = [0.05, 1.0]", "roughness = " + "[" * 5000 + "]" * 5000)),
    ("a table name of 3,000 parts", SMOKE + "\n[" + ".".join(["a"] * 3000) + "]\nk = 1\n"),
    (
        "10^9 renders (10^6 materials x 1,000 lightings)",
        spec_with("materials = 8 ", "materials = 1000000 ")
        .replace("lights_per_material = 2", "lights_per_material = 1000")
        .replace("shard_size = 2 ", "shard_size = 20 "),
    ),
    (
        "a shard of 200,000 renders",
        spec_with("shard_size = 2 ", "shard_size = 100000 ").replace("materials = 8 ", "materials = 100000 "),
    ),
    (
        "storage.layers repeated 20,000 times",
        spec_with('layers = ["diffuse"', "layers = [" + '"diffuse", ' * 20000 + '"diffuse"'),
    ),
    ("a corrupt image in svbrdf_folders", spec_with("svbrdf_folders = []", 'svbrdf_folders = ["badmaps"]')),
    (
        "a 176 kB PNG of 15000 x 12000 pixels in svbrdf_folders",
        spec_with("svbrdf_folders = []", 'svbrdf_folders = ["bombs"]'),
    ),
]

COMMAND_CASES = [
    ("build: spec file missing", ["build", "{dir}/nope.toml", "--out", "{out}"]),
    ("build: --workers negative", ["build", "{smoke}", "--out", "{out}", "--workers", "-1"]),
    ("build: --scheduler unreachable", ["build", "{smoke}", "--out", "{out}", "--scheduler", "tcp://127.0.0.1:9"]),
    ("build: --out is a file", ["build", "{smoke}", "--out", "{file}"]),
    ("build: --out holds other files", ["build", "{smoke}", "--out", "{foreign}"]),
    ("build: --out holds another spec's dataset", ["build", "{smoke}", "--out", "{other_dataset}"]),
    ("build: spec not UTF-8", ["build", "{dir}/latin1.toml", "--out", "{out}"]),
    ("build: --out under a regular file", ["build", "{smoke}", "--out", "{file}/ds"]),
    ("build: --out a dangling symlink", ["build", "{smoke}", "--out", "{dir}/dangling"]),
    ("build: --out a symlink loop", ["build", "{smoke}", "--out", "{dir}/loop"]),
    ("build: --out a name of 300 bytes", ["build", "{smoke}", "--out", "{dir}/" + "x" * 300]),
    ("bench: spec not UTF-8", ["bench", "{dir}/latin1.toml"]),
    ("render: --elevation 95", ["render", "--elevation", "95", "--out", "{out}/x.exr"]),
    ("render: --turbidity 11", ["render", "--turbidity", "11", "--out", "{out}/x.exr"]),
    ("render: --diffuse out of range", ["render", "--diffuse", "1.5,0,0", "--out", "{out}/x.exr"]),
    ("render: --normal pointing down", ["render", "--normal", "0,0,-1", "--out", "{out}/x.exr"]),
    ("render: --out not .exr", ["render", "--out", "{out}/x.png"]),
    ("render: --svbrdf missing", ["render", "--svbrdf", "{dir}/nope.png", "--out", "{out}/x.exr"]),
    ("render: --spp 0", ["render", "--spp", "0", "--out", "{out}/x.exr"]),
    ("scene: --resolution 5", ["scene", "--out", "{out}", "--resolution", "5"]),
    ("validate: folder missing", ["validate", "{dir}/nope"]),
    ("validate: not a dataset", ["validate", "{foreign}"]),
    ("info: not a dataset", ["info", "{foreign}"]),
    ("preview: not a dataset", ["preview", "{foreign}", "--out", "{out}/p.png"]),
    ("unpack: --out under a regular file", ["unpack", "{foreign}", "--out", "{file}/sub"]),
    ("publish: --out under a regular file", ["publish", "{foreign}", "--out", "{file}/sub"]),
    ("validate --json: folder missing", ["validate", "{dir}/nope", "--json"]),
    ("info --json: not a dataset", ["info", "{foreign}", "--json"]),
    ("verify --json: PUB missing", ["verify", "{dir}/nope", "--json"]),
    ("unpack --json: --out not empty", ["unpack", "{foreign}", "--out", "{other_dataset}", "--json"]),
    (
        "publish --json: --shard-bytes not a number",
        ["publish", "{foreign}", "--out", "{out}", "--shard-bytes", "x", "--json"],
    ),
    ("plan: --renders 0", ["plan", "{smoke}", "--renders", "0"]),
    ("plan: --cluster slurm without --cores", ["plan", "{smoke}", "--cluster", "slurm", "--jobs", "2"]),
    ("plan --json: SPEC a folder", ["plan", "{foreign}", "--json"]),
    ("info: SPEC not a spec", ["info", "{file}"]),
]


#: Image files read from outside: sizes checked from the header before decoding (docs/materials.md).
IMAGE_CASES = [
    (
        "render: --svbrdf a 176 kB PNG of 15000 x 12000",
        ["render", "--svbrdf", "{bombs}/strip.png", "--out", "{out}/x.exr"],
    ),
    ("render: --svbrdf a map of 4000 x 4000 pixels", ["render", "--svbrdf", "{bombs}/maps", "--out", "{out}/x.exr"]),
]

#: A training run's config.json as `shaderball train` writes it (the fields commands read).
RUN_CONFIG = {
    "identity": {"dataset": None},
    "identity_digest": "0" * 64,
    "network": {"resolution": 16, "width": 0.1},
    "tonemap": {"exposure": 1.0},
    "split": {"train": ["m000000"], "test": []},
}
DEEP = "[" * 100_000 + "]" * 100_000
#: (what, the run folder's config.json with one thing wrong, CLI arguments; {run} is that folder)
RUN_CASES = [
    (
        "infer: config.json without identity_digest",
        {"identity_digest": None},
        ["infer", "{run}", "--out", "{out}/x.exr"],
    ),
    ("infer: config.json network an integer", {"network": 5}, ["infer", "{run}", "--out", "{out}/x.exr"]),
    (
        "evaluate: config.json network.width a string",
        {"network": {"resolution": 16, "width": "wide"}},
        ["evaluate", "{run}", "{foreign}", "--out", "{out}"],
    ),
    (
        "evaluate: config.json network.resolution a list",
        {"network": {"resolution": [16]}},
        ["evaluate", "{run}", "{foreign}", "--out", "{out}"],
    ),
    (
        "infer: config.json split.test a string",
        {"split": {"train": [], "test": "m1"}},
        ["infer", "{run}", "--out", "{out}/x.exr"],
    ),
    ("evaluate: config.json nested 100,000 deep", {"network": DEEP}, ["evaluate", "{run}", "{foreign}"]),
]


def run_config_text(change: dict) -> str:
    config = {k: v for k, v in {**RUN_CONFIG, **change}.items() if v is not None}
    return json.dumps(config).replace(json.dumps(DEEP), DEEP)


def snapshot(folder: Path) -> dict:
    """Every entry under ``folder`` (links as links: a symlink loop is one entry)."""
    out = {}
    for dirpath, dirnames, names in os.walk(folder):
        for name in sorted(dirnames + names):
            path = os.path.join(dirpath, name)
            info = os.lstat(path)
            out[os.path.relpath(path, folder)] = (info.st_size, info.st_mtime_ns)
    return out


def make_bombs(folder: Path) -> None:
    """Decompression bombs (tests/support/bombs.py): a strip over twice Pillow's pixel
    limit, and a folder of maps whose diffuse map is over a map's 2048 x 2048."""
    from support.bombs import png_bomb

    (folder / "maps").mkdir(parents=True)
    (folder / "strip.png").write_bytes(png_bomb(15000, 12000))
    for name in ("specular", "roughness", "normal"):
        (folder / "maps" / f"{name}.png").write_bytes(png_bomb(16, 16))
    (folder / "maps" / "diffuse.png").write_bytes(png_bomb(4000, 4000))


def run_case(args: list[str], spec_text: str | None, base: Path, run_config: dict | None = None) -> dict:
    from click.testing import CliRunner

    from cli import main

    base.mkdir(parents=True)
    (base / "file.txt").write_text("x")
    foreign = base / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    other = base / "other"
    other.mkdir()
    (other / "spec.toml").write_text(spec_with("seed = 20191117", "seed = 7"))
    (base / "latin1.toml").write_bytes(SMOKE.replace('name = "smoke"', 'name = "sm\u00f6ke"').encode("latin-1"))
    (base / "dangling").symlink_to(base / "nowhere")
    (base / "loop").symlink_to(base / "loop")
    (base / "badmaps").mkdir()
    (base / "badmaps" / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    if "bombs" in " ".join(args) + (spec_text or ""):
        make_bombs(base / "bombs")
    if run_config is not None:
        (base / "run").mkdir()
        (base / "run" / "config.json").write_text(run_config_text(run_config))
    spec = base / "spec.toml"
    if spec_text is not None:
        spec.write_text(spec_text)
        args = ["build", str(spec), "--out", "{out}"]
    fill = {
        "dir": str(base),
        "out": str(base / "out"),
        "smoke": str(REPO / "manifests" / "smoke.toml"),
        "file": str(base / "file.txt"),
        "foreign": str(foreign),
        "other_dataset": str(other),
        "bombs": str(base / "bombs"),
        "run": str(base / "run"),
    }
    argv = [a.format(**fill) for a in args]
    before = snapshot(base)
    result = CliRunner().invoke(main, argv)
    after = snapshot(base)
    message = " ".join(result.output.split())
    doc = None
    if "--json" in argv:  # stdout is one JSON document, whatever happens: shown instead
        try:
            doc = json.loads(result.stdout)
            message = "stdout: " + json.dumps(doc, sort_keys=True)
        except ValueError:
            message = f"NOT JSON on stdout: {result.stdout!r}"
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        message = f"UNCAUGHT {type(result.exception).__name__}: {result.exception}"
    message = message.replace(str(base), "DIR").replace(str(REPO), ".")
    message = re.sub(r"x{300}", "<300 x's>", message)
    return {"argv": argv, "exit_code": result.exit_code, "message": message, "wrote": before != after, "json": doc}


def all_cases():
    yield from ((what, None, args, None) for what, args in COMMAND_CASES)
    yield from ((what, text, ["build", "{spec}"], None) for what, text in SPEC_CASES)
    yield from ((what, None, args, None) for what, args in IMAGE_CASES)
    yield from ((what, None, args, config) for what, config, args in RUN_CASES)


def run_all() -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, (what, text, args, config) in enumerate(all_cases()):
            row = run_case(args, text, Path(tmp) / f"case{i:02d}", config)
            row["what"] = what
            rows.append(row)
    return rows


def table(rows: list[dict]) -> str:
    out = ["| # | bad input | exit | wrote anything | message |", "|---|---|---|---|---|"]
    for i, r in enumerate(rows, 1):
        msg = re.sub(r"\s+", " ", r["message"])[:300].replace("|", "\\|")
        out.append(f"| {i} | {r['what']} | {r['exit_code']} | {'yes' if r['wrote'] else 'no'} | {msg} |")
    return "\n".join(out) + "\n"


#: The generated page; docs/bad-inputs.md says what the exit codes mean and links here.
PAGE = REPO / "docs" / "results" / "bad-inputs.md"


def page_text(new_table: str, count: int) -> str:
    return head("Bad inputs run through the CLI", ".venv/bin/python scripts/bad_inputs.py --write") + (
        f"{count} cases, each a real run of the CLI (click's CliRunner) in a fresh folder (`DIR` below); spec cases "
        "build `manifests/smoke.toml` with one line changed. `tests/test_bad_inputs.py` runs every case again, "
        "asserts exit code 2, an error message and that nothing in the case's folder was created or changed, "
        "and that this table is the one the script prints. What the exit codes mean: "
        "[docs/bad-inputs.md](../bad-inputs.md).\n\n" + new_table
    )


def write_page(new_table: str, count: int, page: Path = PAGE) -> None:
    page.parent.mkdir(parents=True, exist_ok=True)
    page.write_text(page_text(new_table, count))


#: README.md's words for the count of rows in the table.
README_COUNT = re.compile(r"\d+ bad inputs run through the CLI")


def write_readme_count(count: int, readme: Path = REPO / "README.md") -> None:
    readme.write_text(README_COUNT.sub(f"{count} bad inputs run through the CLI", readme.read_text(), count=1))


if __name__ == "__main__":
    write = write_flag(sys.argv[1:], "bad_inputs.py")  # checked before anything runs or is written
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    rows = run_all()
    result = table(rows)
    if write:
        write_page(result, len(rows))
        write_readme_count(len(rows))
    else:
        print(result, end="")
