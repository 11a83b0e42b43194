#!/usr/bin/env python3
"""Stress suite: extreme inputs through the whole renderer, one subprocess per case.

Each case is a JSON scene (written to OUT/cases/) rendered by `granular-render` with a
wall-clock timeout, once per technique (ept, ept+vpt, hybrid). Outcomes:
  ok           exit 0, no non-finite sample dropped, no NaN/Inf in the colour or AOV
               channels (the CLI's --stats-json counts both)
  input-error  exit 2 with one "error: object.attribute: message" line: the renderer
               refused the input clearly (e.g. more than 2^28 tiles for a tiny grain)
  FAIL         anything else: a crash (signal), exit 1, non-finite values, a missing
               stats file, or a timeout (a hang or unbounded time)
Peak RSS is the child's own (os.wait4). Sweeps, one factor at a time around a base case
(a ball of radius 1 of rock grains, R = 0.05, f = 0.6, absorbing IOR 1.5, dome + sun):
packing rate 0.01–0.64, absorption 0 … 1e30 (exactly 0 included), IOR 1.0–4.0 (the
accepted range; 2.4 is diamond), grain radius 1e-5–0.5 of the object, the camera and
lights (sphere, rect) inside the aggregate, grazing rays (camera in the plane of a box
aggregate's face, axis-aligned rays along the tile grid, a sun 0.006° above the face),
a sphere light of radius 0.5 at 5000 units, the whole scene scaled to 1e6 and 1e-6 units
(and 1e9, 1e-9), moved 1e3 to 1e14 units from the origin (render space: scene_desc.h), and
thin lenses of f/1e-15 to f/0.5.

Usage: python3 bench/stress.py [--build build] [--quick] [--timeout 300] [--only SUBSTR]
       [--techniques ept,ept+vpt,hybrid] [--out out/stress]
Exit status 1 when any case FAILs. --quick runs a small subset of each sweep.
"""
import argparse
import copy
import json
import math
import os
import signal
import subprocess
import sys
import time

BASE = {
    "render": {"width": 32, "height": 24, "spp": 4, "seed": 1},
    "camera": {"look_at": {"eye": [0.4, 0.9, 3.4], "target": [0, 0, 0], "up": [0, 1, 0]},
               "focal_length": 35, "horizontal_aperture": 36, "vertical_aperture": 27,
               "clipping_range": [0.01, 100]},
    "materials": {"sand": {"type": "dielectric", "ior": 1.5, "absorption": [0.1, 0.2, 0.4]},
                  "floor": {"type": "lambert", "albedo": 0.5}},
    "meshes": [{"name": "floor", "shape": {"box": {"lo": [-4, -1.3, -4], "hi": [4, -1.0, 4]}}, "material": "floor"}],
    "lights": [{"name": "sky", "type": "dome", "color": [0.5, 0.6, 0.8]},
               {"name": "sun", "type": "distant", "direction": [-0.4, -1.0, -0.3], "angle": 2.0, "intensity": 3.0}],
    "aggregates": [{"name": "ball", "boundary": {"icosphere": {"subdivisions": 2, "radius": 1.0}},
                    "grain_radius": 0.05, "packing_rate": 0.6, "seed": 1, "tile_spheres": 64,
                    "prototypes": [{"name": "rock", "shape": {"rock": {"subdivisions": 1, "roughness": 0.2, "seed": 1}},
                                    "material": "sand"}]}],
}


def scaled(scene, s):
    """The whole scene scaled by s (positions, sizes, grain radius, clipping)."""
    d = copy.deepcopy(scene)
    la = d["camera"]["look_at"]
    la["eye"] = [x * s for x in la["eye"]]
    la["target"] = [x * s for x in la["target"]]
    d["camera"]["clipping_range"] = [x * s for x in d["camera"]["clipping_range"]]
    for m in d.get("meshes", []):
        m["transform"] = {"scale": s}
    for l in d.get("lights", []):
        if "position" in l:
            l["position"] = [x * s for x in l["position"]]
        if "radius" in l:
            l["radius"] *= s
        for k in ("width", "height"):
            if k in l:
                l[k] *= s
    for a in d["aggregates"]:
        a["transform"] = {"scale": s}
        a["grain_radius"] *= s
    return d


