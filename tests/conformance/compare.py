#!/usr/bin/env python3
"""Conformance of the two USD front ends: every stage of stages.py rendered by
`granular render` (usd-core) and by hdGranular (UsdImagingGLEngine through usdrecord's
frame recorder, hydra_runner.py), which must give the same image within noise or fail with
the same error. Prints a table (stage | description | granular render | hdGranular |
verdict) and writes it to OUTDIR/conformance.md; exits 1 when a stage DIFFERs that is not
in KNOWN_DIFFERENCES, or when a known difference now agrees (so that the list only shrinks).

Usage (with the venv's Python, which has usd-core and granular_core):
  GRANULAR_USD_PYTHONPATH=/opt/openusd/lib/python \\
  GRANULAR_HD_PLUGINPATH=$PWD/build/hdGranular/plugin:$PWD/schemas \\
  GRANULAR_CACHE_DIR=$PWD/build/cache \\
  .venv/bin/python tests/conformance/compare.py .venv/bin/granular build/conformance [STAGE ...]

The OpenUSD Python is the interpreter of usdrecord's first line (next to
$GRANULAR_USD_PYTHONPATH: <prefix>/bin/usdrecord), else /usr/bin/python3; set
GRANULAR_USD_PYTHON to choose another.

Both front ends render at the delegate's default samples per pixel and seed (the frame
recorder cannot change them; hydra_runner.py reads them and the command line is given the
same), so they share the core and its per-pixel random streams, and a valid stage should
give the same image. Images agree when the mean relative difference over the pixels
(sum |hydra - cli| / sum |cli|, RGB, over the command line's data window) is at most TIGHT.
A stage without grains must meet that. A stage with an aggregate may instead agree within
noise, since a path through many grains is chaotic (a rounding difference in a camera ray
makes it an independent sample, see tests/hydra/usdrecord_vs_granular.py): the command
line renders a second seed, and the images agree when their means differ by at most
max(2%, four standard errors) and the mean relative difference is at most 1.25 times that
of the two seeds. Errors agree when both front ends fail and the
delegate's messages name the `prim.attribute` that starts the command line's error
(`error: /Prim.attribute: detail`).
"""
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import stages as stage_defs  # noqa: E402
from cli_runner import run_cli  # noqa: E402

WIDTH = stage_defs.WIDTH
TIGHT = 0.01
STAGE_LIMIT_S = 120  # seconds hdGranular may take on one stage (hydra_runner.py stops it then)

# ---- known differences ------------------------------------------------------------------------
# Stages on which the front ends differ today, each with what was observed. A stage listed
# here that differs prints "known" and does not fail the run; one that agrees fails it with
# "known difference now agrees: remove it". Fix the front ends, then shrink this list.
KNOWN_DIFFERENCES = {
    "granular_instanced":
        "granular render renders both instanced heaps; hdGranular: error "
        "/World/HeapA/proto_Pile_id1.primvars:granular:prototypes: prototype \"../Grains/A\" "
        "(/World/HeapA/Grains/A) does not exist: the relative path is resolved against the instance's "
        "Hydra prim, not the aggregate's place in the prototype",
    "explicit_grains_xform_prototype":
        "granular render: error /World/Sim.prototypes: target /World/Sim/Protos/B is a Xform, not a Mesh; "
        "hdGranular renders it: a scene delegate shows the prototype's Mesh under its root's transform, not "
        "the relationship's target",
    "mesh_light_sphere":
        "both render the Sphere as a mesh light; OpenUSD 24.08's default UsdImagingDelegate hands hdGranular its "
        "own tessellation of an implicit surface (180 triangles for a sphere, 4% less area than core's 3968), so "
        "the light has that much less power (the scene-index UsdImaging, USDIMAGINGGL_ENGINE_ENABLE_SCENE_INDEX=1, "
        "hands over the shape, which core tessellates: the same image)",
    "mesh_light_link":
        "granular render lights the block alone; hdGranular lights everything: OpenUSD 24.08's UsdImaging "
        "resolves the light-link collections of light prims alone, not a mesh light's (hdGranular warns where "
        "the collection leaves the root out)",
}
# -----------------------------------------------------------------------------------------------


