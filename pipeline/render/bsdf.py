"""The material model as a Mitsuba BSDF plugin, ``shaderball_ct``.

The model and every stable form or floor are those of :mod:`materials.brdf_ref`
(the numpy reference this plugin is tested against); docs/materials.md lists
them. This module adds what a renderer needs on top of the formulas:

* importance sampling: visible normals of GGX (Dupuy & Benyoub 2023,
  spherical caps) for the specular lobe, cosine-weighted for the diffuse lobe,
  one of them picked per sample with a lobe weight computed from ``wi``;
* ``eval`` (with the cosine), ``pdf``, ``eval_pdf`` and ``sample`` (weight =
  eval / pdf of the mixture) computed by one function, so they agree;
* lobe switches ``diffuse_lobe`` / ``specular_lobe`` that are Python-level
  branches: a lobe that is off is neither sampled nor evaluated, and the
  compiled kernel does not contain it;
* the ``model`` switch, also a Python-level branch: "deschaintre2018" applies
  the two floors of Deschaintre et al.'s code to D and G1 and samples its
  specular lobe with :func:`materials.brdf_ref.sampling_alpha` (the kernel of
  the default model is the one it was before the switch existed).

Dict parameters of ``{"type": "shaderball_ct", ...}``:

=================  ===============  ==============  ======================================
name               type             default         meaning
=================  ===============  ==============  ======================================
``diffuse``        texture or rgb   0.5             linear diffuse albedo ``d``
``specular``       texture or rgb   0.04            linear specular albedo ``s``
``roughness``      texture / float  0.5             roughness ``r`` (alpha = r^2); bitmap: raw
``diffuse_lobe``   bool             true            include the ``d (1 - s) / pi`` lobe
``specular_lobe``  bool             true            include the ``F G D / 4`` lobe
``model``          string           "shaderball"    ``materials.brdf_ref.MODELS``: or
                                                    "deschaintre2018" (their code's floors)
=================  ===============  ==============  ======================================

Normal maps go through Mitsuba's ``normalmap`` BSDF wrapping this one, with
the map encoded by :func:`materials.maps.encode_normal_map` in a ``bitmap``
texture with ``raw: True`` and the settings of :func:`normalmap_dict`;
:func:`bsdf_dict` builds the whole description from
:class:`materials.MaterialMaps`. The wrapper's tangent frame: x along the
shading frame's s (= ``dp/du`` projected), y = n x s, z the shading normal
(checked by the tests on a UV-mapped quad).

Mitsuba is loaded through :func:`pipeline.render.mitsuba_env.load_mitsuba` inside the
functions, never at import time.
"""

from __future__ import annotations

import math

import numpy as np

from materials.brdf_ref import (
    DEFAULT_MODEL,
    DESCHAINTRE_FLOOR,
    DESCHAINTRE_SAMPLING_ALPHA_MIN,
    FRESNEL_C1,
    FRESNEL_C2,
    HALF_VECTOR_MIN_SQUARED,
    MODELS,
    ROUGHNESS_MAX,
    ROUGHNESS_MIN,
    check_model,
)
from materials.maps import MaterialMaps, encode_normal_map
from pipeline.render.mitsuba_env import load_mitsuba, register_plugin

PLUGIN_NAME = "shaderball_ct"
INV_PI = 1.0 / math.pi

_CLASSES: dict[str, type] = {}


def register(variant: str) -> None:
    """Register ``shaderball_ct`` with Mitsuba for ``variant``; calling it again is a no-op."""
    register_plugin(variant, PLUGIN_NAME, "bsdf", lambda mi: plugin_class(variant))


def plugin_class(variant: str) -> type:
    """The ``mi.BSDF`` subclass for ``variant`` (defined once per variant)."""

    mi = load_mitsuba(variant)
    name = mi.variant()
    if name not in _CLASSES:
        _CLASSES[name] = _define_class(mi)
    return _CLASSES[name]


def needed_lobes(maps: MaterialMaps) -> dict[str, bool]:
    """Which lobes a material needs; pass the result as ``diffuse_lobe`` / ``specular_lobe``.

    The diffuse lobe ``d (1 - s) / pi`` is zero, and may be left out, exactly
    when ``d (1 - s) = 0`` in every texel and channel. The specular lobe is
    never zero: Schlick's term ``F = s + (1 - s) 2^(...)`` is at least
    ``2^-12.5`` even for ``s = 0`` and goes to 1 at grazing ``v.h``, so
    dropping it for ``s = 0`` removes up to ~0.6-0.8 of the directional
    albedo of smooth surfaces at grazing view (docs/materials.md). It is
    always kept.
    """
    d = np.maximum(maps.diffuse, 0.0)
    s = np.clip(maps.specular, 0.0, 1.0)
    return {"diffuse_lobe": bool(np.any(d * (1.0 - s) > 0.0)), "specular_lobe": True}


