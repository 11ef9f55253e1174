"""Decompression bombs: EXR files and images whose headers promise far more pixels than the
file holds bytes. Every reader checks the header against what it expects (the spec's
resolution, the role's channels; a map's largest size) and refuses before decoding, so each
command's peak memory on a bomb stays within its peak on good data plus a few megabytes.
Also: preview of a render whose size is not its maps', and the Hub contact-sheet script on
previews of the wrong size or that do not decode."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.publish.writer import write_publication
from pipeline.store.exr import encode_exr, read_exr
from pipeline.store.exrheader import ExrBounds
from support.bombs import exr_bomb, peak_of, png_bomb
from support.publishing import rerecord
from support.scripts import script_module

pytestmark = pytest.mark.slow  # a smoke build (once per session), commands in their own processes

REPO = Path(__file__).resolve().parents[1]
#: How much a command's peak may exceed its peak on good data: run-to-run noise of a Python
#: process's peak (a few MB here) and the decoders' floor (1 MB per file, four threads). Each
#: bomb would decode to 100 MB or more.
MARGIN_MB = 24
#: A render of the smoke spec's 64 x 64 pixels, as a 2048 x 2048 file of six float channels:
#: 106 kB on disk, 100 MB decoded (twice that once its layers are stacked).
RENDER_BOMB = {"render": ("R", "G", "B"), "extra": ("R", "G", "B")}
TRAIN = ["--loss", "l1", "--resolution", "32", "--batch-size", "4", "--lr", "1e-3", "--seed", "3", "--epochs", "1"]


def renders(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() for p in root.glob("shards/*/*.render.exr"))


@pytest.fixture(scope="module")
def bombed(reference, tmp_path_factory) -> Path:
    """The smoke dataset with every render a bomb, every record and checksum agreeing."""
    root = tmp_path_factory.mktemp("bombs") / "ds"
    shutil.copytree(reference, root)
    bomb = exr_bomb(2048, 2048, RENDER_BOMB)
    assert len(bomb) < 200_000
    for rel in renders(root):
        rerecord(root, rel, bomb)
    return root


@pytest.fixture(scope="module")
def shrunk(reference, tmp_path_factory) -> Path:
    """The smoke dataset with every render at 32 x 32 beside its 64 x 64 maps (records agree):
    refused by the same readers for the same reason, after a read of 12 kB each."""
    root = tmp_path_factory.mktemp("bombs") / "shrunk"
    shutil.copytree(reference, root)
    for rel in renders(root):
        image = read_exr((root / rel).read_bytes())
        small = {name: np.ascontiguousarray(array[::2, ::2]) for name, array in image.layers.items()}
        rerecord(root, rel, encode_exr(small, image.meta))
    return root


@pytest.fixture(scope="module")
def good_pub(reference, tmp_path_factory) -> Path:
    pub = tmp_path_factory.mktemp("bombs") / "good-pub"
    write_publication(str(reference), str(pub), contact_sheet=False)
    return pub


@pytest.fixture(scope="module")
def bombed_pub(bombed, tmp_path_factory) -> Path:
    """A consistent publication of the bombed folder: every checksum agrees."""
    pub = tmp_path_factory.mktemp("bombs") / "pub"
    write_publication(str(bombed), str(pub), contact_sheet=False)
    return pub


@pytest.fixture(scope="module")
def trained(reference, tmp_path_factory) -> Path:
    """A run trained one epoch on the good folder."""
    base = tmp_path_factory.mktemp("bombs")
    done, _peak = peak_of(["train", reference, "--out", base / "run", *TRAIN], base / "peak.txt", REPO)
    assert done.returncode == 0, done.stderr[-2000:]
    return base / "run"


def test_the_bomb_is_a_valid_exr_that_decodes_to_its_header_size():
    bomb = exr_bomb(256, 256, RENDER_BOMB)
    image = read_exr(bomb, "bomb", ExrBounds())  # nothing expected of it: within the budget
    assert image.layers["render"].shape == (256, 256, 3) and image.layers["extra"].shape == (256, 256, 3)


@pytest.mark.parametrize(
    "command, code, words",
    [
        ("validate", 1, "decoded for a file expected to hold 64 x 64 pixels of 3 channel(s)"),
        ("preview", 1, "expected 64 x 64 (the spec's resolution)"),  # the sheet written, the file listed
        ("publish", 1, "does not pass `shaderball validate`"),
    ],
)
def test_an_exr_bomb_in_a_folder_is_refused_from_its_header(reference, bombed, tmp_path, command, code, words):
    def args(root: Path, name: str) -> list:
        if command == "validate":
            return ["validate", root]
        if command == "preview":
            return ["preview", root, "--out", tmp_path / f"{name}.png"]
        return ["publish", root, "--out", tmp_path / name]

    good, baseline = peak_of(args(reference, "good"), tmp_path / "base.txt", REPO)
    assert good.returncode == 0, good.stderr[-2000:]
    done, peak = peak_of(args(bombed, "bomb"), tmp_path / "peak.txt", REPO)
    assert done.returncode == code, done.stderr[-2000:]
    assert "Traceback" not in done.stderr and words in done.stdout + done.stderr, (done.stdout, done.stderr)
    assert renders(bombed)[0] in done.stdout + done.stderr  # the file is named
    assert peak < baseline + MARGIN_MB, (command, baseline, peak)


def test_a_publication_holding_an_exr_bomb_is_refused_by_verify_unpack_and_train(good_pub, bombed_pub, tmp_path):
    good, baseline = peak_of(["verify", good_pub], tmp_path / "base.txt", REPO)
    assert good.returncode == 0, good.stderr[-2000:]
    for args in (["verify", bombed_pub], ["unpack", bombed_pub, "--out", tmp_path / "out"]):
        done, peak = peak_of(args, tmp_path / "peak.txt", REPO)
        assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
        message = done.stdout + done.stderr
        assert "m000000_l0.render.exr" in message and "are decoded for a file expected to hold 64 x 64" in message
        assert peak < baseline + MARGIN_MB, (args[0], baseline, peak)
    assert not (tmp_path / "out").exists()


def test_train_and_evaluate_refuse_an_exr_bomb_naming_the_file(trained, shrunk, bombed, bombed_pub, tmp_path):
    """Each command's peak on the bombs is compared with its peak when it refuses 32 x 32
    renders for their size (the same path, after small reads; training on good data costs
    more than either)."""
    shrunk_pub = tmp_path / "shrunk-pub"
    write_publication(str(shrunk), str(shrunk_pub), contact_sheet=False)
    for command, small, bomb in (
        ("train", shrunk, bombed),
        ("train", shrunk_pub, bombed_pub),
        ("evaluate", shrunk, bombed),
    ):
        args = {
            "train": lambda data, name: ["train", data, "--out", tmp_path / name, *TRAIN],
            "evaluate": lambda data, name: [
                *("evaluate", trained, data, "--split", "all", "--spp", "none", "--limit", "1"),
                *("--out", tmp_path / name),
            ],
        }[command]
        cheap, baseline = peak_of(args(small, "small"), tmp_path / "base.txt", REPO)
        assert cheap.returncode in (1, 2) and ".render.exr" in cheap.stdout + cheap.stderr, cheap.stderr[-2000:]
        done, peak = peak_of(args(bomb, "bomb"), tmp_path / "peak.txt", REPO)
        message = done.stdout + done.stderr
        assert done.returncode in (1, 2) and "Traceback" not in done.stderr, message[-2000:]
        assert "m000000_l0.render.exr" in message and "EXR header says" in message, message[-2000:]
        assert peak < baseline + MARGIN_MB, (command, bomb.name, baseline, peak)


def test_preview_of_renders_smaller_than_their_maps_names_the_files(shrunk, tmp_path):
    """32 x 32 renders beside 64 x 64 maps: a problem line each and "unreadable" tiles."""
    done, _peak = peak_of(["preview", shrunk, "--out", tmp_path / "p.png"], tmp_path / "n.txt", REPO)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
    rel = renders(shrunk)[0]
    assert f"{rel}: EXR header says its data window is 32 x 32 pixels; expected 64 x 64" in done.stdout
    assert (tmp_path / "p.png").stat().st_size > 0


# --------------------------------------------------------------------------- images


def strip(path: Path, width: int, height: int) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png_bomb(width, height))
    return path


def maps_folder(folder: Path, diffuse: tuple[int, int]) -> Path:
    folder.mkdir(parents=True)
    for name in ("specular", "roughness", "normal"):
        (folder / f"{name}.png").write_bytes(png_bomb(16, 16, "RGB"))
    (folder / "diffuse.png").write_bytes(png_bomb(*diffuse, "RGB"))
    return folder


@pytest.mark.parametrize(
    "make, words",
    [
        # under Pillow's own limit, over a map's 2048 x 2048: 4000 x 4000 x 3 float64 was 384 MB
        (lambda d: maps_folder(d / "maps", (4000, 4000)), "the image is 4000 x 4000 pixels; at most 2048 x 2048"),
        # over twice Pillow's limit: its DecompressionBombError
        (lambda d: strip(d / "strip.png", 15000, 12000), "refused by Pillow's pixel limit"),
    ],
    ids=["over-a-map", "over-pillow"],
)
def test_render_svbrdf_refuses_an_image_bomb_from_its_header(tmp_path, make, words):
    path = make(tmp_path)
    assert sum(p.stat().st_size for p in ([path] if path.is_file() else path.iterdir())) < 400_000
    out = tmp_path / "ball.exr"
    cheap, baseline = peak_of(
        ["render", "--svbrdf", strip(tmp_path / "small" / "s.png", 64, 16), "--out", out], tmp_path / "b.txt", REPO
    )
    assert cheap.returncode == 2 and "not a multiple of 5" in cheap.stderr  # refused after reading 1 kB
    done, peak = peak_of(["render", "--svbrdf", path, "--out", out], tmp_path / "p.txt", REPO)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert words in done.stderr and str(path.name) in done.stderr, done.stderr
    assert peak < baseline + MARGIN_MB, (baseline, peak)
    assert not out.exists()


def test_a_build_refuses_an_image_bomb_in_svbrdf_folders_before_writing(tmp_path):
    folder = tmp_path / "svbrdf"
    strip(folder / "bomb.png", 15000, 12000)
    spec = (REPO / "manifests" / "smoke.toml").read_text()
    spec = spec.replace("svbrdf_folders = []", f"svbrdf_folders = [{json.dumps(str(folder))}]")
    assert str(folder) in spec
    (tmp_path / "spec.toml").write_text(spec)
    done, _peak = peak_of(["build", tmp_path / "spec.toml", "--out", tmp_path / "ds"], tmp_path / "p.txt", REPO)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert "bomb.png" in done.stderr and "refused by Pillow's pixel limit" in done.stderr
    assert not (tmp_path / "ds").exists()


def test_the_hub_contact_sheet_draws_wrong_previews_as_grey_tiles(good_pub, tmp_path):
    """Previews verify accepts (a PNG header within the caps) that are 4096 x 4096, or whose
    pixels do not decode: grey tiles and a line each, and the sheet keeps the publication's
    preview size (an unbounded read sized the sheet from the first preview: 5.8 GB)."""
    hub = script_module("hub_contact_sheet")
    rows, strips, side = hub.previews(str(good_pub))
    assert side == 64
    rows = rows[:3]
    rows[0] = {**rows[0], "png": png_bomb(4096, 4096, "RGB")}
    rows[1] = {**rows[1], "png": rows[1]["png"][:60]}  # cut inside its pixel data
    problems: list[str] = []
    picture = hub.sheet_of(rows, strips, side, problems)
    assert picture.size[1] == hub.HEADER + 3 * (side + hub.ROW_GAP)
    assert any(f"{rows[0]['key']}.render.png: the image is 4096 x 4096 pixels; at most 64 x 64" in p for p in problems)
    assert any(f"{rows[1]['key']}.render.png: cannot read image" in p for p in problems), problems
    assert len(problems) == 2
