#!/usr/bin/env python3
"""Seed corpora for the fuzz targets: python3 fuzz/seed_corpus.py OUT

OUT/fuzz_scene_json/      examples/*.json, bench/scenes/*.json, the full scene of
                          tests/core/test_scene_io.cpp and bench/stress.py's base case
OUT/fuzz_usd_attributes/  a few well-formed inputs in fuzz_usd_attributes.cpp's layout:
                          a box and a tetrahedron with sane attributes, each light type (distant, sphere, rect, dome, disk, cylinder, mesh)
OUT/fuzz_usd_prims/       well-formed inputs in fuzz_usd_prims.cpp's layout: an aggregate
                          (box boundary, prototype by a relative path) with its grain
                          prototype listed or found through the lookup, each light type (a mesh light too)
OUT/fuzz_ies/             IES profiles: each symmetry of type C, a tilt table, commas
fuzz/regressions/         inputs that once crashed a target (*.json: the JSON target,
                          usd_attributes_*.bin, prims_*.bin: the USD targets), replayed by every run
"""
import glob
import json
import os
import re
import struct
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

BOX = [(x, y, z) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)]
QUADS = [0, 4, 6, 2, 1, 3, 7, 5, 0, 1, 5, 4, 2, 6, 7, 3, 0, 2, 3, 1, 4, 5, 7, 6]
TET = [(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)]
TRIS = [0, 1, 2, 0, 3, 1, 0, 2, 3, 1, 3, 2]


def copy_regressions(pattern, out):
    """Copies fuzz/regressions/PATTERN into out as regression_*; returns the count."""
    n = 0
    for path in sorted(glob.glob(os.path.join(ROOT, "fuzz/regressions", pattern))):
        with open(path, "rb") as f, open(os.path.join(out, "regression_" + os.path.basename(path)), "wb") as g:
            g.write(f.read())
        n += 1
    return n


def view_and_light(light_type):
    """fuzz_common.h's readViewAndLight: a camera at z = 4 looking down -z, a light above
    (each type's parameters sane), a 5 x 4 image."""
    b = bytearray(struct.pack("<16f", 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 4, 0, 0, 0, 1))
    b += struct.pack("<7f", 35, 36, 24, 0, 0, 0.01, 100)
    b += struct.pack("<B16f", light_type, 1, 0, 0, 0, 0, 1, 0, 2, 0, 0, 1, 0, 0, 0, 0, 1)
    b += struct.pack("<3f6fB", 1, 1, 1, 2, 0, 0.53, 0.5, 1, 1, 0)
    # length; shaping on for the area lights of odd type (sphere, dome: ignored, cylinder),
    # a 60° cone of softness 0.3, focus 2, a grey tint
    b += struct.pack("<fB3f3f", 1, light_type % 2 if light_type < 255 else 0, 60, 0.3, 2, 0.2, 0.2, 0.2)
    # light linking: none, to every object, to none, by type
    b += struct.pack("<B", (0, 3, 1)[light_type % 3])
    b += struct.pack("<BB", 5, 4)
    return b


def material(dielectric):
    """fuzz_common.h's readMaterial: a sand-like dielectric or a grey Lambert."""
    return struct.pack("<B3ff3f3f", 1 if dielectric else 0, 0.5, 0.5, 0.5, 1.5, 0.1, 0.2, 0.4, 0, 0, 0)


def json_seeds(out):
    os.makedirs(out, exist_ok=True)
    n = 0
    for pattern in ("examples/*.json", "bench/scenes/*.json"):
        for path in sorted(glob.glob(os.path.join(ROOT, pattern))):
            with open(path, "rb") as f:
                data = f.read()
            with open(os.path.join(out, os.path.basename(path)), "wb") as f:
                f.write(data)
            n += 1
    for test in ("test_scene_io", "test_light_linking"):
        with open(os.path.join(ROOT, f"tests/core/{test}.cpp")) as f:
            src = f.read()
        for k, m in enumerate(re.finditer(r'R"\((.*?)\)"', src, re.S)):
            with open(os.path.join(out, f"{test}_{k}.json"), "w") as f:
                f.write(m.group(1))
            n += 1
    n += copy_regressions("*.json", out)
    sys.path.insert(0, os.path.join(ROOT, "bench"))
    import stress  # noqa: E402
    with open(os.path.join(out, "stress_base.json"), "w") as f:
        json.dump(stress.BASE, f)
    return n + 1


def usd_seed(points, counts, indices, light_type, dielectric=True):
    b = bytearray()
    b += struct.pack("<B", len(points))
    for p in points:
        b += struct.pack("<3f", *p)
    b += struct.pack("<B", len(counts))
    b += struct.pack(f"<{len(counts)}b", *counts)
    b += struct.pack("<H", len(indices))
    b += struct.pack(f"<{len(indices)}h", *indices)
    identity = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
    b += struct.pack("<16f", *identity)                       # aggregate xf
    b += struct.pack("<ffQi", 0.2, 0.5, 1, 16)                 # grainRadius, packingRate, seed, tileSpheres
    b += struct.pack("<B2f", 2, 1.0, 0.5)                      # weights
    b += material(dielectric) + view_and_light(light_type)
    return bytes(b)


def usd_seeds(out):
    os.makedirs(out, exist_ok=True)
    n = 0
    for lt in (0, 1, 2, 3, 4, 5, 255):  # 255: a mesh light
        with open(os.path.join(out, f"box_light{lt}.bin"), "wb") as f:
            f.write(usd_seed(BOX, [4] * 6, QUADS, lt))
        with open(os.path.join(out, f"tet_light{lt}.bin"), "wb") as f:
            f.write(usd_seed(TET, [3] * 4, TRIS, lt, dielectric=lt % 2 == 0))
        n += 2
    return n + copy_regressions("usd_attributes_*.bin", out)


