"""`shaderball bench`: the spec it derives, its bad input, and small real runs of both benchmarks."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from support import VARIANT

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
PAPER = REPO / "manifests" / "paper.toml"


def _cli(*args):
    from cli import main

    return CliRunner().invoke(main, [str(a) for a in args])


def test_derive_spec_cuts_whole_materials_and_resizes():
    from pipeline.bench.build_bench import derive_spec
    from pipeline.dataset.spec_file import parse_spec

    paper = parse_spec(PAPER)
    cut = derive_spec(paper, renders=12, resolution=200, spp=32)
    assert (cut.dataset.materials, cut.dataset.lights_per_material) == (3, 5)  # ceil(12 / 5) materials
    assert (cut.render.resolution, cut.render.spp) == (200, 32)
    assert cut.dataset.seed == paper.dataset.seed and cut.lighting == paper.lighting
    few = derive_spec(paper, renders=3)
    assert (few.dataset.materials, few.dataset.lights_per_material) == (1, 3)
    assert derive_spec(paper) == paper


@pytest.mark.parametrize(
    "args, message",
    [
        (["--renders", "0"], "--renders: 0 is not allowed; an integer from 1 to 1000000"),
        (["--spp", "0"], "--spp: 0 is not allowed"),
        (["--resolution", "9"], "--resolution: 9 is not allowed; an integer from 16 to 4096"),
        (["--workers", "-1"], "--workers: -1 is not allowed"),
        (["--shard-size", "0"], "--shard-size: 0 is not allowed; an integer from 1 to 1000000"),
        (["--repeats", "3"], "--repeats: not an option of the build benchmark; it takes SPEC, --renders"),
        (["--effects"], "SPEC: not an option of the effects benchmark; it takes --effects, --resolution"),
        (["--scale", "10,20", "--out", "x", "--profile"], "--profile: not an option of the scale benchmark"),
        (["--effects", "--repeats", "0"], "--repeats: 0 is not allowed; an integer from 1 to 100"),
    ],
)
def test_bench_bad_options_exit_2(args, message, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = _cli("bench", SMOKE, *args)
    assert result.exit_code == 2 and message in result.output, result.output
    assert not list(tmp_path.iterdir()), "nothing is written"


def test_bench_runs_one_benchmark_at_a_time():
    result = _cli("bench", "--effects", "--scale", "10,20", "--out", "x")
    assert result.exit_code == 2 and "--scale: not allowed with --effects" in result.output, result.output


def test_bench_settings_are_the_renderers_declarations_and_each_benchmarks_own_defaults():
    """spp and resolution are RenderSettings' fields (one rule, one range); unset, each
    benchmark renders at its own: the spec's, the effects benchmark's, the scale benchmark's."""
    from pipeline.bench.command import BenchRequest
    from pipeline.fields import declared
    from pipeline.render.settings import RenderSettings

    for name in ("spp", "resolution"):
        mine, theirs = declared(BenchRequest)[name].metadata["rule"], declared(RenderSettings)[name].metadata["rule"]
        assert mine.rule is theirs  # the same declaration, optional here
    assert BenchRequest(spec=str(SMOKE)).settings() == (None, None)
    assert BenchRequest(effects=True).settings() == (128, 64)
    assert BenchRequest(scale=(10, 20), out="x").settings() == (16, 1)
    assert BenchRequest(effects=True, spp=8).settings() == (128, 8)


def test_bench_needs_a_spec_or_effects(tmp_path):
    result = _cli("bench")
    assert result.exit_code == 2 and "SPEC: missing" in result.output
    result = _cli("bench", tmp_path / "nope.toml")
    assert result.exit_code == 2 and "nope.toml" in result.output


def test_bench_refuses_a_non_empty_out(tmp_path):
    (tmp_path / "something").write_text("x")
    result = _cli("bench", SMOKE, "--out", tmp_path)
    assert result.exit_code == 2 and "a new or empty folder" in result.output
    assert [p.name for p in tmp_path.iterdir()] == ["something"]


