"""The Mitsuba plugin ``shaderball_ct`` against the numpy reference, and its sampling.

Per-lane material parameters are fed through N x 1 ``bitmap`` textures with
nearest filtering, each lane looking up its own texel, so one kernel tests a
whole sweep.
"""

import itertools

import numpy as np
import pytest

from materials import UniformMaterial, brdf_ref, sample_svbrdf
from materials.brdf_ref import MODELS
from materials.errors import MaterialError
from pipeline.render import bsdf as mitsuba_bsdf
from support import VARIANT
from support.material_cases import (
    HARD_NORMALS,
    HARD_ROUGHNESS,
    Z,
    bsdf_chi2,
    deschaintre_code_brdf,
    floor_cases,
    hard_directions,
)


@pytest.fixture(scope="module")
def mi(mi):
    mitsuba_bsdf.register(variant=VARIANT)
    return mi


@pytest.fixture(scope="module")
def dr(mi):
    import drjit

    return drjit


def _bitmap(mi, values):
    values = np.asarray(values, dtype=np.float32)
    count = values.shape[0]
    array = np.ascontiguousarray(values.reshape(1, count, -1))
    return {"type": "bitmap", "bitmap": mi.Bitmap(array), "raw": True, "filter_type": "nearest"}


def _lanes(mi, dr, d, s, r, wi, **extra):
    """A plugin whose lane k has parameters (d[k], s[k], r[k]), and a SurfaceInteraction for wi."""
    count = len(r)
    bsdf = mi.load_dict(
        {
            "type": "shaderball_ct",
            "diffuse": _bitmap(mi, d),
            "specular": _bitmap(mi, s),
            "roughness": _bitmap(mi, np.asarray(r)[:, None]),
            **extra,
        }
    )
    si = dr.zeros(mi.SurfaceInteraction3f, count)
    si.uv = mi.Point2f(mi.Float((np.arange(count) + 0.5) / count), mi.Float(np.full(count, 0.5)))
    si.wi = mi.Vector3f(np.asarray(wi, dtype=np.float32).T)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    return bsdf, si


def _vec(mi, v):
    return mi.Vector3f(np.asarray(v, dtype=np.float32).T)


def _np3(x):
    return np.asarray(x.numpy()).T


def _random_dirs(rng, n, upper=True):
    v = rng.normal(size=(n, 3))
    if upper:
        v[:, 2] = np.abs(v[:, 2])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v.astype(np.float32)