def bsdf_dict(
    maps: MaterialMaps,
    *,
    filter_type: str = "bilinear",
    wrap_mode: str = "repeat",
    lobes: dict[str, bool] | None = None,
    model: str = DEFAULT_MODEL,
    variant: str,
) -> dict:
    """A Mitsuba dict for ``maps`` (call :func:`register` before ``mi.load_dict``).

    Uniform maps become constant ``rgb``/float parameters; otherwise ``bitmap``
    textures with ``raw: True`` (the maps are already linear; roughness and the
    encoded normal are data). A non-flat normal wraps the BSDF in Mitsuba's
    ``normalmap``; a flat one (every texel (0, 0, 1)) leaves it out. ``lobes``
    defaults to :func:`needed_lobes`. ``model`` is one of
    ``materials.brdf_ref.MODELS``. ``variant`` is the Mitsuba variant the
    dict is for (the bitmaps are built with it), the one resolved at the edge.
    """

    mi = load_mitsuba(variant)
    lobes = needed_lobes(maps) if lobes is None else lobes
    bsdf: dict = {"type": PLUGIN_NAME, **lobes, "model": check_model(model)}

    def bitmap(data: np.ndarray) -> dict:
        array = np.array(data, dtype=np.float32, order="C", copy=True)  # writeable: nanobind rejects read-only
        if array.ndim == 2:
            array = array[..., None]
        return {
            "type": "bitmap",
            "bitmap": mi.Bitmap(array),
            "raw": True,
            "filter_type": filter_type,
            "wrap_mode": wrap_mode,
        }

    uniform = maps.uniform_values()
    if uniform is not None:
        bsdf["diffuse"] = {"type": "rgb", "value": [float(c) for c in uniform.diffuse]}
        bsdf["specular"] = {"type": "rgb", "value": [float(c) for c in uniform.specular]}
        bsdf["roughness"] = float(uniform.roughness)
    else:
        bsdf["diffuse"] = bitmap(maps.diffuse)
        bsdf["specular"] = bitmap(maps.specular)
        bsdf["roughness"] = bitmap(maps.roughness)
    flat = bool(np.all(maps.normal[..., 2] == 1.0))
    if flat:
        return bsdf
    return normalmap_dict(bitmap(encode_normal_map(maps.normal)), bsdf)


def normalmap_dict(normal_texture: dict, bsdf: dict) -> dict:
    """Mitsuba's ``normalmap`` around ``bsdf``, with the settings this model is tested with.

    ``use_shadowing_function`` is off: Mitsuba 3.9 multiplies by default by a
    shadow-terminator factor (Estevez et al. 2019) of the perturbed normal and
    ``wo``, which is not part of Deschaintre et al.'s model and breaks
    reciprocity. ``flip_invalid_normals`` stays on (Mitsuba's default): where
    the viewer sees the back of the shading normal (``wi.n <= 0``) Mitsuba
    mirrors the normal's tangential part instead of returning black. That is
    the project's one convention for normal maps seen from below, the one
    :func:`materials.brdf_ref.mapped_normal` implements.
    """
    return {
        "type": "normalmap",
        "normalmap": normal_texture,
        "bsdf": bsdf,
        "use_shadowing_function": False,
        "flip_invalid_normals": True,
    }