def usd_python():
    if os.environ.get("GRANULAR_USD_PYTHON"):
        return os.environ["GRANULAR_USD_PYTHON"]
    pypath = os.environ.get("GRANULAR_USD_PYTHONPATH", "")
    for entry in filter(None, pypath.split(os.pathsep)):
        usdrecord = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(entry))), "bin", "usdrecord")
        try:
            with open(usdrecord) as f:
                first = f.readline().strip()
        except OSError:
            continue
        if first.startswith("#!") and "env" not in first:
            return first[2:].split()[0]
    return "/usr/bin/python3"


def run_hydra(manifest, outdir, names):
    """Runs hydra_runner.py on `names` (one process; again on the rest if it dies part way,
    the stage it died on recorded as a crash). Returns the delegate's settings."""
    env = dict(os.environ)
    # The OpenUSD build's pxr, not the venv's usd-core; the delegate on the plugin path.
    env["PYTHONPATH"] = os.environ.get("GRANULAR_USD_PYTHONPATH", "")
    env["PXR_PLUGINPATH_NAME"] = os.environ.get("GRANULAR_HD_PLUGINPATH", "")
    os.makedirs(outdir, exist_ok=True)
    for n in ["settings", *names]:
        for ext in (".json", ".exr"):
            if os.path.exists(os.path.join(outdir, n + ext)):
                os.remove(os.path.join(outdir, n + ext))
    todo = list(names)
    while todo:
        cmd = [usd_python(), os.path.join(HERE, "hydra_runner.py"), manifest, outdir, *todo]
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1800)
        done = [n for n in todo if os.path.exists(os.path.join(outdir, n + ".json"))]
        todo = [n for n in todo if n not in done]
        if r.returncode == 0 and not todo:
            break
        if not todo:  # every stage recorded, then a failure at exit (the host's shutdown)
            print(f"note: hydra_runner.py exited with status {r.returncode} after recording every stage",
                  file=sys.stderr)
            break
        if not os.path.exists(os.path.join(outdir, "settings.json")):
            sys.stderr.write(r.stdout + r.stderr)
            raise SystemExit(f"hydra_runner.py failed with status {r.returncode} before any stage")
        crashed = todo.pop(0)  # stages run in order: the first unrecorded one killed the process
        tail = " ".join(r.stderr.strip().splitlines()[-3:])
        why = (f"stopped after {STAGE_LIMIT_S} s without converging" if r.returncode == -signal.SIGALRM
               else f"the process died (status {r.returncode}): {tail}")
        with open(os.path.join(outdir, crashed + ".json"), "w") as f:
            json.dump({"recorded": False, "exception": None, "seconds": 0.0, "image": None, "warnings": [],
                       "errors": [why], "stderr": r.stderr[-20000:]}, f)
    with open(os.path.join(outdir, "settings.json")) as f:
        return json.load(f)


def read_rgb(path):
    """(rgb (h, w, 3) float64, x, y, full_width, full_height) of an EXR."""
    import granular_core as core
    img = core.read_exr(path)
    px = np.asarray(img.pixels, dtype=np.float64)
    idx = [img.channels.index(c) for c in ("R", "G", "B")]
    return px[..., idx], img.x, img.y, img.full_width, img.full_height


def mean_rel_diff(a, b):
    return float(np.abs(a - b).sum() / max(np.abs(b).sum(), 1e-12))


