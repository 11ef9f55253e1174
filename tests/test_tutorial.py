"""docs/tutorial.md runs as written: every command of its ```sh blocks and every ```python
snippet, in order, in a fresh folder (``shaderball`` is this checkout's ``python -m cli``, put
first on PATH), each exits 0, and its output still holds the lines of the ```text block that
follows it on the page ("..." elides lines, or text inside a line). ``make`` lines are the
set-up the suite already runs inside: each names a target of the Makefile.

The README's picture of the demo's contact sheet (docs/img/smoke_preview.png) is what the
demo's own preview command draws from the same build, compared by structure with a tolerance
for the Monte Carlo noise in which CPUs differ (never by bits)."""

import os
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pipeline.check.preview import COLUMNS, GAP, LABEL_WIDTH

REPO = Path(__file__).resolve().parents[1]
TUTORIAL = REPO / "docs" / "tutorial.md"
PREVIEW_COPY = REPO / "docs" / "img" / "smoke_preview.png"
ELLIPSIS = "..."


@dataclass
class Step:
    """One command (or Python snippet) of the page and the output lines it shows."""

    kind: str  # "sh" or "python"
    code: str
    shown: list[str] = field(default_factory=list)
    output: str = ""
    exit: int | None = None
    seconds: float = 0.0


def page_blocks(text: str) -> list[tuple[str, str]]:
    """The fenced blocks of a markdown page, as (language, body), in order."""
    return [(m.group(1), m.group(2)) for m in re.finditer(r"^```(\w*)\n(.*?)^```\s*$", text, re.S | re.M)]


def page_steps(text: str) -> list[Step]:
    """Each line of a ```sh block is a step (comments and blank lines dropped), each ```python
    block one step; a ```text block shows the output of the step just before it."""
    steps: list[Step] = []
    for language, body in page_blocks(text):
        if language == "sh":
            for line in body.splitlines():
                command = line.split(" #", 1)[0].strip()
                if command and not command.startswith("#"):
                    steps.append(Step("sh", command))
        elif language == "python":
            steps.append(Step("python", body))
        elif language == "text":
            assert steps and not steps[-1].shown, f"a ```text block follows no command:\n{body}"
            steps[-1].shown = [line.strip() for line in body.splitlines() if line.strip()]
    return steps


def shown_line_found(shown: str, lines: list[str]) -> bool:
    """Whether an output line holds the pieces of ``shown`` (split at "...") in order."""
    pieces = [piece.strip() for piece in shown.split(ELLIPSIS) if piece.strip()]
    for line in lines:
        at = 0
        for piece in pieces:
            at = line.find(piece, at)
            if at < 0:
                break
            at += len(piece)
        else:
            return True
    return False


def missing_lines(step: Step) -> list[str]:
    lines = step.output.replace("\r", "\n").splitlines()
    return [shown for shown in step.shown if shown != ELLIPSIS and not shown_line_found(shown, lines)]


def make_targets() -> set[str]:
    text = (REPO / "Makefile").read_text()
    return {name for line in text.splitlines() if (m := re.match(r"^([\w-]+):", line)) for name in [m.group(1)]}