@pytest.mark.slow
def test_build_bench_renders_the_same_images_as_the_build(tmp_path):
    from pipeline.bench.build_bench import run_build_bench
    from pipeline.bench.command import BenchRequest

    bench = run_build_bench(BenchRequest(spec=str(SMOKE), out=str(tmp_path / "ds"), renders=4, workers=0))
    assert bench.samples == 4 and len(bench.timings) == 4
    assert all(t.identical for t in bench.timings)  # the bare renders are the build's samples
    assert bench.build_s > 0 and bench.bare_s > 0 and bench.ratio == bench.build_s / bench.bare_s
    text = "\n".join(bench.lines())
    assert "wall ratio build / bare" in text and "CPU ratio build / bare" in text and "4/4" in text
    assert bench.build_compiled == 0  # warmed kernels, one scene per material moved between lights
    assert bench.records_render_s > 0 and bench.processes == 1 and "same run, from the records" in text
    # the build's own split, per phase (2 materials x 2 lightings: a scene load, a material
    # moved in, two emitter moves)
    from pipeline.bench.bare_renders import BUILD_PHASES

    phases = bench.in_build_phases
    assert list(phases) == list(BUILD_PHASES) and phases["render calls"] == bench.in_build_render_s
    moved = ("render calls", "scene loads", "material moves", "emitter moves", "statistics", "writer thread")
    assert all(phases[p] > 0 for p in moved)
    assert sum(v for p, v in phases.items() if p != "writer thread") < bench.build_s
    assert bench.render_call_ratio == bench.in_build_render_s / bench.bare_s
    assert bench.outside_per_render_s == pytest.approx((bench.build_s - bench.startup_s - phases["render calls"]) / 4)
    assert "render calls inside the build over bare renders of the same scenes" in text
    assert "outside the render calls, per render:" in text and "on the writer thread" in text
    cpu = bench.in_build_phases_cpu
    assert list(cpu) == list(BUILD_PHASES) and cpu["writer thread"] > 0 and cpu["scene loads"] > 0
    assert "the same phases in CPU time of their thread" in text
    main = bench.main_thread_outside_cpu_s  # the main thread's CPU outside render calls: the phases and more
    assert main == bench.in_build_main_cpu_s - cpu["render calls"]
    assert main >= sum(cpu[p] for p in ("material moves", "emitter moves", "statistics"))
    assert "the main thread outside its render calls" in text
    estimate = bench.paper_estimate()
    assert estimate["scaled_by"] == (400 * 400 * 150) / (64 * 64 * 16)
    assert estimate["hours_bare"] == pytest.approx(bench.bare_s / 4 * estimate["scaled_by"] * 50_000 / 3600)
    assert "paper scale: run at 400x400, 150 spp for the estimate" in text
    assert (tmp_path / "ds" / "manifest.jsonl").is_file()  # --out keeps the dataset


@pytest.mark.slow
def test_effects_bench_reports_every_omission(tmp_path):
    import json

    from pipeline.bench.command import BenchRequest, run_bench

    bench = run_bench(BenchRequest(effects=True, resolution=64, spp=4, repeats=1, json_out=str(tmp_path / "e.json")))
    cases = {c.omission: c for c in bench.cases}
    assert set(cases) == {
        "textured -> constant",
        "normal map -> none",
        "both -> constant, none",
        "diffuse lobe -> none",
        "specular lobe -> none",
    }
    for case in bench.cases:
        c = case.comparison
        if case.applied:
            assert c["identical"] or c["rounding"], (case.omission, c)
        else:
            assert not c["identical"] and not c["rounding"], (case.omission, c)
    assert cases["diffuse lobe -> none"].comparison["identical"]
    saved = json.loads((tmp_path / "e.json").read_text())
    assert len(saved["cases"]) == 5 and "saved_cpu" in saved["cases"][0]


def test_a_scene_moved_to_a_light_renders_the_bytes_of_a_scene_loaded_for_it(mi):
    """What lets a build move a loaded scene between lightings (pipeline.render.renderer.MaterialScene).

    Mitsuba's sunsky normalises a dict's ``sun_direction`` in float32 when it loads, and
    for some directions that differs by an ulp from the rounded vector (shown below), so an
    update writing the rounded vector renders a few ulps away from a fresh load. The update
    writes the loader's own vector (pipeline.render.emitter.loaded_sun_direction): a scene
    loaded for the first light and moved to each next one renders the bytes of a scene
    loaded for that light, with no kernel compiled for the moves.
    """
    import numpy as np

    from geometry import build_shaderball, default_camera
    from materials.maps import UniformMaterial
    from pipeline.dataset.plan import plan_dataset
    from pipeline.dataset.spec_file import parse_spec
    from pipeline.render.emitter import emitter_dicts, loaded_sun_direction
    from pipeline.render.kernels import KernelCounter
    from pipeline.render.renderer import MaterialScene, RenderSettings, scene_dict
    from sky import Light

    lights = [
        Light(s.elevation_deg, s.azimuth_deg, s.turbidity)
        for shard in plan_dataset(parse_spec(SMOKE))
        for m in shard.materials
        for s in m.samples
    ]
    off_by_rounding = 0
    for light in lights:
        entries, _ = emitter_dicts(light, variant=VARIANT)
        loaded = np.asarray(mi.traverse(mi.load_dict({"type": "scene", **entries}))["sky.sun_direction"])
        rounded = np.asarray(mi.Vector3f(*entries["sky"]["sun_direction"]))
        off_by_rounding += not np.array_equal(loaded, rounded)
        assert np.array_equal(loaded, np.asarray(loaded_sun_direction(light.direction, VARIANT)))
    assert off_by_rounding > 0

    ball, camera = build_shaderball(), default_camera()
    settings = RenderSettings(resolution=32, spp=4, variant=VARIANT)
    maps = UniformMaterial((0.5, 0.3, 0.2), (0.04,) * 3, 0.3).to_maps(1)

    def render(scene, seed):
        return np.asarray(mi.render(scene, spp=4, seed=seed))

    fresh = []
    for i, light in enumerate(lights):
        scene = mi.load_dict(scene_dict(ball, camera, maps, light, settings)[0])
        fresh.append(render(scene, 100 + i))
        del scene
    kernels = KernelCounter()
    with MaterialScene() as held, kernels:
        for i, light in enumerate(lights):
            scene, lighting, _ = held.lit(mi, ball, camera, maps, light, settings)
            assert lighting == emitter_dicts(light, variant=VARIANT)[1]
            assert np.array_equal(fresh[i], render(scene, 100 + i)), i
    assert kernels.compiled == 0


