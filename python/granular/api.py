"""The granular package's Python API for tools other than the command line (the usdview
plugin in usdview_plugins/, pipeline scripts): the same reports and exports as
`granular info` and `granular export-vdb`, from a stage path or an open Usd.Stage.

Errors are granular.errors.UserError naming the prim and the attribute.
"""
import os

from .errors import UserError


def _f32(x):
    """A float32 value (core's) as the shortest decimal that round-trips it."""
    return float(f"{x:.7g}")


def build_scene(scene, previous=None, log=None):
    """core.Scene of a StageScene, errors named after the stage's prims; previous (a core.Scene
    of the same stage, another time) lends it the aggregates whose inputs are unchanged; log(line)
    hears what the build waits for."""
    import granular_core as core
    from .usd_reader import translate_core_error, validate
    validate(scene)
    try:
        return core.Scene.build(scene.desc, previous, log)
    except core.InputError as e:
        raise translate_core_error(e, scene) from None


def _media(scene, built):
    import granular_core as core
    from .usd_reader import translate_core_error
    try:
        return built.media()
    except core.InputError as e:
        raise translate_core_error(e, scene) from None


def _report(scene, built, media):
    out = []
    descs = scene.desc.aggregates
    for k, (src, info) in enumerate(zip(scene.aggregates, built.aggregates)):
        a = descs[k]
        r = {
            "prim": src["prim"],
            "prototypes": src["prototypes"],
            "weights": [_f32(w) for w in a.weights],
            "sizes": [_f32(x) for x in a.sizes] or [1.0] * len(a.weights),
            "size_spread": _f32(a.size_spread),
            "grain_radius": _f32(a.grain_radius),
            "max_grain_radius": _f32(info["max_grain_radius"]),
            "packing_rate": _f32(a.packing_rate),
            "seed": a.seed,
            "tile_spheres": a.tile_spheres,
            "grains": info["approx_grains"],
            "tiles": {"edge": _f32(info["cell_size"]), "cells": info["cells"], "inside": info["inside_cells"],
                      "partial": info["partial_cells"]},
            "tile_packing_rate": info["tile_packing_rate"],
            "memory_bytes": info["memory_bytes"],
            "setup_seconds": info["setup_seconds"],
        }
        m = media[k]
        r["media_used_by_renderer"] = bool(built.has_media)
        r["tt"] = {"beta": m["beta"], "beta_se": m["beta_se"], "lambda_delta": m["lambda_delta"],
                   "lambda_s": list(m["lambda_s"]), "sigma_b": _f32(m["sigma_b"]), "rays": m["rays"]}
        r["rte"] = {key: [_f32(x) for x in m[key]] for key in ("sigma_t", "albedo", "g", "sigma_t_reduced", "albedo_reduced",
                                                  "sigma_a", "sigma_tr")}
        r["mean_free_path"] = [_f32(x) for x in m["mean_free_path"]]
        # What carries this aggregate's low orders before the medium (switching.h).
        r["switching"] = built.switching[k]
        r["low_orders"] = built.low_orders_text(k)
        out.append(r)
    return out


def _fmt3(v):
    return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"


def report_lines(r):
    """One aggregate_report() entry as text (granular info, the usdview statistics)."""
    t, tt, rte = r["tiles"], r["tt"], r["rte"]
    return [
        r["prim"],
        f"  prototypes    {', '.join(r['prototypes'])}  (weights {', '.join(f'{w:g}' for w in r['weights'])})",
        *([f"  sizes         {', '.join(f'{x:g}' for x in r['sizes'])} x radius, spread ±{r['size_spread']:g} "
           f"(largest grain {r['max_grain_radius']:.4g})"] if r["size_spread"] > 0 or any(x != 1 for x in r["sizes"])
          else []),
        f"  grains        ~{r['grains']:.4g}  (radius {r['grain_radius']:g}, packing rate {r['packing_rate']:g}, "
        f"seed {r['seed']})",
        f"  tiles         {t['cells']} of edge {t['edge']:.4g}: {t['inside']} inside, {t['partial']} partial "
        f"({r['tile_spheres']} spheres each, f = {r['tile_packing_rate']:.3f})",
        f"  TT            beta {tt['beta']:.4f} ± {tt['beta_se']:.4f}, lambda_delta {tt['lambda_delta']:.4g} R, "
        f"lambda_s {_fmt3(tt['lambda_s'])} R, sigma_b {tt['sigma_b']:.4g}",
        f"  RTE           sigma_t {_fmt3(rte['sigma_t'])}, albedo {_fmt3(rte['albedo'])}, g {_fmt3(rte['g'])}",
        f"  diffusion     sigma'_t {_fmt3(rte['sigma_t_reduced'])}, albedo' {_fmt3(rte['albedo_reduced'])}, "
        f"sigma_tr {_fmt3(rte['sigma_tr'])}",
        f"  mean free path {_fmt3(r['mean_free_path'])} (world units, per RGB channel)",
        "  hybrid        " + ("after the first grain: " + r["low_orders"] if r["media_used_by_renderer"] else
                              "does not use media here: the scene's aggregates are thinner than their mean "
                              "free paths, so EPT renders them"),
    ]


