"""From a material plan to its maps: the one place a plan's material seed is consumed."""

from __future__ import annotations

from materials import load_deschaintre, sample_svbrdf, sample_uniform
from materials.errors import MaterialError
from pipeline.dataset.plan import KIND_UNIFORM, MaterialPlan, Plan, seeded_rng
from pipeline.dataset.spec import DatasetSpec
from pipeline.errors import ShaderballError


def make_material(plan: MaterialPlan, spec: DatasetSpec):
    """(materials.MaterialMaps, JSON-able description) of a planned material.

    Uniform materials become 1x1 maps (one value per map; Mitsuba's bilinear, repeating
    lookup of a 1x1 texture is that constant everywhere).
    """

    rng = seeded_rng(plan.material_seed)
    if plan.kind == KIND_UNIFORM:
        material = sample_uniform(rng, spec.materials.to_uniform_ranges())
        return material.to_maps(1), {"kind": "uniform", "values": material.as_dict()}
    if plan.svbrdf_family is not None:
        maps = sample_svbrdf(rng, plan.svbrdf_family, spec.materials.texture_resolution)
        return maps, {"kind": "svbrdf", "family": plan.svbrdf_family}
    maps = load_deschaintre(plan.svbrdf_file)
    return maps, {"kind": "svbrdf", "file": plan.svbrdf_file}


def check_imported_files(plans: Plan) -> int:
    """Import every map file of the spec's ``svbrdf_folders`` once, before anything is
    written: a file that cannot be imported refuses the build up front instead of stopping
    it half-way. Returns the count of files checked."""
    count = 0
    for files in plans.file_orders.values():
        for path in files:
            try:
                load_deschaintre(path).check()
            except (MaterialError, ValueError, OSError) as exc:
                raise ShaderballError(
                    f"materials.svbrdf_folders: {path}: cannot be imported ({exc}); "
                    "fix or remove the file (nothing was written)"
                ) from None
            count += 1
    return count