def _random_params(rng, n):
    d = rng.uniform(0, 1, (n, 3)).astype(np.float32)
    s = rng.uniform(0, 1, (n, 3)).astype(np.float32)
    r = rng.uniform(0, 1, n).astype(np.float32)
    r[: n // 10] = rng.uniform(0, 0.02, n // 10)  # many near-mirror lanes
    return d, s, r


def _random_lanes(mi, dr, seed, n, **extra):
    """n lanes of random parameters lit from random directions: (rng, d, s, r, wi, bsdf, si),
    ``rng`` seeded with ``seed`` and drawn from in that order, ready for the test's next draws."""
    rng = np.random.default_rng(seed)
    d, s, r = _random_params(rng, n)
    wi = _random_dirs(rng, n)
    return (rng, d, s, r, wi, *_lanes(mi, dr, d, s, r, wi, **extra))


def _sample(mi, bsdf, si, rng, count, ctx=None):
    ctx = ctx or mi.BSDFContext()
    s1 = mi.Float(rng.uniform(size=count).astype(np.float32))
    s2 = mi.Point2f(rng.uniform(size=(2, count)).astype(np.float32))
    return bsdf.sample(ctx, si, s1, s2)


# ---- registration and parameters ---------------------------------------------------------------


def test_register_is_idempotent_and_defaults_load(mi):
    mitsuba_bsdf.register(variant=VARIANT)
    mitsuba_bsdf.register(variant=VARIANT)
    bsdf = mi.load_dict({"type": "shaderball_ct"})
    assert "diffuse_lobe=True" in str(bsdf) and "model=shaderball" in str(bsdf)
    assert bsdf.component_count() == 2
    with pytest.raises(Exception, match="at least one lobe"):
        mi.load_dict({"type": "shaderball_ct", "diffuse_lobe": False, "specular_lobe": False})
    assert "model=deschaintre2018" in str(mi.load_dict({"type": "shaderball_ct", "model": "deschaintre2018"}))
    with pytest.raises(Exception, match="model 'walter2007' is not allowed; allowed: shaderball, deschaintre2018"):
        mi.load_dict({"type": "shaderball_ct", "model": "walter2007"})


# ---- eval against the reference ----------------------------------------------------------------


@pytest.mark.parametrize("model", MODELS)
def test_eval_matches_reference_random_sweep(mi, dr, model):
    n = 40000
    rng, d, s, r, wi, bsdf, si = _random_lanes(mi, dr, 1, n, model=model)
    wo = _random_dirs(rng, n)
    value = _np3(bsdf.eval(mi.BSDFContext(), si, _vec(mi, wo)))
    ref = brdf_ref.eval_brdf(wi.astype(np.float64), wo.astype(np.float64), Z, d, s, r, normalize=False, model=model)
    assert np.all(ref > 0)
    np.testing.assert_allclose(value, ref, rtol=1e-4, atol=0)
    pdf = bsdf.pdf(mi.BSDFContext(), si, _vec(mi, wo)).numpy()
    both_value, both_pdf = bsdf.eval_pdf(mi.BSDFContext(), si, _vec(mi, wo))
    np.testing.assert_array_equal(_np3(both_value), value)
    np.testing.assert_array_equal(both_pdf.numpy(), pdf)


@pytest.mark.parametrize("model, peak", [("shaderball", 1e6), ("deschaintre2018", 1e3)])
def test_eval_matches_reference_at_sampled_directions(mi, dr, model, peak):
    # Sampled directions crowd the specular peaks, where the value is largest (the floored
    # model's peaks are capped: D <= alpha^2 / (pi 1e-6)).
    n = 40000
    rng, d, s, r, wi, bsdf, si = _random_lanes(mi, dr, 2, n, model=model)
    bs, _ = _sample(mi, bsdf, si, rng, n)
    wo = _np3(bs.wo)
    ok = bs.pdf.numpy() > 0
    value = _np3(bsdf.eval(mi.BSDFContext(), si, bs.wo))[ok]
    ref = brdf_ref.eval_brdf(wi.astype(np.float64), wo.astype(np.float64), Z, d, s, r, normalize=False, model=model)[ok]
    assert ok.mean() > 0.9 and ref.max() > peak  # reached the near-mirror peaks
    np.testing.assert_allclose(value, ref, rtol=1e-4, atol=0)


def test_plugin_and_reference_are_their_code_where_the_floors_act(mi, dr):
    """deschaintre2018 in float32 = the reference = a transcription of their code, where the floors act."""
    rng = np.random.default_rng(12)
    wi, wo, r, labels = floor_cases(rng, 20000)
    wi, wo = wi.astype(np.float32), wo.astype(np.float32)
    n = len(r)
    d, s = rng.uniform(0, 1, (n, 3)).astype(np.float32), rng.uniform(0, 1, (n, 3)).astype(np.float32)
    r = r.astype(np.float32)
    wi64, wo64 = wi.astype(np.float64), wo.astype(np.float64)
    theirs = deschaintre_code_brdf(wi64, wo64, Z, d, s, r)
    ref = brdf_ref.eval_brdf(wi64, wo64, Z, d, s, r, model="deschaintre2018")
    np.testing.assert_allclose(ref, theirs, rtol=1e-9)
    values = {}
    for model in MODELS:
        bsdf, si = _lanes(mi, dr, d, s, r, wi, model=model)
        values[model] = _np3(bsdf.eval(mi.BSDFContext(), si, _vec(mi, wo)))
    np.testing.assert_allclose(values["deschaintre2018"], theirs, rtol=1e-4)
    # The default plugin is not their code there: the floors matter in these cases.
    off = np.abs(values["shaderball"] / theirs - 1).max(axis=1)
    for label in ("ggx", "smith"):
        assert np.mean(off[labels == label] > 1e-3) > 0.2, label


# ---- sample / pdf / eval agree ----------------------------------------------------------------


@pytest.mark.parametrize("model", MODELS)
def test_sample_pdf_eval_agree(mi, dr, model):
    n = 40000
    rng, d, s, r, wi, bsdf, si = _random_lanes(mi, dr, 3, n, model=model)
    bs, weight = _sample(mi, bsdf, si, rng, n)
    weight = _np3(weight)
    pdf_s = bs.pdf.numpy()
    value, pdf = bsdf.eval_pdf(mi.BSDFContext(), si, bs.wo)
    value, pdf = _np3(value), pdf.numpy()
    ok = pdf_s > 0
    np.testing.assert_allclose(pdf_s[ok], pdf[ok], rtol=1e-6)
    np.testing.assert_allclose(weight[ok], value[ok] / pdf[ok, None], rtol=1e-5, atol=1e-7)
    assert np.all(weight[~ok] == 0)
    kinds = bs.sampled_type.numpy()
    glossy, diffuse = int(mi.BSDFFlags.GlossyReflection), int(mi.BSDFFlags.DiffuseReflection)
    assert set(np.unique(kinds)) == {glossy, diffuse}
    np.testing.assert_array_equal(bs.sampled_component.numpy(), np.where(kinds == glossy, 0, 1))
    np.testing.assert_allclose(bs.eta.numpy(), 1.0)
    # The lobe weight is per lane: a lane's pdf does not depend on the rest of the batch.
    head = 100
    si_head = dr.zeros(mi.SurfaceInteraction3f, head)
    si_head.uv = mi.Point2f(mi.Float((np.arange(head) + 0.5) / n), mi.Float(np.full(head, 0.5)))
    si_head.wi = _vec(mi, wi[:head])
    pdf_head = bsdf.pdf(mi.BSDFContext(), si_head, _vec(mi, _np3(bs.wo)[:head])).numpy()
    np.testing.assert_allclose(pdf_head, pdf[:head], rtol=1e-6)


def _chi2_cases():
    """(model, roughness, incidence, material): alpha 0.05 to 1 for both models, and for the floored
    model the roughnesses where its floor acts (it samples those with alpha = 0.001^0.5)."""
    for model in MODELS:
        roughness = [float(np.sqrt(alpha)) for alpha in (0.05, 0.125, 0.5, 1.0)]
        if model == "deschaintre2018":
            roughness = [0.05, 0.1, 0.15] + roughness
        for r in roughness:
            for theta in (0, 30, 60, 80, 85):
                for material in ("metal", "mixed"):
                    yield model, r, theta, material


@pytest.mark.parametrize("model, r, theta, material", list(_chi2_cases()))
def test_chi2_sample_matches_pdf(mi, model, r, theta, material):
    d, s = {"metal": (0.0, 1.0), "mixed": (0.5, 0.5)}[material]
    # ires=32: Mitsuba's default 4 x 4 trapezoid per cell misintegrates lobes of alpha <= 0.125
    # near the pole and the horizon, failing Mitsuba's own roughconductor there too; at the
    # floored model's sampling alpha 0.0316 it needs 64 (so does roughconductor at normal incidence).
    sampling_alpha = float(brdf_ref.sampling_alpha(r * r, model))
    ires = 32 if sampling_alpha >= 0.05 else 64
    test = bsdf_chi2(mi.Vector3f, d, s, r, model, theta, ires=ires, seed=int(r * r * 1000) + theta)
    assert test.run(0.01, test_count=40, quiet=True), test.messages


# ---- sample weights ------------------------------------------------------------------------------


def _weight_sweep(mi, dr, d_values, s_values, r_values, theta_deg, per_config=2048, seed=4, model="shaderball"):
    configs = np.array(list(itertools.product(d_values, s_values, r_values, theta_deg)))
    lane = np.repeat(np.arange(len(configs)), per_config)
    c = configs[lane]
    theta = np.radians(c[:, 3])
    wi = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=1)
    bsdf, si = _lanes(mi, dr, np.repeat(c[:, :1], 3, 1), np.repeat(c[:, 1:2], 3, 1), c[:, 2], wi, model=model)
    rng = np.random.default_rng(seed)
    bs, weight = _sample(mi, bsdf, si, rng, len(lane))
    return configs, _np3(weight).reshape(len(configs), per_config, 3), bs