def case(name, **kw):
    d = copy.deepcopy(BASE)
    agg = d["aggregates"][0]
    mat = d["materials"]["sand"]
    for k, v in kw.items():
        if k == "f":
            agg["packing_rate"] = v
        elif k == "absorption":
            mat["absorption"] = v
        elif k == "ior":
            mat["ior"] = v
        elif k == "R":
            agg["grain_radius"] = v
        elif k == "fn":
            d = v(d)
    return name, d


def camera_inside(d):
    d["camera"]["look_at"] = {"eye": [0.1, 0.05, 0.2], "target": [0.3, -0.2, -1], "up": [0, 1, 0]}
    return d


def sphere_light_inside(d):
    d["lights"] = [{"name": "bulb", "type": "sphere", "position": [0, 0.1, 0], "radius": 0.15, "intensity": 20}]
    return d


def rect_light_inside(d):
    d["lights"] = [{"name": "panel", "type": "rect", "width": 0.5, "height": 0.5, "intensity": 20,
                    "transform": {"translate": [0, 0.2, 0], "rotate": [90, 1, 0, 0]}}]
    return d


def far_small_sphere_light(d):
    # A lamp of radius 0.5 at 5000 units: its cone is too narrow for cos in float.
    d["lights"].append({"name": "far lamp", "type": "sphere", "position": [0, 5000, 0], "radius": 0.5,
                        "intensity": 1e7})
    return d


def camera_and_light_inside(d):
    return sphere_light_inside(camera_inside(d))


def grazing_box(d):
    # A flat box aggregate; the camera sits in the plane of its top face and the sun is
    # 0.006 degrees above that plane: rays graze the face and run along it.
    agg = d["aggregates"][0]
    agg["boundary"] = {"box": {"lo": [-1, -0.25, -1], "hi": [1, 0.25, 1]}}
    d["camera"]["look_at"] = {"eye": [0.0, 0.25, 3.0], "target": [0.0, 0.25, 0.0], "up": [0, 1, 0]}
    d["lights"][1] = {"name": "sun", "type": "distant", "direction": [1, -1e-4, 0.2], "angle": 0}
    return d


def axis_aligned(d):
    # Camera on an axis, looking straight down it: many primary rays have zero direction
    # components, and the box's faces lie on the tile grid's planes.
    agg = d["aggregates"][0]
    agg["boundary"] = {"box": {"lo": [-1, -1, -1], "hi": [1, 1, 1]}}
    d["camera"]["look_at"] = {"eye": [0.0, 0.0, 4.0], "target": [0.0, 0.0, 0.0], "up": [0, 1, 0]}
    d["lights"][1] = {"name": "sun", "type": "distant", "direction": [0, -1, 0], "angle": 0}
    return d


def moved(d, t):
    """The whole scene moved by t along each axis (camera, lights, meshes, aggregates)."""
    d = copy.deepcopy(d)
    # The look-at frame as a matrix (row-major, column vectors), its translation moved in
    # double: look_at's eye and target are floats, which 1e9 away round to one point.
    la = d["camera"].pop("look_at")
    eye, target, up = (la[k] for k in ("eye", "target", "up"))

    def unit(v):
        n = math.sqrt(sum(x * x for x in v))
        return [x / n for x in v]

    def cross(a, b):
        return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    back = unit([e - g for e, g in zip(eye, target)])
    right = unit(cross(up, back))
    cols = [right, cross(back, right), back, [e + t for e in eye]]
    d["camera"]["transform"] = {"matrix": [float(cols[c][r]) for r in range(3) for c in range(4)] + [0, 0, 0, 1.0]}
    # Translations as matrices too (JSON's translate is float: 1e12 would round by 4096).
    shift = [1.0, 0, 0, t, 0, 1.0, 0, t, 0, 0, 1.0, t, 0, 0, 0, 1.0]
    for obj in d.get("meshes", []) + d["aggregates"]:
        if "transform" in obj:
            raise ValueError("moved() takes a scene whose meshes and aggregates have no transform")
        obj["transform"] = {"matrix": shift}
    for l in d.get("lights", []):
        if "position" in l:
            l["position"] = [x + t for x in l["position"]]
    return d