def _define_class(mi):
    """The ``mi.BSDF`` subclass for the variant ``mi`` was loaded as: made after ``set_variant``,
    since every ``mi.*`` type is that variant's; its formulas are :class:`_CookTorrance`'s."""
    import drjit as dr

    formulas = _CookTorrance(mi, dr)

    class ShaderballCT(mi.BSDF):
        """Deschaintre et al. 2018's Cook-Torrance model; see the module docstring."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            _read_properties(self, props)
            self.m_components, self.spec_index, self.diff_index = _components(mi, self)
            flags = self.m_components[0]
            for component in self.m_components[1:]:
                flags = flags | component
            self.m_flags = flags

        def _enabled(self, ctx):
            spec = self.specular_on and ctx.is_enabled(mi.BSDFFlags.GlossyReflection, self.spec_index)
            diff = self.diffuse_on and ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, self.diff_index)
            return spec, diff

        # ---- mi.BSDF interface -------------------------------------------------------------

        def eval(self, ctx, si, wo, active=True):
            spec, diff = self._enabled(ctx)
            if not (spec or diff):
                return mi.Color3f(0.0)
            return formulas.eval_pdf(self, spec, diff, si, wo, active)[0]

        def pdf(self, ctx, si, wo, active=True):
            spec, diff = self._enabled(ctx)
            if not (spec or diff):
                return mi.Float(0.0)
            return formulas.eval_pdf(self, spec, diff, si, wo, active)[1]

        def eval_pdf(self, ctx, si, wo, active=True):
            spec, diff = self._enabled(ctx)
            if not (spec or diff):
                return mi.Color3f(0.0), mi.Float(0.0)
            return formulas.eval_pdf(self, spec, diff, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            spec, diff = self._enabled(ctx)
            bs = dr.zeros(mi.BSDFSample3f)
            if not (spec or diff):
                return bs, mi.Color3f(0.0)
            return formulas.sample(self, bs, spec, diff, si, sample1, sample2, active)

        def eval_diffuse_reflectance(self, si, active=True):
            d, s, _ = formulas.params(self, si, active)
            return d * (1.0 - s) if self.diffuse_on else mi.Color3f(0.0)

        def traverse(self, callback):
            callback.put("diffuse", self.diffuse, mi.ParamFlags.Differentiable)
            callback.put("specular", self.specular, mi.ParamFlags.Differentiable)
            callback.put("roughness", self.roughness, mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            return (
                f"ShaderballCT[diffuse={self.diffuse}, specular={self.specular}, "
                f"roughness={self.roughness}, diffuse_lobe={self.diffuse_on}, "
                f"specular_lobe={self.specular_on}, model={self.model}]"
            )

    return ShaderballCT


def _read_properties(plugin, props) -> None:
    """The dict parameters of the module docstring's table, checked, onto ``plugin``."""
    plugin.diffuse = props.get_texture("diffuse", 0.5)
    plugin.specular = props.get_texture("specular", 0.04)
    plugin.roughness = props.get_texture("roughness", 0.5)
    plugin.diffuse_on = bool(props.get("diffuse_lobe", True))
    plugin.specular_on = bool(props.get("specular_lobe", True))
    plugin.model = props.get("model", DEFAULT_MODEL)
    if plugin.model not in MODELS:
        raise ValueError(f"{PLUGIN_NAME}: model {plugin.model!r} is not allowed; allowed: " + ", ".join(MODELS))
    plugin.floored = plugin.model == "deschaintre2018"
    if not (plugin.diffuse_on or plugin.specular_on):
        raise ValueError(f"{PLUGIN_NAME}: diffuse_lobe and specular_lobe are both false; at least one lobe must be on")


def _components(mi, plugin) -> tuple[list, int | None, int | None]:
    """(component flags, index of the specular one, index of the diffuse one): a lobe that is
    off has no component, so Mitsuba never asks for it."""
    varying = mi.BSDFFlags.Empty
    for texture in (plugin.diffuse, plugin.specular, plugin.roughness):
        if texture.is_spatially_varying():
            varying = mi.BSDFFlags.SpatiallyVarying
    components = []
    spec_index = diff_index = None
    if plugin.specular_on:
        spec_index = len(components)
        components.append(mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide | varying)
    if plugin.diffuse_on:
        diff_index = len(components)
        components.append(mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide | varying)
    return components, spec_index, diff_index