WEIGHT_THETA = (0.0, 30.0, 60.0, 80.0, 85.0, 89.0, 89.9)


@pytest.mark.parametrize("model", MODELS)
def test_sample_weights_finite_non_negative_and_bounded(mi, dr, record_property, model):
    configs, weight, _ = _weight_sweep(
        mi,
        dr,
        (0.0, 0.5, 1.0),
        (0.0, 0.04, 0.5, 1.0),
        HARD_ROUGHNESS + (0.05, 0.1, 0.3, 0.5),
        WEIGHT_THETA,
        model=model,
    )
    assert np.all(np.isfinite(weight)) and np.all(weight >= 0)
    largest = float(weight.max())
    worst = configs[np.argmax(weight.max(axis=(1, 2)))]
    record_property("max_sample_weight", largest)
    record_property("max_sample_weight_config_d_s_r_theta", worst.tolist())
    # The weight tracks the total albedo, which the model lets reach ~2 at grazing incidence
    # (d = 1, s = 0: d (1 - s) + A0 -> 1 + 0.99); see docs/materials.md.
    assert largest < 2.0, worst
    assert worst[0] == 1.0 and worst[1] == 0.0 and worst[3] >= 89.0


@pytest.mark.parametrize("model, bound", [("shaderball", 1.0 + 1e-4), ("deschaintre2018", 1.2)])
def test_vndf_specular_weight_at_most_one_when_f_is_one(mi, dr, model, bound):
    # The floored model samples a GGX lobe wider than its alpha (sampling_alpha) whose shape
    # is close to, not equal to, its flat-topped D: its weights reach 1.17 (r = 0.15, 89.9 deg).
    _, weight, bs = _weight_sweep(
        mi, dr, (0.0,), (1.0,), HARD_ROUGHNESS + (0.05, 0.1, 0.15, 0.2, 0.5), WEIGHT_THETA, model=model
    )
    assert np.all(bs.sampled_type.numpy() == int(mi.BSDFFlags.GlossyReflection))
    assert np.all(weight >= 0) and weight.max() <= bound


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize(
    "r, theta", [(0.05, 0.0), (0.2, 60.0), (0.5, 80.0), (1.0, 30.0), (0.1, 85.0), (0.15, 0.0), (0.1, 60.0)]
)
def test_mean_weight_equals_quadrature_albedo(mi, dr, r, theta, model):
    # White furnace at one point: E[weight] = directional albedo (independent numpy quadrature).
    d, s = np.array([0.0, 0.5, 0.9]), np.array([1.0, 0.3, 0.02])
    n = 1 << 18
    wi = np.tile([np.sin(np.radians(theta)), 0.0, np.cos(np.radians(theta))], (n, 1))
    bsdf, si = _lanes(mi, dr, np.tile(d, (n, 1)), np.tile(s, (n, 1)), np.full(n, r), wi, model=model)
    _, weight = _sample(mi, bsdf, si, np.random.default_rng(5), n)
    weight = _np3(weight)
    expected = brdf_ref.directional_albedo(r, np.cos(np.radians(theta)), d, s, n_theta=2048, n_phi=512, model=model)
    stderr = weight.std(axis=0) / np.sqrt(n)
    np.testing.assert_array_less(np.abs(weight.mean(axis=0) - expected), 5 * stderr + 2e-3)


