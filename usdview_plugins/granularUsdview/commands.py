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


def statistics_text(stage, paths):
    """Grains, tiles, teleportation-transport and RTE parameters of the selected aggregates."""
    from pxr import Usd
    from granular import schema
    wanted = set()
    for p in paths:
        prim = stage.GetPrimAtPath(str(p))
        if prim:
            wanted.update(str(q.GetPath()) for q in Usd.PrimRange(prim) if q.HasAPI(schema.AGGREGATE_API))
    if not wanted:
        return "No granular aggregate selected (select a Mesh with GranularAggregateAPI, or a parent of one)."
    api = _api()
    lines = []
    for r in api.aggregate_report(stage=stage):
        if r["prim"] in wanted:
            lines += api.report_lines(r)
    return "\n".join(lines)


def export_density_text(stage, prim_path, output, voxel_size=None):
    """Writes the aggregate's coarse density to an OpenVDB file; returns a summary."""
    api = _api()
    r = api.export_density(str(prim_path), output, voxel_size, stage=stage)
    text = api.export_summary(prim_path, output, r)
    return text[0].upper() + text[1:] + "."


def default_vdb_name(stage, prim_path):
    base = os.path.splitext(os.path.basename(stage.GetRootLayer().realPath or "stage"))[0]
    return f"{base}_{str(prim_path).strip('/').replace('/', '_')}.vdb"


def toggled_technique(current):
    """EPT-only reference on, or back to the hybrid."""
    return DEFAULT if str(current) == REFERENCE else REFERENCE
