"""What the usdview menu commands do, without a GUI (testable with usd-core alone).

Each function takes an open Usd.Stage (usdview's, with the user's edits) and returns
text for the user, or raises granular.errors.UserError naming the prim and attribute.
"""
import os

TECHNIQUE_SETTING = "granular:technique"   # the Granular delegate's render setting
REFERENCE = "ept"                            # explicit path tracing alone: the reference
DEFAULT = "hybrid"


def _api():
    from granular import api  # imported late: usdview loads plugins before a stage exists
    return api


def _descendants(prim):
    from pxr import Usd
    return list(Usd.PrimRange(prim))[1:]


def statistics_text(stage, paths):
    """Grains, tiles, teleportation-transport and RTE parameters of the selected aggregates."""
    from granular import schema
    wanted = []
    for p in paths:
        prim = stage.GetPrimAtPath(str(p))
        if not prim:
            continue
        for q in [prim] + _descendants(prim):
            if q.HasAPI(schema.AGGREGATE_API) and str(q.GetPath()) not in wanted:
                wanted.append(str(q.GetPath()))
    if not wanted:
        return "No granular aggregate selected (select a Mesh with GranularAggregateAPI, or a parent of one)."
    lines = []
    for r in _api().aggregate_report(stage=stage):
        if r["prim"] not in wanted:
            continue
        rte, tt = r["rte"], r["tt"]
        f3 = lambda v: "(" + ", ".join(f"{x:.4g}" for x in v) + ")"
        lines += [
            r["prim"],
            f"  grains          ~{r['grains']:.4g}  (radius {r['grain_radius']:g}, packing rate {r['packing_rate']:g})",
            f"  prototypes      {', '.join(r['prototypes'])}  (weights {', '.join(f'{w:g}' for w in r['weights'])})",
            f"  tiles           {r['tiles']['cells']}: {r['tiles']['inside']} inside, {r['tiles']['partial']} partial",
            f"  TT              beta {tt['beta']:.4f}, lambda_delta {tt['lambda_delta']:.4g} R, lambda_s {f3(tt['lambda_s'])} R",
            f"  sigma_t         {f3(rte['sigma_t'])}  albedo {f3(rte['albedo'])}  g {f3(rte['g'])}",
            f"  mean free path  {f3(r['mean_free_path'])}",
        ]
    return "\n".join(lines)


def export_density_text(stage, prim_path, output, voxel_size=None):
    """Writes the aggregate's coarse density to an OpenVDB file; returns a summary."""
    r = _api().export_density(str(prim_path), output, voxel_size, stage=stage)
    return (f"Wrote {output}: grid 'density' = {r['sigma_t']:.6g} inside {prim_path}, 0 outside "
            f"(voxel {r['voxel_size']:.4g}, {r['active_voxels']} active voxels).")


def default_vdb_name(stage, prim_path):
    base = os.path.splitext(os.path.basename(stage.GetRootLayer().realPath or "stage"))[0]
    return f"{base}_{str(prim_path).strip('/').replace('/', '_')}.vdb"


def toggled_technique(current):
    """EPT-only reference on, or back to the hybrid."""
    return DEFAULT if str(current) == REFERENCE else REFERENCE