def test_pass_plan_follows_the_variants_guarantee():
    """Power-of-two passes where they make re-renders byte-identical (llvm), one pass where
    re-renders are not byte-identical anyway (cuda: the passes would only cost launches)."""
    from pipeline.render.mitsuba_env import BYTE_IDENTICAL, WITHIN_NOISE, determinism
    from pipeline.render.renderer import pass_plan

    assert determinism("llvm_ad_rgb") == BYTE_IDENTICAL and determinism("cuda_ad_rgb") == WITHIN_NOISE
    assert pass_plan(150, "llvm_ad_rgb") == [128, 16, 4, 2]
    assert pass_plan(150, "cuda_ad_rgb") == [150]
    assert pass_plan(16, "llvm_ad_rgb") == pass_plan(16, "cuda_ad_rgb") == [16]


def test_a_single_pass_is_the_pass_the_power_of_two_plan_renders_for_a_power_of_two(mi):
    """render_in_passes' one-pass shortcut returns the same values as the weighted average it skips."""
    import numpy as np

    from geometry import build_shaderball, default_camera
    from materials.maps import UniformMaterial
    from pipeline.render.renderer import RenderSettings, pass_seed, render_in_passes, scene_dict
    from sky import Light

    settings = RenderSettings(resolution=32, spp=8, variant=VARIANT)
    maps = UniformMaterial((0.5, 0.3, 0.2), (0.04,) * 3, 0.4).to_maps(1)
    scene = mi.load_dict(scene_dict(build_shaderball(), default_camera(), maps, Light(35.0, 300.0, 3.0), settings)[0])
    one = render_in_passes(mi, scene, 8, 5, [8])
    raw = np.asarray(mi.render(scene, spp=8, seed=pass_seed(5, 0)), dtype=np.float64)
    assert np.array_equal(one, raw * 8 / 8) and np.array_equal(one, render_in_passes(mi, scene, 8, 5))


def test_power_of_two_passes():
    from pipeline.render.renderer import power_of_two_passes

    assert power_of_two_passes(150) == [128, 16, 4, 2]
    assert power_of_two_passes(16) == [16] and power_of_two_passes(1) == [1]
    assert all(sum(power_of_two_passes(n)) == n for n in range(1, 300))


def test_power_of_two_passes_render_identically_across_repeats_and_thread_counts(mi):
    """Evidence for docs/build.md, "Determinism": a 150 spp render in one pass
    is not bit-reproducible with 2 render threads (a pixel's samples straddle drjit's work
    blocks), the same samples in power-of-two passes are, whatever the thread count."""
    import drjit as dr
    import numpy as np

    from geometry import build_shaderball, default_camera
    from materials.maps import UniformMaterial
    from pipeline.render.renderer import RenderSettings, render_in_passes, scene_dict
    from sky import Light

    settings = RenderSettings(resolution=64, spp=150, variant=VARIANT)
    maps = UniformMaterial((0.5, 0.3, 0.2), (0.04,) * 3, 0.4).to_maps(1)
    scene = mi.load_dict(scene_dict(build_shaderball(), default_camera(), maps, Light(35.0, 300.0, 3.0), settings)[0])
    threads = dr.thread_count()
    try:
        dr.set_thread_count(2)
        first = render_in_passes(mi, scene, 150, 5)
        assert np.array_equal(first, render_in_passes(mi, scene, 150, 5))
        dr.set_thread_count(1)
        assert np.array_equal(first, render_in_passes(mi, scene, 150, 5))
    finally:
        dr.set_thread_count(threads)
    assert first.shape == (64, 64, 9) and np.isfinite(first).all()
