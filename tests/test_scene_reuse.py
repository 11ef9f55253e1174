"""One loaded scene moved from material to material (pipeline.render.renderer.MaterialScene)
renders the bytes of a scene loaded afresh for each, with no kernel compiled per material."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from support import VARIANT

SMOKE = Path(__file__).resolve().parents[1] / "manifests" / "smoke.toml"


def _samples():
    """The smoke plan's materials, in plan order, with their maps and lights (3 effect plans:
    uniform with and without a normal map, textured with one)."""
    from pipeline.dataset.materialize import make_material
    from pipeline.dataset.plan import plan_dataset
    from pipeline.dataset.spec_file import parse_spec
    from sky import Light

    spec = parse_spec(SMOKE)
    out = []
    for shard in plan_dataset(spec):
        for material in shard.materials:
            maps, _ = make_material(material, spec)
            lights = [Light(s.elevation_deg, s.azimuth_deg, s.turbidity) for s in material.samples]
            out.append((maps, lights))
    return out


def test_a_scene_moved_to_each_material_renders_the_bytes_of_a_scene_loaded_for_it(mi):
    from geometry import build_shaderball, default_camera
    from pipeline.render.kernels import KernelCounter
    from pipeline.render.renderer import MaterialScene, RenderSettings, plan_effects, scene_dict

    ball, camera = build_shaderball(), default_camera()
    settings = RenderSettings(resolution=32, spp=4, variant=VARIANT)
    samples = _samples()
    plans = [plan_effects(maps).key() for maps, _ in samples]
    # the held scene meets a change of effect plan both ways, not only one plan
    assert len(set(plans)) >= 2 and any(a != b for a, b in zip(plans, plans[1:]))

    def render(scene, seed):
        return np.asarray(mi.render(scene, spp=4, seed=seed))

    fresh, records = [], []
    for m, (maps, lights) in enumerate(samples):
        for i, light in enumerate(lights):
            desc, lighting, effects = scene_dict(ball, camera, maps, light, settings)
            scene = mi.load_dict(desc)
            fresh.append(render(scene, 100 * m + i))
            records.append((lighting, effects))
            del scene, desc  # one scene alive at a time
    for round_ in range(2):
        steps, moved = [], []
        kernels = KernelCounter()
        with MaterialScene() as held, kernels:
            for m, (maps, lights) in enumerate(samples):
                for i, light in enumerate(lights):
                    steps.append(held.step(ball, camera, maps, settings))
                    scene, lighting, effects = held.lit(mi, ball, camera, maps, light, settings)
                    moved.append(render(scene, 100 * m + i))
                    assert (lighting, effects) == records[len(moved) - 1]
                    del scene
        assert steps.count("load") == 1 and steps.count("material") == len(samples) - 1
        assert steps.count("light") == len(fresh) - len(samples)
        same = [np.array_equal(a, b) for a, b in zip(fresh, moved)]
        assert all(same), f"round {round_}: renders {[k for k, ok in enumerate(same) if not ok]} differ"
    # the second round met every scene the first one did: nothing compiled per material
    assert kernels.compiled == 0


def test_a_held_scene_is_loaded_again_for_other_settings_or_geometry(mi):
    from geometry import build_shaderball, default_camera
    from pipeline.render.renderer import MaterialScene, RenderSettings

    ball, camera = build_shaderball(), default_camera()
    settings = RenderSettings(resolution=32, spp=4, variant=VARIANT)
    (maps, lights), (other, _) = _samples()[:2]
    with MaterialScene() as held:
        assert held.step(ball, camera, maps, settings) == "load"
        first, _, _ = held.lit(mi, ball, camera, maps, lights[0], settings)
        assert held.step(ball, camera, maps, settings) == "light"
        assert held.step(ball, camera, other, settings) == "material"
        bigger = RenderSettings(resolution=48, spp=4, variant=VARIANT)
        assert held.step(ball, camera, maps, bigger) == "load"
        assert held.step(ball, default_camera(), maps, settings) == "load"
        scene, _, _ = held.lit(mi, ball, camera, maps, lights[0], bigger)
        assert scene is not first and np.asarray(mi.render(scene, spp=1)).shape[:2] == (48, 48)
        del first, scene
    assert held.scene is None and held.step(ball, camera, maps, settings) == "load"