def export_summary(prim, output, r):
    """What export_density() wrote, in one line."""
    return (f"wrote {output}: grid 'density' = {r['sigma_t']:.6g} inside {prim}, 0 outside; "
            f"voxel {r['voxel_size']:.4g}, {r['active_voxels']} active voxels")


def read_aggregates(path=None, stage=None):
    """The stage's aggregates only (no surfaces, no camera needed): a StageScene."""
    from .usd_reader import read_stage
    return read_stage(path or (stage.GetRootLayer().identifier if stage else None), surfaces=False,
                      need_camera=False, stage=stage)


def aggregate_report(path=None, stage=None, scene=None):
    """Per aggregate: prim, prototypes, weights, grain radius, packing rate, seed, grain
    count, tiles, teleportation-transport (tt) and RTE/diffusion (rte) parameters, mean
    free path, and whether the renderer uses media for it. A list of dicts."""
    scene = scene or read_aggregates(path, stage)
    built = build_scene(scene)
    return _report(scene, built, _media(scene, built))


def export_density(prim, output, voxel_size=None, path=None, stage=None):
    """Writes the aggregate `prim`'s coarse density (σ_t inside its boundary, 0 outside) as
    an OpenVDB float grid named `density` to `output`; returns the writer's summary
    (voxel_size, active_voxels) with sigma_t (the grid's value)."""
    import granular_core as core
    from pxr import Sdf
    from .usd_reader import translate_core_error, validate

    scene = read_aggregates(path, stage)
    validate(scene)
    ok, _ = Sdf.Path.IsValidPathString(prim)
    matches = [k for k, a in enumerate(scene.aggregates) if ok and a["prim"] == str(Sdf.Path(prim))]
    if not matches:
        p = scene.stage.GetPrimAtPath(prim) if ok and Sdf.Path(prim).IsAbsolutePath() else None
        if not p:
            raise UserError("command line", "--prim", f'"{prim}" is not a prim of the stage')
        raise UserError(prim, "", "is not a visible Mesh with GranularAggregateAPI")
    k = matches[0]
    built = build_scene(scene)
    medium = _media(scene, built)[k]
    sigma = medium["sigma_t"]
    sigma_mean = sum(sigma) / 3.0
    source = path or scene.stage.GetRootLayer().identifier
    try:
        r = core.write_density_vdb(
            output, scene.aggregates[k]["world_boundary"], sigma_mean, voxel_size or 0.0, prim,
            float_metadata={"granular:grainRadius": medium["grain_radius"],
                            "granular:packingRate": medium["packing_rate"]},
            vec3_metadata={"granular:sigmaT": tuple(sigma), "granular:albedo": tuple(medium["albedo"]),
                           "granular:g": tuple(medium["g"]), "granular:meanFreePath": tuple(medium["mean_free_path"])},
            string_metadata={"granular:stage": os.path.abspath(source) if os.path.exists(source) else source,
                             "granular:density": "mean over RGB of sigma_t (1/world unit); per channel in granular:sigmaT"})
    except core.InputError as e:
        if e.attribute == "voxelSize":
            raise UserError("command line", "--voxel-size", e.detail) from None
        raise translate_core_error(e, scene) from None
    out = dict(r)
    out["sigma_t"] = sigma_mean
    return out