def compare_images(stage, cli, hydra, granular, outdir, spp, seed):
    """(agree, why) for two successful renders."""
    c, x, y, fw, fh = read_rgb(cli["image"])
    h, *_ = read_rgb(hydra["image"])
    if h.shape[:2] != (fh, fw):
        return False, f"image sizes: cli {fw}x{fh}, hydra {h.shape[1]}x{h.shape[0]}"
    h = h[y:y + c.shape[0], x:x + c.shape[1]]  # the command line's data window
    if not (np.isfinite(c).all() and np.isfinite(h).all()):
        return False, "non-finite pixels"
    mean_c, mean_h = c.mean(), h.mean()
    if mean_c < 1e-6 and mean_h < 1e-6:
        return True, "both black"
    mrd = mean_rel_diff(h, c)
    bias = (mean_h - mean_c) / max(mean_c, 1e-12)
    if mrd <= TIGHT:
        return True, f"same image: mean rel. diff {mrd:.2g}"
    if not stage.grains:
        # Without grains nothing is chaotic: equal seeds must give the same image.
        return False, f"mean rel. diff {mrd:.3f} > {TIGHT} at equal seeds, means {bias:+.1%}"
    other = run_cli(granular, stage, os.path.join(outdir, "cli"), spp, seed + 1, WIDTH, suffix="_seed1")
    if not other["image"]:
        return False, f"mean rel. diff {mrd:.3f}; a second seed failed ({other['error']})"
    c1 = read_rgb(other["image"])[0]
    noise = mean_rel_diff(c1, c)
    se = np.sqrt(np.sum((c - c1) ** 2) / 2.0) / c.size
    bias_tol = max(0.02, 4.0 * se / max(mean_c, 1e-12))
    ok = abs(bias) <= bias_tol and mrd <= 1.25 * noise
    return ok, (f"{'within noise: ' if ok else ''}mean rel. diff {mrd:.3f} (two seeds {noise:.3f}), "
                f"means {bias:+.1%} (tol {bias_tol:.1%})")


def attribute_of(error):
    """The `prim.attribute` an error line starts with ("/World/Pile.primvars:granular:seed")."""
    head = error.split(": ", 1)[0].strip()
    return head


def short(text, n=110):
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 1] + "…"


def cli_outcome(r):
    warn = f" ({len(r['warnings'])} warning{'s' if len(r['warnings']) != 1 else ''})" if r["warnings"] else ""
    if r["rc"] == 0 and r["image"]:
        return "image" + warn
    if r["rc"] == 2:
        return "error: " + short(r["error"] or "(no error line)")
    return f"status {r['rc']}: " + short(r["error"] or r["stderr"].strip().splitlines()[-1:] or "")


def hydra_outcome(r):
    warn = f" ({len(r['warnings'])} warning{'s' if len(r['warnings']) != 1 else ''})" if r["warnings"] else ""
    if r["errors"]:
        times = r.get("repeats", {}).get("errors", len(r["errors"]))
        again = f" (reported {times} times)" if times > len(r["errors"]) else ""
        return "error: " + short(" | ".join(r["errors"])) + again
    if r["image"]:
        return "image" + warn
    return "no image, no error"


def verdict(stage, cli, hydra, granular, outdir, spp, seed):
    """(agree, why)."""
    cli_ok = cli["rc"] == 0 and cli["image"] is not None
    hydra_ok = not hydra["errors"] and hydra["image"] is not None
    if cli["rc"] not in (0, 2):
        return False, f"the command line failed with status {cli['rc']} (not an input error)"
    if cli_ok and hydra_ok:
        return compare_images(stage, cli, hydra, granular, outdir, spp, seed)
    if cli_ok:
        return False, "only hdGranular fails" if hydra["errors"] else "hdGranular wrote no image"
    if hydra_ok:
        return False, "only granular render fails"
    if not hydra["errors"]:
        return False, "granular render fails; hdGranular neither rendered nor reported an error"
    name = attribute_of(cli["error"] or "")
    if name and any(name in m for m in hydra["errors"]):
        return True, f"both name {name}"
    return False, f"granular render names {name or '(nothing)'}, hdGranular does not"