# ---- reciprocity -------------------------------------------------------------------------------


@pytest.mark.parametrize("model", MODELS)
def test_eval_over_cosine_is_reciprocal(mi, dr, model):
    n = 40000
    rng, d, s, r, wi, bsdf, si = _random_lanes(mi, dr, 6, n, model=model)
    bs, _ = _sample(mi, bsdf, si, rng, n)
    wo = _np3(bs.wo)
    wo[: n // 2] = _random_dirs(rng, n // 2)  # half sampled (peaks), half uniform
    forward = _np3(bsdf.eval(mi.BSDFContext(), si, _vec(mi, wo)))
    _, si_back = _lanes(mi, dr, d, s, r, wo, model=model)
    backward = _np3(bsdf.eval(mi.BSDFContext(), si_back, _vec(mi, wi)))
    ok = (wo[:, 2] > 0) & (forward.min(axis=1) > 0)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(forward[ok] / wo[ok, 2:3], backward[ok] / wi[ok, 2:3], rtol=1e-4)


# ---- hard cases -----------------------------------------------------------------------------------


def _assert_finite_non_negative(*arrays, label=""):
    for a in arrays:
        a = np.asarray(a)
        assert np.all(np.isfinite(a)), label
        assert np.all(a >= 0), label


@pytest.mark.parametrize("model", MODELS)
def test_hard_case_sweep_never_nan_inf_or_negative(mi, dr, model):
    wi, wo = hard_directions()
    configs = list(itertools.product(HARD_ROUGHNESS, (0.0, 1.0), (0.0, 1.0)))
    lane = np.repeat(np.arange(len(configs)), len(wi))
    c = np.array(configs)[lane]
    wi_all, wo_all = np.tile(wi, (len(configs), 1)), np.tile(wo, (len(configs), 1))
    bsdf, si = _lanes(mi, dr, np.repeat(c[:, 2:3], 3, 1), np.repeat(c[:, 1:2], 3, 1), c[:, 0], wi_all, model=model)
    ctx = mi.BSDFContext()
    value, pdf = bsdf.eval_pdf(ctx, si, _vec(mi, wo_all))
    _assert_finite_non_negative(_np3(value), pdf.numpy(), label="eval_pdf")
    _assert_finite_non_negative(_np3(bsdf.eval(ctx, si, _vec(mi, wo_all))), bsdf.pdf(ctx, si, _vec(mi, wo_all)).numpy())
    for u1, u2 in itertools.product((0.0, 0.5, 1 - 2**-24), (0.0, 0.3, 1 - 2**-24)):
        count = len(lane)
        bs, weight = bsdf.sample(ctx, si, mi.Float(np.full(count, u1)), mi.Point2f(np.full((2, count), u2)))
        _assert_finite_non_negative(_np3(weight), bs.pdf.numpy(), label=f"sample {u1} {u2}")
        assert np.all(np.isfinite(_np3(bs.wo)))
        # below-horizon or degenerate wi never scatters
        below = wi_all[:, 2] <= 0
        assert np.all(_np3(weight)[below] == 0) and np.all(bs.pdf.numpy()[below] == 0)


def _normalmap_bsdf(mi, normals, params):
    """normalmap(shaderball_ct) with an N x 1 float bitmap of encoded normals (may exceed [0, 1])."""
    encoded = (np.asarray(normals, dtype=np.float32) + 1.0) * 0.5
    inner = {"type": "shaderball_ct", **params}
    return mi.load_dict(mitsuba_bsdf.normalmap_dict(_bitmap(mi, encoded), inner))


@pytest.mark.parametrize("model", MODELS)
def test_hard_normals_through_normalmap_wrapper(mi, dr, model):
    wi, wo = hard_directions()
    normals = np.repeat(HARD_NORMALS, len(wi), axis=0)
    wi_all, wo_all = np.tile(wi, (len(HARD_NORMALS), 1)), np.tile(wo, (len(HARD_NORMALS), 1))
    count = len(normals)
    ctx = mi.BSDFContext()
    for r, s in itertools.product((0.0, 1e-4, 1.0), (0.0, 1.0)):
        bsdf = _normalmap_bsdf(
            mi,
            normals,
            {
                "diffuse": {"type": "rgb", "value": [1.0] * 3},
                "specular": {"type": "rgb", "value": [s] * 3},
                "roughness": r,
                "model": model,
            },
        )
        si = dr.zeros(mi.SurfaceInteraction3f, count)
        si.uv = mi.Point2f(mi.Float((np.arange(count) + 0.5) / count), mi.Float(np.full(count, 0.5)))
        si.wi = _vec(mi, wi_all)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        si.dp_du = mi.Vector3f(1, 0, 0)
        value, pdf = bsdf.eval_pdf(ctx, si, _vec(mi, wo_all))
        _assert_finite_non_negative(_np3(value), pdf.numpy(), label=f"normalmap eval {r} {s}")
        bs, weight = _sample(mi, bsdf, si, np.random.default_rng(7), count)
        _assert_finite_non_negative(_np3(weight), label=f"normalmap sample {r} {s}")


@pytest.mark.parametrize("model, roughness", [("shaderball", 0.4), ("deschaintre2018", 0.4), ("deschaintre2018", 0.12)])
def test_normalmap_wrapper_follows_the_convention_for_normals_seen_from_below(mi, dr, model, roughness):
    """The plugin under Mitsuba's wrapper is brdf_ref.eval_normal_mapped: the map's normal, mirrored
    where the viewer sees its back; viewers anywhere on the sphere, light anywhere."""
    rng = np.random.default_rng(8)
    n = 20000
    normals = _random_dirs(rng, n)
    normals[:, 2] = np.maximum(normals[:, 2], 0.4)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    wi, wo = _random_dirs(rng, n, upper=False), _random_dirs(rng, n, upper=False)
    wi[: n // 2, 2] = np.abs(wi[: n // 2, 2])  # half the viewers above the surface, as on the ball
    params = {
        "diffuse": {"type": "rgb", "value": [0.3, 0.5, 0.7]},
        "specular": {"type": "rgb", "value": [0.2, 0.1, 0.05]},
        "roughness": roughness,
        "model": model,
    }
    bsdf = _normalmap_bsdf(mi, normals, params)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.uv = mi.Point2f(mi.Float((np.arange(n) + 0.5) / n), mi.Float(np.full(n, 0.5)))
    si.wi = _vec(mi, wi)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.dp_du = mi.Vector3f(1, 0, 0)
    value = _np3(bsdf.eval(mi.BSDFContext(), si, _vec(mi, wo)))
    ref = brdf_ref.eval_normal_mapped(wi, wo, normals, [0.3, 0.5, 0.7], [0.2, 0.1, 0.05], roughness, model=model)
    below = (np.sum(wi * normals, axis=1) < 0) & (wi[:, 2] > 0)  # viewer above the surface, below n
    lit_below = below & (ref[:, 0] > 0)
    assert below.mean() > 0.02 and lit_below.sum() > 100 and np.mean(ref[:, 0] > 0) > 0.1
    # Float32 normal texture and frame: agreement to 1e-3 relative plus a small floor.
    np.testing.assert_allclose(value, ref, rtol=1e-3, atol=1e-6)
    # Without the convention the reference would return 0 where the viewer sees the back of n.
    plain = brdf_ref.eval_brdf(wi, wo, normals, [0.3, 0.5, 0.7], [0.2, 0.1, 0.05], roughness, model=model)
    assert np.all(plain[below] == 0) and np.all(value[lit_below] > 0)


def test_normal_map_frame_on_a_uv_mapped_quad(mi, dr):
    """x of the map along +u, y up the picture: with the picture upright on the quad, world +x and +y."""
    mesh = mi.Mesh("quad", 4, 2, has_vertex_normals=False, has_vertex_texcoords=True)
    params = mi.traverse(mesh)
    corners = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    params["vertex_positions"] = mi.Float(corners.ravel())
    # Row 0 of the picture (v = 0) at the top (+y), column 0 (u = 0) on the left (-x).
    params["vertex_texcoords"] = mi.Float(np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32).ravel())
    params["faces"] = mi.UInt32(np.array([0, 1, 2, 0, 2, 3], np.uint32))
    params.update()
    scene = mi.load_dict({"type": "scene", "quad": mesh})
    si = scene.ray_intersect(mi.Ray3f(mi.Point3f(0.1, 0.2, 1.0), mi.Vector3f(0, 0, -1)))
    ctx = mi.BSDFContext()
    base = {
        "diffuse": {"type": "rgb", "value": [0.0] * 3},
        "specular": {"type": "rgb", "value": [1.0] * 3},
        "roughness": 0.3,
    }
    wo_world = np.array([0.3, -0.4, 0.866])
    wo_world /= np.linalg.norm(wo_world)
    wi_world = np.array([0.0, 0.0, 1.0])
    for tangent_normal in ([0.5, 0.0, 0.866], [0.0, 0.5, 0.866]):
        n = np.array(tangent_normal) / np.linalg.norm(tangent_normal)
        bsdf = mi.load_dict(
            mitsuba_bsdf.normalmap_dict(
                {"type": "rgb", "value": ((n + 1) / 2).tolist()}, {"type": "shaderball_ct", **base}
            )
        )
        value = _np3(bsdf.eval(ctx, si, si.to_local(mi.Vector3f(*map(float, wo_world)))))[0]
        expected = brdf_ref.eval_brdf(wi_world, wo_world, n, 0.0, 1.0, 0.3)  # n read as world x, y, z
        mirrored = brdf_ref.eval_brdf(wi_world, wo_world, n * [-1, -1, 1], 0.0, 1.0, 0.3)
        assert abs(value[0] / expected[0] - 1) < 2e-3, tangent_normal
        assert abs(mirrored[0] / expected[0] - 1) > 0.1  # the test can tell the frames apart


# ---- lobe switches -----------------------------------------------------------------------------------


def test_lobe_switches_leave_out_a_lobe(mi, dr):
    rng = np.random.default_rng(9)
    n = 8000
    d, s, r = _random_params(rng, n)
    wi, wo = _random_dirs(rng, n), _random_dirs(rng, n)
    for lobe, kept, flag in (
        ("diffuse_lobe", "specular", "GlossyReflection"),
        ("specular_lobe", "diffuse", "DiffuseReflection"),
    ):
        bsdf, si = _lanes(mi, dr, d, s, r, wi, **{lobe: False})
        assert bsdf.component_count() == 1
        assert bsdf.flags() & int(getattr(mi.BSDFFlags, flag))
        value = _np3(bsdf.eval(mi.BSDFContext(), si, _vec(mi, wo)))
        ref = brdf_ref.eval_brdf(wi, wo, Z, d, s, r, lobes=(kept,), normalize=False)
        np.testing.assert_allclose(value, ref, rtol=1e-4, atol=1e-30)
        bs, weight = _sample(mi, bsdf, si, rng, n)
        assert np.all(bs.sampled_type.numpy() == int(getattr(mi.BSDFFlags, flag)))
        assert np.all(bs.sampled_component.numpy() == 0)
        _assert_finite_non_negative(_np3(weight))


def test_context_selects_one_component(mi, dr):
    n = 4000
    rng, d, s, r, wi, bsdf, si = _random_lanes(mi, dr, 10, n)
    wo = _random_dirs(rng, n)
    for component, kept in ((0, "specular"), (1, "diffuse")):
        ctx = mi.BSDFContext()
        ctx.component = component
        value = _np3(bsdf.eval(ctx, si, _vec(mi, wo)))
        ref = brdf_ref.eval_brdf(wi, wo, Z, d, s, r, lobes=(kept,), normalize=False)
        np.testing.assert_allclose(value, ref, rtol=1e-4, atol=1e-30)


def test_needed_lobes_keeps_specular_always():
    black = UniformMaterial(diffuse=(0, 0, 0), specular=(0.5,) * 3, roughness=0.3).to_maps(2)
    plastic = UniformMaterial(diffuse=(0.5,) * 3, specular=(0.0,) * 3, roughness=0.3).to_maps(2)
    assert mitsuba_bsdf.needed_lobes(black) == {"diffuse_lobe": False, "specular_lobe": True}
    assert mitsuba_bsdf.needed_lobes(plastic) == {"diffuse_lobe": True, "specular_lobe": True}


# ---- bsdf_dict ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("model", MODELS)
def test_bsdf_dict_uniform_and_spatially_varying(mi, dr, model):
    flat = UniformMaterial(diffuse=(0.2, 0.3, 0.4), specular=(0.04,) * 3, roughness=0.5).to_maps(4)
    desc = mitsuba_bsdf.bsdf_dict(flat, model=model, variant=VARIANT)
    assert desc["type"] == "shaderball_ct" and desc["roughness"] == 0.5 and desc["model"] == model
    mi.load_dict(desc)
    with pytest.raises(MaterialError, match="model: 'floored' is not allowed"):
        mitsuba_bsdf.bsdf_dict(flat, model="floored", variant=VARIANT)
    maps = sample_svbrdf(np.random.default_rng(0), "tiles", 32)
    desc = mitsuba_bsdf.bsdf_dict(maps, filter_type="nearest", model=model, variant=VARIANT)
    assert desc["type"] == "normalmap" and desc["bsdf"]["diffuse"]["type"] == "bitmap"
    assert desc["bsdf"]["model"] == model and desc["flip_invalid_normals"] is True
    bsdf = mi.load_dict(desc)
    # Evaluate at every texel centre and compare with the reference with that texel's maps.
    h, w = maps.resolution
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    count = h * w
    rng = np.random.default_rng(11)
    wi, wo = _random_dirs(rng, count), _random_dirs(rng, count)
    si = dr.zeros(mi.SurfaceInteraction3f, count)
    si.uv = mi.Point2f(mi.Float(((jj + 0.5) / w).ravel()), mi.Float(((ii + 0.5) / h).ravel()))
    si.wi = _vec(mi, wi)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.dp_du = mi.Vector3f(1, 0, 0)
    value = _np3(bsdf.eval(mi.BSDFContext(), si, _vec(mi, wo)))
    ref = brdf_ref.eval_normal_mapped(
        wi,
        wo,
        maps.normal.reshape(-1, 3),
        maps.diffuse.reshape(-1, 3),
        maps.specular.reshape(-1, 3),
        maps.roughness.ravel(),
        model=model,
    )
    np.testing.assert_allclose(value, ref, rtol=2e-3, atol=1e-5)
