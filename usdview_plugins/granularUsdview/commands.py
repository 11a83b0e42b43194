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


def light_links_text(stage, paths):
    """What each selected light lights (UsdLux light linking), as both front ends read it: the
    drawn meshes, aggregates and simulated grains its collection:lightLink includes; and which
    of them cast its shadows (its collection:shadowLink, inputs:shadow:enable)."""
    from pxr import UsdLux
    from granular import usd_reader
    lights = [str(p) for p in paths if stage.GetPrimAtPath(str(p)) and
              stage.GetPrimAtPath(str(p)).HasAPI(UsdLux.LightAPI)]
    if not lights:
        return "No light selected (select a UsdLux light)."
    scene = usd_reader.read_stage(stage.GetRootLayer().realPath, stage=stage, need_camera=False)
    d = scene.desc
    objects = {}  # name -> its categories (a prim's instances share them here)
    for o in list(d.meshes) + list(d.aggregates) + list(d.instanced_grains):
        objects.setdefault(o.name, set()).update(o.link_categories)
    links = {l.name: l.light_link for l in d.lights}
    shadows = {l.name: (l.shadow_link, l.shadows) for l in d.lights}
    lines = []
    for path in lights:
        if path not in links:
            lines.append(f"{path}: not rendered (see the render's warnings)")
            continue
        if not links[path]:
            lines.append(f"{path} lights every object (its collection:lightLink holds every prim)")
        else:
            lit = sorted(n for n, c in objects.items() if links[path] in c)
            unlit = sorted(n for n in objects if n not in lit)
            lines.append(f"{path} lights {len(lit)} of {len(objects)} objects")
            lines += [f"  lights {n}" for n in lit] + [f"  not {n}" for n in unlit]
        link, enabled = shadows[path]
        if not enabled:
            lines.append(f"{path}: no object casts its shadows (inputs:shadow:enable is off)")
        elif link:
            cast = sorted(n for n, c in objects.items() if link in c)
            lines.append(f"{path}: {len(cast)} of {len(objects)} objects cast its shadows")
            lines += [f"  casts {n}" for n in cast] + [f"  not {n}" for n in sorted(objects) if n not in cast]
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