def tiny_aperture(f_stop):
    # A thin lens faster than any real one (f/0.5): an fStop of 1e-15 once aborted the
    # process inside Embree; refused now, by name.
    def fn(d):
        d["camera"]["f_stop"] = f_stop
        d["camera"]["focus_distance"] = 0.1
        return d
    return fn


def cases(quick):
    out = []
    for f in ([0.01, 0.64] if quick else [0.01, 0.05, 0.2, 0.4, 0.6, 0.64]):
        out.append(case(f"packing f={f}", f=f))
    for a in ([0, 1e30] if quick else [0, 1e-6, 0.1, 10, 1e3, 1e6, 1e30, [0, 1e6, 1e30]]):
        out.append(case(f"absorption {a}", absorption=a))
    for n in ([1.0, 4.0] if quick else [1.0, 1.0001, 1.33, 2.4, 4.0]):
        out.append(case(f"ior {n}", ior=n))
    for R in ([1e-5, 0.5] if quick else [1e-5, 1e-4, 1e-3, 0.01, 0.1, 0.5]):
        out.append(case(f"grain radius {R}", R=R))
    out.append(case("camera inside", fn=camera_inside))
    out.append(case("sphere light inside", fn=sphere_light_inside))
    if not quick:
        out.append(case("rect light inside", fn=rect_light_inside))
        out.append(case("camera + light inside", fn=camera_and_light_inside))
    out.append(case("small sphere light 5000 away", fn=far_small_sphere_light))
    out.append(case("grazing face", fn=grazing_box))
    out.append(case("axis-aligned rays", fn=axis_aligned))
    for s in [1e6, 1e-6]:
        out.append(case(f"scale {s:g}", fn=lambda d, s=s: scaled(d, s)))
    for t in ([1e6, 1e14] if quick else [1e3, 1e5, 1e6, 1e9, 1e12, 1e14]):
        out.append(case(f"moved {t:g}", fn=lambda d, t=t: moved(d, t)))
    for f_stop in ([1e-15] if quick else [1e-15, 1e-6, 0.49, 0.5]):
        out.append(case(f"f-stop {f_stop:g}", fn=tiny_aperture(f_stop)))
    if not quick:
        out.append(case("scale 1e9", fn=lambda d: scaled(d, 1e9)))
        out.append(case("scale 1e-9", fn=lambda d: scaled(d, 1e-9)))
        out.append(case("scale 1e6, camera inside", fn=lambda d: scaled(camera_inside(d), 1e6)))
        out.append(case("scale 1e-6, light inside", fn=lambda d: scaled(sphere_light_inside(d), 1e-6)))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default="build")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--timeout", type=float, default=300)
    ap.add_argument("--only", default="")
    ap.add_argument("--techniques", default="ept,ept+vpt,hybrid")
    ap.add_argument("--out", default="out/stress")
    a = ap.parse_args()
    exe = os.path.join(a.build, "core", "granular-render")
    if not os.path.exists(exe):
        sys.exit(f"{exe} not found: build first")
    os.makedirs(os.path.join(a.out, "cases"), exist_ok=True)
    env = dict(os.environ)
    env.setdefault("GRANULAR_CACHE_DIR", os.path.join(a.out, "cache"))
    rows, failures = [], 0
    for i, (name, scene) in enumerate(cases(a.quick)):
        if a.only and a.only not in name:
            continue
        path = os.path.join(a.out, "cases", f"case{i:02d}.json")
        with open(path, "w") as f:
            json.dump(scene, f, indent=1)
        for tech in a.techniques.split(","):
            rc, err, elapsed, timed_out, stats, rss = run_one(exe, path, tech, a.timeout, env)
            outcome, note = classify(rc, err, timed_out, stats)
            if outcome == "FAIL":
                failures += 1
            rows.append((name, tech, outcome, elapsed, rss, note))
            print(f"{name:28s} {tech:8s} {outcome:11s} {elapsed:7.2f} s {rss / 1024:7.0f} MiB  {note}",
                  file=sys.stderr, flush=True)
    if not rows:
        sys.exit(f"no case matches --only {a.only!r}")
    print("| case | technique | outcome | time (s) | peak RSS (MiB) | note |")
    print("|---|---|---|---|---|---|")
    for name, tech, outcome, elapsed, rss, note in rows:
        print(f"| {name} | {tech} | {outcome} | {elapsed:.2f} | {rss / 1024:.0f} | {note} |")
    print("\n| sweep | cases | runs | ok | input-error | FAIL | longest (s) | largest peak RSS (MiB) |")
    print("|---|---|---|---|---|---|---|---|")
    for fam, members in families(rows).items():
        print(f"| {fam} | {len({r[0] for r in members})} | {len(members)} | {sum(r[2] == 'ok' for r in members)} | "
              f"{sum(r[2] == 'input-error' for r in members)} | {sum(r[2] == 'FAIL' for r in members)} | "
              f"{max(r[3] for r in members):.1f} | {max(r[4] for r in members) / 1024:.0f} |")
    print(f"\n{len(rows)} runs, {sum(r[2] == 'ok' for r in rows)} ok, "
          f"{sum(r[2] == 'input-error' for r in rows)} clear input errors, {failures} failures; "
          f"longest {max(r[3] for r in rows):.1f} s, largest peak RSS {max(r[4] for r in rows) / 1024:.0f} MiB")
    return 1 if failures else 0


