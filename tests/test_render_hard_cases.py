"""The issue's hard-case lighting sweep through the real pipeline: the shaderball, the project's
own BSDF (diffuse, glossy, near-mirror), the emitter and its policy.

Rejected requests raise an error naming the field; every accepted one renders with no NaN,
Inf or negative pixel, never black, and its record says what the policy did.
"""

import numpy as np
import pytest

from geometry import build_shaderball, default_camera
from materials import UniformMaterial
from pipeline.errors import USER_ERRORS
from pipeline.render.renderer import RenderSettings, render_sample
from sky import Light
from support import VARIANT

ELEVATIONS = (-5, -1e-4, 0, 0.5, 1.9, 2, 3, 10, 45, 89.999, 90)
TURBIDITIES = (0.99, 1, 3, 10, 10.01)
MATERIALS = {
    "diffuse": UniformMaterial((0.8, 0.8, 0.8), (0.0, 0.0, 0.0), 1.0),
    "glossy": UniformMaterial((0.3, 0.1, 0.05), (0.04, 0.04, 0.04), 0.3),
    "near_mirror": UniformMaterial((0.0, 0.0, 0.0), (0.95, 0.95, 0.95), 0.02),
}
SETTINGS = RenderSettings(resolution=24, spp=4, max_depth=6, variant=VARIANT)


@pytest.fixture(scope="module")
def scene_parts():
    return build_shaderball(), default_camera()


@pytest.mark.parametrize("material", list(MATERIALS))
def test_lighting_sweep(scene_parts, material):
    ball, camera = scene_parts
    maps = MATERIALS[material].to_maps(1)
    rendered = rejected = 0
    for elevation in ELEVATIONS:
        for turbidity in TURBIDITIES:
            accepted = 0 <= elevation <= 90 and 1 <= turbidity <= 10
            if not accepted:
                bad_elevation, bad_turbidity = not 0 <= elevation <= 90, not 1 <= turbidity <= 10
                field = (
                    "elevation_deg|turbidity"
                    if bad_elevation and bad_turbidity
                    else ("elevation_deg" if bad_elevation else "turbidity")
                )
                with pytest.raises(USER_ERRORS, match=f"({field}).*allowed"):
                    render_sample(ball, camera, maps, Light(elevation, 30.0, turbidity), SETTINGS, seed=1)
                rejected += 1
                continue
            result = render_sample(ball, camera, maps, Light(elevation, 30.0, turbidity), SETTINGS, seed=1)
            image, stats, record = result.image, result.stats, result.lighting
            case = f"{material} elevation {elevation} turbidity {turbidity}"
            assert np.isfinite(image).all(), case
            assert (image >= 0).all(), case
            assert image.max() > 0, case
            assert stats["nan"] == stats["inf"] == stats["negative"] == 0 and not stats["flagged"], case
            effective = record["effective"]["elevation_deg"]
            assert record["changed"] == (effective != elevation), case
            assert effective >= min(elevation, 90) and effective >= record["elevation_floor_deg"] - 1e-9, case
            rendered += 1
    assert rendered == 9 * 3 and rejected == len(ELEVATIONS) * len(TURBIDITIES) - 27
