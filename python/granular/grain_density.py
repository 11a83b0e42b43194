"""The packing rate of a PointInstancer's explicit grains as an OpenVDB file (core's
grain_density.h and density_export.h): what `granular export-vdb` writes for an instancer
of simulated grains (GranularInstancedAggregateAPI)."""
import os

from .errors import UserError


def explicit_grains_prim(scene, prim):
    """The instancer of explicit grains at path `prim` in a read scene, or None."""
    for p in scene.explicit_grains:
        if str(p.GetPath()) == prim:
            return p
    return None


def export_grain_density(scene, prim, output, voxel_size=0.0, source=None):
    """Writes the grains' packing rate f (grid 'density', dimensionless) and, where several
    prototypes mix, their number fractions ('fraction.<k>') to `output`. voxel_size > 0 sets
    the kernel width to twice it (core's Δ = h/2); 0 keeps the default kernel of 3 mean
    grain radii. Returns the writer's summary with the grains, kernel width, mean radius and
    the mean f over the active voxels."""
    import granular_core as core
    from .usd_reader import read_instanced_grains, translate_core_error

    desc = read_instanced_grains(scene, prim)
    try:
        density = core.build_grain_density(desc, kernel_width=2.0 * voxel_size if voxel_size else 0.0)
    except core.InputError as e:
        if e.attribute in ("voxelSize", "kernelWidth"):
            raise UserError("command line", "--voxel-size", e.detail) from None
        raise translate_core_error(e, scene) from None
    source = source or scene.stage.GetRootLayer().identifier
    try:
        r = core.write_grain_density_vdb(
            output, density, str(prim.GetPath()),
            string_metadata={"granular:stage": os.path.abspath(source) if os.path.exists(source) else source,
                             "granular:density": "packing rate f: grain volume per volume, smoothed by a cubic "
                                                 "B-spline kernel of width granular:kernelWidth"})
    except core.InputError as e:
        if e.attribute == "voxelSize":
            raise UserError("command line", "--voxel-size", e.detail) from None
        raise translate_core_error(e, scene) from None
    out = dict(r)
    st = density.stats
    out.update(grains=st["grains"], kernel_width=density.kernel_width, mean_radius=st["mean_radius"],
               prototypes=list(density.prototype_names), seconds=st["seconds"], bytes=st["bytes"])
    return out


def export_summary(prim, output, r):
    fractions = f", number fractions of {len(r['prototypes'])} prototypes in 'fraction.<k>'" \
        if len(r["prototypes"]) > 1 else ""
    return (f"wrote {output}: grid 'density' = packing rate of the {r['grains']} grains of {prim} (kernel width "
            f"{r['kernel_width']:.4g} = {r['kernel_width'] / r['mean_radius']:.3g} mean grain radii){fractions}; "
            f"voxel {r['voxel_size']:.4g}, {r['active_voxels']} active voxels")
