"""A render over Mitsuba's launch limit (pipeline.render.limits.LAUNCH_SAMPLES_MAX, resolution^2 x
spp) is split into launches under it, averaged; every render under it makes the calls it always did.

Above 2^32-1 samples Mitsuba splits a render itself: it fails where spp is no multiple of its pass
(4096 px at 65536 spp) and otherwise keeps 24-28 bytes a lane between passes (4096 px at 256 spp:
a segfault under a 6 GiB limit). A render that large takes hours, so the wiring is checked at a
lowered limit with real renders, and at the real limit by the calls the renderer asks Mitsuba for.
"""

from __future__ import annotations

import numpy as np
import pytest

from support import VARIANT

FULL_HD_PIXELS = 4096 * 4096
DRJIT_LANES_MAX = 2**32 - 1  # a launch's lanes are indexed in 32 bits


def test_launches_at_the_boundary():
    from pipeline.render.limits import LAUNCH_SAMPLES_MAX, launch_spp

    assert LAUNCH_SAMPLES_MAX == DRJIT_LANES_MAX
    # exactly at the limit: one call; one sample over it: split, every launch under it
    assert launch_spp(LAUNCH_SAMPLES_MAX, 1) == [LAUNCH_SAMPLES_MAX]
    over = launch_spp(LAUNCH_SAMPLES_MAX + 1, 1)
    assert len(over) > 1 and sum(over) == LAUNCH_SAMPLES_MAX + 1 and max(over) <= LAUNCH_SAMPLES_MAX
    assert launch_spp(255, FULL_HD_PIXELS) == [255]  # 4,278,190,080 samples
    assert launch_spp(256, FULL_HD_PIXELS) == [128, 128]  # 2^32
    assert launch_spp(65536, FULL_HD_PIXELS) == [128] * 512  # Mitsuba: "should be a multiple"
    assert launch_spp(26843, 400 * 400) == [26843]
    assert launch_spp(26844, 400 * 400) == [16384, 10460]
    # the paper's and the smoke spec's passes stay single calls
    assert [launch_spp(n, 400 * 400) for n in (128, 16, 4, 2)] == [[128], [16], [4], [2]]
    assert launch_spp(16, 64 * 64) == [16]


def test_a_sampler_that_rounds_up_is_counted_as_it_renders():
    """stratified takes the next square: 255 asked is 256 rendered, 2^32 at 4096 px: split."""
    from pipeline.render.limits import LAUNCH_SAMPLES_MAX, launch_spp

    def next_square(n):
        r = 1
        while r * r < n:
            r += 1
        return r * r

    split = launch_spp(255, FULL_HD_PIXELS, next_square)
    assert len(split) > 1 and sum(split) == 255
    assert all(FULL_HD_PIXELS * next_square(n) <= LAUNCH_SAMPLES_MAX for n in split)


class _Calls:
    """mi.render, recording the spp and film pixels of each call; ``stop``: refuse to run any
    call (its arguments recorded first), for renders that would take hours."""

    def __init__(self, mi, stop: bool = False):
        self.real, self.stop, self.calls = mi.render, stop, []

    def __call__(self, scene, spp=0, seed=0, **kw):
        width, height = scene.sensors()[0].film().crop_size()
        self.calls.append((int(width) * int(height), int(spp)))
        if self.stop:
            raise _Stopped
        return self.real(scene, spp=spp, seed=seed, **kw)


class _Stopped(Exception):
    pass


def _scene(mi, resolution: int, spp: int):
    from geometry import build_shaderball, default_camera
    from materials import UniformMaterial
    from pipeline.render.renderer import MaterialScene
    from pipeline.render.settings import RenderSettings
    from sky import Light

    settings = RenderSettings(resolution=resolution, spp=spp, variant=VARIANT)
    maps = UniformMaterial((0.5, 0.3, 0.2), (0.04,) * 3, 0.3).to_maps(1)
    held = MaterialScene()
    scene, _, _ = held.lit(mi, build_shaderball(), default_camera(), maps, Light(40.0, 250.0, 3.0), settings)
    return held, scene


def test_a_4096_px_65536_spp_render_asks_mitsuba_for_launches_under_the_limit(mi, monkeypatch):
    """The spec Mitsuba refused with a traceback: the first call the renderer makes is within the
    limit (the call is stopped before it runs: 2^31 samples take many minutes here)."""
    from pipeline.render.renderer import render_scene

    held, scene = _scene(mi, 4096, 65536)
    calls = _Calls(mi, stop=True)
    monkeypatch.setattr(mi, "render", calls)
    with held, pytest.raises(_Stopped):
        render_scene(mi, scene, 65536, seed=7)
    pixels, spp = calls.calls[0]
    assert pixels == FULL_HD_PIXELS and pixels * spp <= DRJIT_LANES_MAX, calls.calls


def test_a_split_render_is_the_weighted_mean_of_its_launches(mi, monkeypatch):
    """At a lowered limit (32 px: 4 spp a launch) a real 32 px, 16 spp render is four launches of 4,
    each seeded from the pass's seed, averaged: the same values as those launches made by hand."""
    import pipeline.render.limits as limits
    from pipeline.render.renderer import pass_seed, render_launch, render_scene

    held, scene = _scene(mi, 32, 16)
    with held:
        whole = _Calls(mi)
        monkeypatch.setattr(mi, "render", whole)
        one = render_scene(mi, scene, 16, seed=5)
        assert whole.calls == [(32 * 32, 16)]  # under the real limit: one call, as always

        monkeypatch.setattr(limits, "LAUNCH_SAMPLES_MAX", 32 * 32 * 4)
        split = _Calls(mi)
        monkeypatch.setattr(mi, "render", split)
        out = render_scene(mi, scene, 16, seed=5)
        assert split.calls == [(32 * 32, 4)] * 4
        monkeypatch.setattr(mi, "render", whole.real)

        seed = pass_seed(5, 0)  # the pass's seed; its launches are keyed by it
        by_hand = sum(np.asarray(render_launch(mi, scene, 4, pass_seed(seed, j)), np.float64) for j in range(4)) / 4
    assert np.array_equal(out.image, np.ascontiguousarray(by_hand[..., 0:3], dtype=np.float32))
    assert out.spp_used == 16 and np.isfinite(out.image).all() and out.image.mean() > 0
    # the same image within noise as the single call: the mean over the frame agrees
    assert abs(float(out.image.mean()) - float(one.image.mean())) < 0.1 * float(one.image.mean())


def test_plan_says_a_render_over_the_limit_is_split(tmp_path):
    from click.testing import CliRunner

    from cli import main

    spec = tmp_path / "big.toml"
    spec.write_text(
        '[dataset]\nname = "big"\nversion = "1"\nseed = 1\nmaterials = 1\nlights_per_material = 1\n'
        'svbrdf_fraction = 0.0\nshard_size = 1\n[render]\nresolution = 4096\nspp = 65536\nvariant = "llvm"\n'
    )
    result = CliRunner().invoke(main, ["plan", str(spec), "--no-timing"])
    assert result.exit_code == 0, result.output
    assert "4096^2 x 65536 samples, more than 2^32-1" in result.output
    assert "launches of at most 128 spp" in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.toml"]
