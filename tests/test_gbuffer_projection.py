"""The projection through the G-buffer equals Mitsuba's own texture lookup on the ball.

The ball is made an area emitter whose radiance is the texture (a ``bitmap``, bilinear,
repeat, raw) and rendered with one unjittered sample per pixel (pixel centres), a box
filter and emission only (max_depth 1): each pixel is then Mitsuba's lookup at the
surface point the G-buffer recorded. Mitsuba's area emitter is one-sided in the shading
frame, so the few silhouette pixels whose shading normal faces away (``facing_mask``)
render black; they are counted and must stay a tiny share.
"""

import numpy as np
import pytest

from geometry import default_camera
from pipeline.render.gbuffer import facing_mask, load_gbuffer
from pipeline.render.raster import project
from pipeline.render.scene import BALL_SHAPE_ID, bitmap_texture, sensor_dict, shape_dicts
from support import VARIANT


def _mitsuba_lookup(mi, ball, camera, resolution, texture):
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 1},
        **shape_dicts(ball, {"type": "diffuse"}),
        "sensor": sensor_dict(camera, resolution, 1, sampler="stratified-centres", variant=VARIANT),
    }
    scene[BALL_SHAPE_ID]["emitter"] = {"type": "area", "radiance": bitmap_texture(texture, variant=VARIANT)}
    return np.array(mi.render(mi.load_dict(scene), seed=0), dtype=np.float32)


@pytest.mark.parametrize(
    "resolution, texture_shape",
    [(64, (37, 53, 3)), (128, (64, 64, 3)), (128, (29, 41))],
)
def test_projection_equals_mitsuba_lookup(mi, ball, tmp_path, resolution, texture_shape):
    camera = default_camera()
    rng = np.random.default_rng(resolution + len(texture_shape))
    texture = rng.random(texture_shape).astype(np.float32)
    gbuffer = load_gbuffer(ball, camera, resolution, cache_dir=str(tmp_path), variant=VARIANT)

    rendered = _mitsuba_lookup(mi, ball, camera, resolution, texture)
    projected = project(texture, gbuffer)
    if projected.shape[-1] == 1:  # a one-channel bitmap emits grey
        projected = np.repeat(projected, 3, axis=-1)

    facing = facing_mask(gbuffer)
    assert gbuffer.mask.sum() - facing.sum() <= max(2, 0.002 * gbuffer.mask.sum())
    error = np.abs(rendered - projected)
    assert error[facing].max() <= 1e-6
    # Nothing but the ball emits: Mitsuba sees no texture where the mask is empty.
    assert np.all(rendered[~gbuffer.mask] == 0)
    # The texture really varies over the ball, so the comparison has teeth.
    assert projected[facing].std() > 0.1