# fuzz_usd_prims.cpp's pick lists: the index of an entry.
PATHS = ["/World/Castle", "/World/Grains/Round", "/World/Grains/Flat", "/World/Floor", "../Grains/Round"]
NAMES = ["grainRadius", "packingRate", "prototypes", "weights", "seed", "tileSpheres", "ior", "absorption",
         "roughness", "unknownName", "Mesh", "Cube", "Sphere", "Xform", "GranularAggregateAPI", "GranularGrainAPI"]
TYPES = ["float", "double", "half", "int", "int64", "uint", "uchar", "float[]", "double[]", "half[]", "string[]"]


def prims_mesh(points, counts, indices):
    b = bytearray(struct.pack("<B", len(points)))
    for p in points:
        b += struct.pack("<3f", *p)
    b += struct.pack("<B", len(counts)) + struct.pack(f"<{len(counts)}b", *counts)
    b += struct.pack("<B", len(indices)) + struct.pack(f"<{len(indices)}b", *indices)
    return b


def prims_primvar(name, typ, numbers=(), strings=(), is_array=False, is_string=False):
    b = bytearray(struct.pack("<BBB", NAMES.index(name), TYPES.index(typ), (1 if is_array else 0) | (2 if is_string else 0)))
    b += struct.pack("<B", 0)  # interpolation "constant"
    b += struct.pack("<B", len(numbers)) + struct.pack(f"<{len(numbers)}f", *numbers)
    b += struct.pack("<B", len(strings)) + bytes(PATHS.index(p) for p in strings)
    return b


def prims_prim(path, api, visible, material, mesh, primvars):
    b = bytearray(struct.pack("<BB", PATHS.index(path), NAMES.index("Mesh")))
    b += struct.pack("<B", 1 | (2 if visible else 0) | 4)
    b += struct.pack("<BB", 1, NAMES.index(api))
    b += struct.pack("<b", material) + mesh + struct.pack("<B", 0)  # no instances
    b += struct.pack("<B", len(primvars)) + b"".join(primvars)
    return b


def prims_seed(light_type, lookup):
    b = bytearray(struct.pack("<B", 1)) + material(True)  # one material: a dielectric
    castle = prims_prim("/World/Castle", "GranularAggregateAPI", True, -1, prims_mesh(BOX, [4] * 6, QUADS), [
        prims_primvar("grainRadius", "float", [0.2]),
        prims_primvar("prototypes", "string[]", strings=["../Grains/Round"], is_array=True, is_string=True),
        prims_primvar("tileSpheres", "int", [16])])
    grain = prims_prim("/World/Grains/Round", "GranularGrainAPI", False, 0, prims_mesh(TET, [3] * 4, TRIS),
                       [prims_primvar("ior", "float", [1.5])])
    # The listed count is read as 1 + byte % 4, the looked-up count as byte % 3.
    if lookup:
        b += struct.pack("<B", 0) + castle + struct.pack("<B", 1) + grain
    else:
        b += struct.pack("<B", 1) + castle + grain + struct.pack("<B", 0)
    b += view_and_light(light_type)
    return bytes(b)


def prims_seeds(out):
    os.makedirs(out, exist_ok=True)
    n = 0
    for lt in (0, 1, 2, 3, 4, 5, 255):  # 255: a mesh light
        for lookup in (False, True):
            with open(os.path.join(out, f"castle_light{lt}{'_lookup' if lookup else ''}.bin"), "wb") as f:
                f.write(prims_seed(lt, lookup))
            n += 1
    return n + copy_regressions("prims_*.bin", out)


def ies_seeds(out):
    """Profiles of each horizontal symmetry, one with a tilt table and commas; returns the count."""
    os.makedirs(out, exist_ok=True)
    head = "IESNA:LM-63-2002\n[TEST] seed\nTILT={tilt}\n1 -1 1 {nv} {nh} 1 2 0 0 0\n1 1 10\n"
    seeds = [("0 45 90", "0", "100 50 0", "NONE"),
             ("0 90", "0 45 90", "10 0 20 0 40 0", "NONE"),
             ("0 90 180", "0 90 180", "1 2 3 4 5 6 7 8 9", "NONE"),
             ("0 90", "90 180 270", "1 1 2 2 3 3", "NONE"),
             ("0,60,120,180", "0,90,180,270", "8,4,2,1,2,6,1,3,5,5,0,9,1,7,3,3", "INCLUDE\n1\n2\n0 90\n1 0.5")]
    for i, (v, h, c, tilt) in enumerate(seeds):
        nv, nh = len(v.replace(",", " ").split()), len(h.replace(",", " ").split())
        with open(os.path.join(out, f"seed_{i}.ies"), "w") as f:
            f.write(head.format(tilt=tilt, nv=nv, nh=nh) + f"{v}\n{h}\n{c}\n")
    return len(seeds)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = sys.argv[1]
    a = json_seeds(os.path.join(out, "fuzz_scene_json"))
    b = usd_seeds(os.path.join(out, "fuzz_usd_attributes"))
    c = prims_seeds(os.path.join(out, "fuzz_usd_prims"))
    d = ies_seeds(os.path.join(out, "fuzz_ies"))
    print(f"seed corpus: {a} JSON scenes, {b} USD attribute inputs, {c} USD prim inputs, {d} IES profiles in {out}")


if __name__ == "__main__":
    main()