class _CookTorrance:
    """The model's formulas on one variant's types (``mi``, ``dr``), for the plugin class of that
    variant. Methods take the plugin for its textures and switches; ``spec`` / ``diff`` say
    which lobes a call includes (Python-level: a lobe left out is not in the kernel)."""

    def __init__(self, mi, dr):
        self.mi, self.dr = mi, dr

    # ---- parameters and lobes --------------------------------------------------------

    def params(self, plugin, si, active):
        """(d, s, alpha) at ``si``: the albedos clamped to the model's range, alpha = r^2."""
        dr = self.dr
        d = dr.maximum(plugin.diffuse.eval(si, active), 0.0)
        s = dr.clip(plugin.specular.eval(si, active), 0.0, 1.0)
        r = dr.clip(plugin.roughness.eval_1(si, active), ROUGHNESS_MIN, ROUGHNESS_MAX)
        return d, s, r * r

    def fresnel(self, s, cos_vh):
        dr = self.dr
        c = dr.clip(cos_vh, 0.0, 1.0)
        return s + (1.0 - s) * dr.exp2((FRESNEL_C1 * c + FRESNEL_C2) * c)

    def sampling_alpha(self, plugin, alpha):
        return self.dr.maximum(alpha, DESCHAINTRE_SAMPLING_ALPHA_MIN) if plugin.floored else alpha

    def half_vector(self, wi, wo):
        """(whether wi + wo is long enough to normalise, h, sin^2 of h's angle to the normal)."""
        dr = self.dr
        h_raw = wi + wo
        len2 = dr.squared_norm(h_raw)
        h_ok = len2 > HALF_VECTOR_MIN_SQUARED
        h = h_raw * dr.rsqrt(dr.maximum(len2, HALF_VECTOR_MIN_SQUARED))
        return h_ok, h, dr.fma(h.x, h.x, h.y * h.y)

    def spec_prob(self, spec, diff, wi, d, s):
        """The probability of sampling the specular lobe."""
        mi, dr = self.mi, self.dr
        if not diff:
            return mi.Float(1.0)
        if not spec:
            return mi.Float(0.0)
        # Lobe weights from wi alone: Fresnel at v.h = cos(theta_i) against d (1 - s).
        f_i = dr.mean(self.fresnel(s, wi.z))
        w_d = dr.mean(d * (1.0 - s))
        return f_i / (f_i + w_d)

    # ---- the specular lobe, per model ------------------------------------------------

    def floored_spec(self, plugin, wi, h, sin2_h, cos_i, cos_o, alpha):
        """Deschaintre et al.'s D G / 4 (both floors) and the visible-normal pdf it is sampled with."""
        dr = self.dr
        a2 = alpha * alpha
        k = 0.5 * alpha
        denom = dr.maximum(dr.fma(a2, h.z * h.z, sin2_h), DESCHAINTRE_FLOOR)
        d_term = a2 / (math.pi * denom * denom)
        g_i = dr.rcp(dr.maximum(dr.fma(cos_i, 1.0 - k, k), DESCHAINTRE_FLOOR))
        cos_g_o = cos_o / dr.maximum(dr.fma(cos_o, 1.0 - k, k), DESCHAINTRE_FLOOR)
        alpha_s = self.sampling_alpha(plugin, alpha)
        a2_s = alpha_s * alpha_s
        denom_s = dr.fma(a2_s, h.z * h.z, sin2_h)
        d_sample = a2_s / (math.pi * denom_s * denom_s)
        sin2_i = dr.fma(wi.x, wi.x, wi.y * wi.y)
        root = dr.sqrt(dr.fma(cos_i, cos_i, a2_s * sin2_i))
        return 0.25 * d_term * g_i * cos_g_o, d_sample / (2.0 * (cos_i + root))

    def add_floored_spec(self, plugin, value, pdf, p_spec, wi, wo, s, alpha):
        """``value`` and ``pdf`` with the specular lobe of "deschaintre2018" added."""
        dr = self.dr
        h_ok, h, sin2_h = self.half_vector(wi, wo)
        dg_term, spec_pdf = self.floored_spec(plugin, wi, h, sin2_h, wi.z, wo.z, alpha)
        value += dr.select(h_ok, self.fresnel(s, dr.dot(wi, h)) * dg_term, 0.0)
        pdf += dr.select(h_ok, p_spec * spec_pdf, 0.0)
        return value, pdf

    def add_ggx_spec(self, value, pdf, p_spec, wi, wo, s, alpha):
        """``value`` and ``pdf`` with the specular lobe of the default model added: F G D / 4
        (times cos_o) and the pdf of sampling GGX's visible normals."""
        dr = self.dr
        cos_i, cos_o = wi.z, wo.z
        a2 = alpha * alpha
        k = 0.5 * alpha
        h_ok, h, sin2_h = self.half_vector(wi, wo)
        denom = dr.fma(a2, h.z * h.z, sin2_h)
        d_term = a2 / (math.pi * denom * denom)
        cos_vh = dr.dot(wi, h)
        g_i = dr.rcp(dr.fma(cos_i, 1.0 - k, k))
        cos_g_o = cos_o / dr.fma(cos_o, 1.0 - k, k)
        f_term = self.fresnel(s, cos_vh)
        spec_value = f_term * (0.25 * d_term * g_i * cos_g_o)
        value += dr.select(h_ok, spec_value, 0.0)
        # Visible-normal pdf of the reflected direction: G1(wi) D / (4 cos_i), G1 exact Smith.
        sin2_i = dr.fma(wi.x, wi.x, wi.y * wi.y)
        root = dr.sqrt(dr.fma(cos_i, cos_i, a2 * sin2_i))
        spec_pdf = d_term / (2.0 * (cos_i + root))
        pdf += dr.select(h_ok, p_spec * spec_pdf, 0.0)
        return value, pdf

    # ---- eval, pdf and sample ----------------------------------------------------------

    def eval_pdf(self, plugin, spec, diff, si, wo, active):
        """(value with the cosine, pdf of the lobe mixture) of the lobes ``spec`` / ``diff``:
        one function, so that eval, pdf and sample agree."""
        mi, dr = self.mi, self.dr
        wi = si.wi
        cos_i, cos_o = wi.z, wo.z
        active = active & (cos_i > 0.0) & (cos_o > 0.0)
        d, s, alpha = self.params(plugin, si, active)
        p_spec = self.spec_prob(spec, diff, wi, d, s)
        value = mi.Color3f(0.0)
        pdf = mi.Float(0.0)
        if diff:
            value += d * (1.0 - s) * (cos_o * INV_PI)
            pdf += (1.0 - p_spec) * (cos_o * INV_PI)
        if spec and plugin.floored:
            value, pdf = self.add_floored_spec(plugin, value, pdf, p_spec, wi, wo, s, alpha)
        elif spec:
            value, pdf = self.add_ggx_spec(value, pdf, p_spec, wi, wo, s, alpha)
        value = dr.select(active, value, 0.0)
        pdf = dr.select(active, pdf, 0.0)
        return value, pdf

    def sample_visible_normal(self, wi, alpha, sample2):
        # Spherical-cap sampling of GGX visible normals (Dupuy & Benyoub 2023).
        mi, dr = self.mi, self.dr
        wi_std = dr.normalize(mi.Vector3f(alpha * wi.x, alpha * wi.y, wi.z))
        phi = 2.0 * math.pi * sample2.x
        z = dr.fma(1.0 - sample2.y, 1.0 + wi_std.z, -wi_std.z)
        sin_theta = dr.safe_sqrt(dr.fma(-z, z, 1.0))
        sin_phi, cos_phi = dr.sincos(phi)
        m_std = mi.Vector3f(sin_theta * cos_phi, sin_theta * sin_phi, z) + wi_std
        m = mi.Vector3f(alpha * m_std.x, alpha * m_std.y, dr.maximum(m_std.z, 0.0))
        len2 = dr.squared_norm(m)
        ok = len2 > 1e-30
        return dr.select(ok, m * dr.rsqrt(dr.maximum(len2, 1e-30)), mi.Vector3f(0.0, 0.0, 1.0))

    def sample_direction(self, plugin, spec, diff, si, sample1, sample2, d, s, alpha):
        """(wo, whether the specular lobe was picked): one lobe picked with ``sample1``, its
        direction drawn with ``sample2``."""
        mi, dr = self.mi, self.dr
        wi = si.wi
        if spec and diff:
            pick_spec = sample1 < self.spec_prob(spec, diff, wi, d, s)
        else:
            pick_spec = mi.Bool(spec)
        wo = mi.Vector3f(0.0, 0.0, 1.0)
        if spec:
            m = self.sample_visible_normal(wi, self.sampling_alpha(plugin, alpha), sample2)
            wo_spec = dr.fma(mi.Vector3f(2.0 * dr.dot(wi, m)), m, -wi)
            wo = wo_spec
        if diff:
            wo_diff = mi.warp.square_to_cosine_hemisphere(sample2)
            wo = dr.select(pick_spec, wo, wo_diff) if spec else wo_diff
        return wo, pick_spec

    def sample(self, plugin, bs, spec, diff, si, sample1, sample2, active):
        """(``bs`` filled in, weight = eval / pdf of the mixture)."""
        mi, dr = self.mi, self.dr
        active = active & (si.wi.z > 0.0)
        d, s, alpha = self.params(plugin, si, active)
        wo, pick_spec = self.sample_direction(plugin, spec, diff, si, sample1, sample2, d, s, alpha)
        value, pdf = self.eval_pdf(plugin, spec, diff, si, wo, active)
        active = active & (pdf > 0.0)
        bs.wo = wo
        bs.pdf = dr.select(active, pdf, 0.0)
        bs.eta = 1.0
        glossy = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
        diffuse = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
        bs.sampled_type = dr.select(pick_spec, glossy, diffuse)
        spec_index = mi.UInt32(plugin.spec_index if spec else 0)
        diff_index = mi.UInt32(plugin.diff_index if diff else 0)
        bs.sampled_component = dr.select(pick_spec, spec_index, diff_index)
        weight = dr.select(active, value / dr.select(active, pdf, 1.0), 0.0)
        return bs, weight