def main():
    args = sys.argv[1:]
    if len(args) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    granular, outdir, only = os.path.abspath(args[0]), os.path.abspath(args[1]), args[2:]
    t_start = time.monotonic()
    all_stages = stage_defs.write_all(os.path.join(outdir, "stages"))
    unknown = set(only) - {s.name for s in all_stages}
    if unknown:
        print(f"unknown stages: {', '.join(sorted(unknown))}", file=sys.stderr)
        return 2
    todo = [s for s in all_stages if not only or s.name in only]
    stale = set(KNOWN_DIFFERENCES) - {s.name for s in all_stages}
    manifest = os.path.join(outdir, "manifest.json")
    with open(manifest, "w") as f:
        json.dump([{"name": s.name, "path": s.path, "time": s.time, "hydra_camera": s.hydra_camera,
                    "width": WIDTH, "limit_s": STAGE_LIMIT_S} for s in todo], f, indent=1)

    hydra_dir, cli_dir = os.path.join(outdir, "hydra"), os.path.join(outdir, "cli")
    t0 = time.monotonic()
    settings = run_hydra(manifest, hydra_dir, [s.name for s in todo])
    t_hydra = time.monotonic() - t0
    spp, seed = int(settings["convergedSamplesPerPixel"]), int(settings["granular:seed"])

    rows, warn_rows, failures, t_cli = [], [], [], 0.0
    counts = {"agree": 0, "DIFFER": 0, "known": 0, "now agrees": 0}
    for s in todo:
        t0 = time.monotonic()
        cli = run_cli(granular, s, cli_dir, spp, seed, WIDTH)
        with open(os.path.join(hydra_dir, s.name + ".json")) as f:
            hydra = json.load(f)
        agree, why = verdict(s, cli, hydra, granular, outdir, spp, seed)
        t_cli += time.monotonic() - t0
        known = KNOWN_DIFFERENCES.get(s.name)
        if agree and known:
            text = f"known difference now agrees: remove it ({why})"
            counts["now agrees"] += 1
            failures.append(s.name)
        elif agree:
            text = f"agree ({why})"
            counts["agree"] += 1
        elif known:
            text = f"known: {why}"
            counts["known"] += 1
        else:
            text = f"DIFFER: {why}"
            counts["DIFFER"] += 1
            failures.append(s.name)
        rows.append((s.name, s.description, cli_outcome(cli), hydra_outcome(hydra), text))
        if cli["rc"] == 0 and not hydra["errors"] and len(cli["warnings"]) != len(hydra["warnings"]):
            warn_rows.append(f"- {s.name}: granular render {cli['warnings']}; hdGranular {hydra['warnings']}")

    def cell(t):
        return str(t).replace("|", "\\|")

    lines = [f"{len(todo)} stages at {WIDTH} px wide, {spp} spp, seed {seed} (hdGranular's defaults, "
             "both front ends)", "",
             "| stage | description | granular render | hdGranular | verdict |", "|---|---|---|---|---|"]
    lines += ["| " + " | ".join(cell(c) for c in row) + " |" for row in rows]
    lines += ["", f"agree {counts['agree']}, DIFFER {counts['DIFFER']}, known {counts['known']}, "
                  f"known but now agreeing {counts['now agrees']}; "
                  f"hdGranular {t_hydra:.1f} s, granular render and comparison {t_cli:.1f} s, "
                  f"total {time.monotonic() - t_start:.1f} s"]
    if stale:
        lines.append(f"KNOWN_DIFFERENCES names stages that do not exist: {', '.join(sorted(stale))}")
    known_lines = []
    if KNOWN_DIFFERENCES:
        known_lines = ["", "Known differences (KNOWN_DIFFERENCES in tests/conformance/compare.py):", ""]
        known_lines += [f"- {k}: {v}" for k, v in KNOWN_DIFFERENCES.items()]
    if warn_rows:  # not a verdict: the images agree, the warnings differ
        known_lines += ["", "Warnings that differ where both rendered (not counted in the verdict):", ""] + warn_rows
    text = "\n".join(lines + known_lines) + "\n"
    print(text)
    with open(os.path.join(outdir, "conformance.md"), "w") as f:
        f.write("# The two USD front ends on generated stages\n\n" + text)
    if failures:
        print(f"FAILED: {', '.join(failures)}")
    return 1 if failures or (stale and not only) else 0


if __name__ == "__main__":
    sys.exit(main())