def families(rows):
    """Rows grouped by sweep (the case name's first words), in order."""
    out = {}
    for r in rows:
        fam = next((k for k in ("packing", "absorption", "ior", "grain radius", "scale") if r[0].startswith(k)), r[0])
        out.setdefault(fam, []).append(r)
    return out


def run_one(exe, path, technique, timeout, env):
    """Runs one render; returns (rc, stderr, seconds, timed_out, stats_path, peak_rss_kib)."""
    exr = path[:-5] + f".{technique}.exr"
    stats = exr + ".json"
    for p in (exr, stats):
        if os.path.exists(p):
            os.remove(p)
    cmd = [exe, path, "-o", exr, "--technique", technique, "--quiet", "--stats-json", stats]
    errpath = exr + ".stderr"
    t0 = time.time()
    with open(errpath, "w") as errf:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=errf, env=env, start_new_session=True)
        deadline = t0 + timeout
        timed_out = False
        while True:
            pid, status, ru = os.wait4(proc.pid, os.WNOHANG)
            if pid == proc.pid:
                break
            if time.time() > deadline:
                timed_out = True
                os.killpg(proc.pid, signal.SIGKILL)
                pid, status, ru = os.wait4(proc.pid, 0)
                break
            time.sleep(0.02)
    proc.returncode = os.waitstatus_to_exitcode(status)
    elapsed = time.time() - t0
    with open(errpath, errors="replace") as f:
        err = f.read()
    return proc.returncode, err, elapsed, timed_out, stats, ru.ru_maxrss


def classify(rc, err, timed_out, stats):
    lines = [l for l in err.strip().splitlines() if l.strip()]
    if timed_out:
        return "FAIL", "timeout"
    if rc < 0:
        return "FAIL", f"killed by signal {-rc}: {lines[-1] if lines else ''}"
    if rc == 2:
        if len(lines) == 1 and lines[0].startswith("error: "):
            return "input-error", lines[0][7:][:110]
        return "FAIL", "exit 2 without one clear error line: " + " / ".join(lines)[:110]
    if rc != 0:
        return "FAIL", f"exit {rc}: " + " / ".join(lines)[:110]
    try:
        with open(stats) as f:
            s = json.load(f)
    except (OSError, ValueError) as e:
        return "FAIL", f"no stats: {e}"
    if s["nonfinite_samples"] or s["nonfinite_values"] or s.get("lost_paths"):
        return "FAIL", (f"{s['nonfinite_samples']} non-finite samples, {s['nonfinite_values']} non-finite values, "
                        f"{s.get('lost_paths', 0)} lost paths")
    media = "media" if s.get("has_media") else "no media"
    return "ok", f"mean {s['mean'][0]:.3g} {s['mean'][1]:.3g} {s['mean'][2]:.3g}; {media}"


if __name__ == "__main__":
    sys.exit(main())
