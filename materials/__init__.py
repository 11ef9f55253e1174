"""Materials: the model (Deschaintre et al. 2018's Cook-Torrance), samplers and an importer.

A material is four texture-space maps (:class:`MaterialMaps`). Uniform
materials come from :func:`sample_uniform`, procedural spatially varying ones
from :func:`sample_svbrdf`, files in Deschaintre et al.'s layout from
:func:`load_deschaintre`. The numpy reference BRDF is :mod:`materials.brdf_ref`;
the Mitsuba plugin that renders it is :mod:`pipeline.render.bsdf` (the only
module here that loads Mitsuba, and only when called). docs/materials.md has
the details. The ranges of a material's values (``ALBEDO_RANGE``, ``ROUGHNESS_RANGE``,
``UNIFORM_LIMITS``) are declared here once: the spec's, the commands' and the server's rules
are built from them.

Layer 1 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): imports
nothing of the project.
"""

from materials.deschaintre import load_deschaintre
from materials.maps import (
    ALBEDO_RANGE,
    ROUGHNESS_RANGE,
    MaterialMaps,
    UniformMaterial,
    decode_normal_map,
    encode_normal_map,
    normals_from_height,
)
from materials.svbrdf import SVBRDF_FAMILIES, sample_svbrdf
from materials.uniform import UNIFORM_LIMITS, UniformRanges, sample_uniform

__all__ = [
    "ALBEDO_RANGE",
    "ROUGHNESS_RANGE",
    "UNIFORM_LIMITS",
    "MaterialMaps",
    "UniformMaterial",
    "UniformRanges",
    "sample_uniform",
    "SVBRDF_FAMILIES",
    "sample_svbrdf",
    "load_deschaintre",
    "encode_normal_map",
    "decode_normal_map",
    "normals_from_height",
]