def run_tutorial(folder: Path) -> list[Step]:
    """Every step of the page in ``folder`` (``manifests`` linked in), as a user would run them."""
    bin_dir = folder / ".bin"
    bin_dir.mkdir()
    shim = bin_dir / "shaderball"
    shim.write_text(f'#!/bin/sh\nexec {shlex.quote(sys.executable)} -m cli "$@"\n')
    shim.chmod(0o755)
    (folder / "manifests").symlink_to(REPO / "manifests")
    env = dict(
        os.environ,
        PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
        PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
        PYTHONUNBUFFERED="1",
        # the Hugging Face snippet: nothing from the network, caches in this folder
        HF_DATASETS_OFFLINE="1",
        HF_HUB_OFFLINE="1",
        HF_HOME=str(folder / ".hf"),
    )
    steps = page_steps(TUTORIAL.read_text())
    for number, step in enumerate(steps):
        if step.kind == "sh" and step.code.split()[0] == "make":
            continue  # the set-up; test_make_lines_name_targets checks them
        if step.kind == "python":
            script = folder / f".snippet{number}.py"
            script.write_text(step.code)
            argv = [sys.executable, str(script)]
        else:
            argv = ["bash", "-c", step.code]
        start = time.monotonic()
        done = subprocess.run(argv, cwd=folder, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        step.seconds = time.monotonic() - start
        step.output, step.exit = done.stdout, done.returncode
        if done.returncode != 0:
            break  # what follows needs what this step makes
    return steps


@pytest.fixture(scope="module")
def tutorial(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tutorial")
    return folder, run_tutorial(folder)


@pytest.mark.slow
def test_every_command_of_the_tutorial_runs_and_prints_what_the_page_shows(tutorial):
    _, steps = tutorial
    ran = [step for step in steps if step.exit is not None]
    assert len(ran) >= 12, f"the page has {len(ran)} runnable steps; the walkthrough lost its commands"
    for step in ran:
        assert step.exit == 0, f"`{step.code}` exited {step.exit}:\n{step.output[-3000:]}"
        missing = missing_lines(step)
        assert not missing, (
            f"`{step.code.strip()}` no longer prints what docs/tutorial.md shows; missing:\n"
            + "\n".join(missing)
            + f"\n--- its output:\n{step.output[-3000:]}"
        )
    shown = sum(1 for step in ran if step.shown)
    assert shown >= 10, f"only {shown} steps show their output on the page"


def test_the_page_covers_the_walkthrough():
    """The commands the walkthrough is for are all on the page, and none is an old spelling."""
    commands = [step.code for step in page_steps(TUTORIAL.read_text()) if step.kind == "sh"]
    words = {command.split()[1] for command in commands if command.startswith("shaderball ")}
    assert {"build", "info", "validate", "preview", "publish", "verify", "train", "infer", "evaluate"} <= words
    for old in ("--samples", "--workers"):
        assert not any(old in command for command in commands if command.startswith("shaderball train")), old
    assert not any(re.search(r"--json \S", command) for command in commands), "--json is a flag"


def test_make_lines_name_targets():
    """The page's set-up lines are skipped by the run above (the suite runs inside that set-up),
    so each must at least name a Makefile target; the `shaderball` it puts on PATH is the
    package's console script."""
    makes = [step.code for step in page_steps(TUTORIAL.read_text()) if step.code.split()[0] == "make"]
    assert makes, "the page no longer says how to set up (`make setup` or `make demo`)"
    targets = make_targets()
    for line in makes:
        assert all(word in targets for word in line.split()[1:] if "=" not in word), f"{line}: not a Makefile target"
    assert re.search(r'^shaderball = "cli:main"$', (REPO / "pyproject.toml").read_text(), re.M)


def test_shown_lines_are_matched_with_elision():
    """The matcher the page test relies on: "..." elides, and a changed line is caught."""
    output = ["rendered 16, already present 0, 9.1 s (1.75 renders/s)", "valid: no problems found"]
    assert shown_line_found("rendered 16, already present 0, ... renders/s)", output)
    assert not shown_line_found("rendered 15, already present 0, ... renders/s)", output)
    assert not shown_line_found("renders/s) ... rendered 16", output)
    step = Step("sh", "x", shown=["...", "valid: no problems found", "invalid"], output="\n".join(output))
    assert missing_lines(step) == ["invalid"]


def demo_preview_command(dataset: Path, out: Path) -> list[str]:
    """The Makefile demo's preview line, on ``dataset`` (its `$(DEMO_OUT)/smoke`)."""
    text = (REPO / "Makefile").read_text()
    recipe = text.split("\ndemo:", 1)[1].split("\n\n", 1)[0]
    line = next(line.strip() for line in recipe.splitlines() if " preview " in line)
    words = shlex.split(
        line.replace("$(DEMO_OUT)/smoke-preview.png", str(out)).replace("$(DEMO_OUT)/smoke", str(dataset))
    )
    assert words[0] == "$(VENV)/bin/shaderball" and words[1] == "preview", line
    return [sys.executable, "-m", "cli", *words[1:]]


def block_means(image: np.ndarray, k: int = 8) -> np.ndarray:
    h, w = image.shape[0] // k * k, image.shape[1] // k * k
    return image[:h, :w].reshape(h // k, k, w // k, k, -1).mean(axis=(1, 3))


def render_columns(width: int) -> tuple[int, int]:
    """Where a contact sheet's render tiles lie across it (pipeline.check.preview's layout)."""
    tile = (width - LABEL_WIDTH - GAP) // len(COLUMNS) - GAP
    x0 = LABEL_WIDTH + COLUMNS.index("render") * (tile + GAP) + GAP
    return x0, x0 + tile


def same_picture_but_noise(a: np.ndarray, b: np.ndarray) -> list[str]:
    """Why two contact sheets are not the same picture up to the renders' Monte Carlo noise
    ([] when they are): the same size; outside the render tiles (labels, maps, background)
    at least 99.5% of pixels within 2 levels; in the render tiles every 8x8 block's mean within
    48 levels and the blocks' mean difference at most 4 (two noise realisations of the smoke
    renders at 16 spp: up to 23 and 1.7; a changed sample, lighting or tone map moves whole
    tiles)."""
    if a.shape != b.shape:
        return [f"size {a.shape[1]}x{a.shape[0]} against {b.shape[1]}x{b.shape[0]}"]
    a, b = a.astype(np.float64), b.astype(np.float64)
    x0, x1 = render_columns(a.shape[1])
    problems = []
    outside = np.concatenate([np.abs(a - b)[:, :x0], np.abs(a - b)[:, x1:]], axis=1).max(axis=-1)
    close = float((outside <= 2).mean())
    if close < 0.995:
        problems.append(f"only {close:.2%} of pixels beside the renders within 2 levels (want 99.5%)")
    blocks = np.abs(block_means(a[:, x0:x1]) - block_means(b[:, x0:x1]))
    if blocks.max() > 48 or blocks.mean() > 4:
        problems.append(
            f"the renders' 8x8 blocks differ by up to {blocks.max():.1f} levels, {blocks.mean():.2f} on average"
        )
    return problems


def test_the_comparison_catches_a_changed_sheet():
    """Two samples swapped, a label redrawn or a render brightened is another picture; new
    noise in the renders is not."""
    with Image.open(PREVIEW_COPY) as image:
        sheet = np.asarray(image.convert("RGB"))
    assert same_picture_but_noise(sheet, sheet) == []
    x0, x1 = render_columns(sheet.shape[1])
    rows = sheet.shape[0] // 8
    swapped = sheet.copy()
    swapped[rows : 2 * rows], swapped[2 * rows : 3 * rows] = sheet[2 * rows : 3 * rows], sheet[rows : 2 * rows]
    assert same_picture_but_noise(sheet, swapped)
    relabelled = sheet.copy()
    relabelled[30:60, 10:150] = 255 - relabelled[30:60, 10:150]
    assert same_picture_but_noise(sheet, relabelled)
    brighter = sheet.copy()
    brighter[:, x0:x1] = np.clip(sheet[:, x0:x1].astype(int) + 12, 0, 255)
    assert same_picture_but_noise(sheet, brighter)
    noisy = sheet.copy()
    noise = np.random.default_rng(0).integers(-40, 41, sheet[:, x0:x1].shape)
    noisy[:, x0:x1] = np.clip(sheet[:, x0:x1].astype(int) + noise, 0, 255)
    assert same_picture_but_noise(sheet, noisy) == []


@pytest.mark.slow
def test_the_readme_contact_sheet_is_what_the_demo_draws(tutorial, tmp_path):
    """docs/img/smoke_preview.png (scripts/readme_pictures.sh) against the demo's own preview
    command run on the tutorial's smoke build (the same spec the demo builds)."""
    folder, steps = tutorial
    dataset = folder / "out" / "smoke"
    assert (dataset / "manifest.jsonl").is_file(), "the tutorial's smoke build did not finish"
    out = tmp_path / "smoke-preview.png"
    done = subprocess.run(
        demo_preview_command(dataset, out), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    assert done.returncode == 0, done.stdout
    with Image.open(out) as drawn, Image.open(PREVIEW_COPY) as shipped:
        problems = same_picture_but_noise(np.asarray(drawn.convert("RGB")), np.asarray(shipped.convert("RGB")))
    assert not problems, (
        "docs/img/smoke_preview.png is not what `make demo` draws (run scripts/readme_pictures.sh): "
        + "; ".join(problems)
    )
