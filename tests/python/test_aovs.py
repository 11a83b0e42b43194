"""The compositing AOVs of `granular render`: sampleCount, variance, instanceId and
aggregateId, and `--cryptomatte`'s layers decoded independently of our writer: the EXR
header is parsed here byte by byte, ids are hashed by this file's own MurmurHash3 (checked
against the published vectors, and against the mmh3 package where it is installed), and
the masks are decoded as a compositor would, from the manifest alone."""
import json
import struct

import numpy as np
import pytest
from conftest import EXAMPLES, core, run_cli, small_scene
from pxr import Gf, Usd, UsdGeom, UsdLux, Vt


# ---- an independent MurmurHash3_x86_32 and the spec's float conversion -----------------------

def murmur3_32(data: bytes, seed: int = 0) -> int:
    def rotl(x, r):
        return ((x << r) | (x >> (32 - r))) & 0xFFFFFFFF

    c1, c2 = 0xCC9E2D51, 0x1B873593
    h = seed & 0xFFFFFFFF
    n = len(data) // 4
    for i in range(n):
        k = int.from_bytes(data[4 * i:4 * i + 4], "little")
        k = rotl((k * c1) & 0xFFFFFFFF, 15) * c2 & 0xFFFFFFFF
        h = (rotl(h ^ k, 13) * 5 + 0xE6546B64) & 0xFFFFFFFF
    tail = data[4 * n:]
    if tail:
        k = int.from_bytes(tail, "little")
        h ^= rotl((k * c1) & 0xFFFFFFFF, 15) * c2 & 0xFFFFFFFF
    h ^= len(data)
    h ^= h >> 16
    h = (h * 0x85EBCA6B) & 0xFFFFFFFF
    h ^= h >> 13
    h = (h * 0xC2B2AE35) & 0xFFFFFFFF
    return h ^ (h >> 16)


def crypto_id(name: str) -> int:
    """The id's float32 bits: the hash, its exponent clamped to [1, 254] (the spec)."""
    h = murmur3_32(name.encode("utf-8"))
    exponent = min(max((h >> 23) & 0xFF, 1), 254)
    return (h & 0x807FFFFF) | (exponent << 23)


def float_bits(a):
    return np.ascontiguousarray(a, dtype=np.float32).view(np.uint32)


def test_our_murmur3_reproduces_the_published_vectors():
    assert murmur3_32(b"", 0) == 0
    assert murmur3_32(b"", 1) == 0x514E28B7
    assert murmur3_32(b"", 0xFFFFFFFF) == 0x81F16F39
    assert murmur3_32(b"\0\0\0\0", 0) == 0x2362F9DE
    for key, want in [(b"aaaa", 0x5A97808A), (b"aaa", 0x283E0130), (b"aa", 0x5D211726), (b"a", 0x7FA09EA6),
                      (b"abcd", 0xF0478627), (b"abc", 0xC84A62DD), (b"ab", 0x74875592),
                      (b"Hello, world!", 0x24884CBA),
                      (b"The quick brown fox jumps over the lazy dog", 0x2FA826CD)]:
        assert murmur3_32(key, 0x9747B28C) == want, key
    # The specification's own manifest example.
    assert "%08x" % crypto_id("bunny") == "13851a76"
    assert "%08x" % crypto_id("bunny_porcelain_mat") == "b24b26d4"
    try:
        import mmh3
    except ImportError:
        return
    for s in ["/World/Castle", "/World/Floor", "ünïcode", "x" * 37]:
        assert murmur3_32(s.encode()) == mmh3.hash(s.encode(), 0, signed=False)


# ---- reading an EXR header without our reader ------------------------------------------------

def exr_string_attributes(path):
    """The string attributes of a single-part OpenEXR header (OpenEXR's file layout)."""
    data = open(path, "rb").read()
    assert struct.unpack_from("<I", data, 0)[0] == 20000630, "not an OpenEXR file"
    pos, attrs = 8, {}

    def cstring(p):
        end = data.index(b"\0", p)
        return data[p:end].decode("utf-8"), end + 1

    while True:
        name, pos = cstring(pos)
        if not name:
            return attrs
        kind, pos = cstring(pos)
        size = struct.unpack_from("<i", data, pos)[0]
        pos += 4
        if kind == "string":
            attrs[name] = data[pos:pos + size].decode("utf-8")
        pos += size


def _floor(stage):
    floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
    floor.CreatePointsAttr(Vt.Vec3fArray([(-3, 0, -3), (3, 0, -3), (3, 0, 3), (-3, 0, 3)]))
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    floor.CreateDisplayColorAttr([(0.4, 0.4, 0.4)])


def _render(tmp_path, capsys, stage_path, *extra):
    out = tmp_path / "out.exr"
    rc, _, err = run_cli(["render", stage_path, "-o", out, "--width", 48, "--height", 32, "--spp", 4,
                          "--technique", "ept", "--quiet", *extra], capsys)
    assert rc == 0, err
    im = core.read_exr(str(out))
    return out, np.asarray(im.pixels), list(im.channels)


def test_cryptomatte_layers_decode_to_the_objects_where_their_ids_say(tmp_path, capsys):
    path, px, ch = _render(tmp_path, capsys, small_scene(tmp_path / "s.usda", _floor), "--cryptomatte")
    attrs = exr_string_attributes(path)
    c = {n: px[..., ch.index(n)] for n in ch}
    alpha = c["A"]
    masks = {}
    for kind, expected_names in [("CryptoObject", {"/World/Castle", "/World/Floor"}),
                                 ("CryptoMaterial", {"/World/Grains/A", "/World/Grains/B",
                                                     "/World/Floor.displayColor"})]:
        key = "%08x" % murmur3_32(kind.encode())
        prefix = f"cryptomatte/{key[:7]}/"
        assert attrs[prefix + "name"] == kind
        assert attrs[prefix + "hash"] == "MurmurHash3_32"
        assert attrs[prefix + "conversion"] == "uint32_to_float32"
        manifest = json.loads(attrs[prefix + "manifest"])
        assert set(manifest) == expected_names, manifest
        for name, hexid in manifest.items():
            assert hexid == "%08x" % crypto_id(name), name
        # Ranks 0..5 in three RGBA layers: (id, coverage, id, coverage).
        ranks = []
        for layer in ("00", "01", "02"):
            n = kind + layer
            ranks += [(c[n + ".R"], c[n + ".G"]), (c[n + ".B"], c[n + ".A"])]
        coverage = sum(cov for _, cov in ranks)
        np.testing.assert_allclose(coverage, alpha, atol=1e-6, err_msg=kind)  # misses count nowhere
        for name, hexid in manifest.items():
            want = np.uint32(int(hexid, 16))
            masks[name] = sum(np.where(float_bits(i) == want, cov, 0.0) for i, cov in ranks)
        # Everything ranked is in the manifest (or an empty rank).
        known = {np.uint32(int(h, 16)) for h in manifest.values()}
        for i, cov in ranks:
            bits = float_bits(i)[cov > 0]
            assert all(b in known for b in np.unique(bits)), kind
    # Each object's whole pixels carry one primId, its own; the castle's is its aggregateId.
    ids = {}
    for name in ("/World/Castle", "/World/Floor"):
        whole = masks[name] == 1.0
        assert whole.sum() > 20, name
        prim = np.unique(c["primId"][whole])
        assert len(prim) == 1 and prim[0] >= 0, (name, prim)
        ids[name] = prim[0]
        agg = np.unique(c["aggregateId"][whole])
        assert list(agg) == ([prim[0]] if name == "/World/Castle" else [-1]), (name, agg)
        # Where the primId AOV says this object, the mask covers the pixel's first hit.
        assert np.all(masks[name][c["primId"] == prim[0]] > 0), name
    assert ids["/World/Castle"] != ids["/World/Floor"]
    np.testing.assert_array_equal(c["instanceId"], -1.0)
    # The material masks of the grains add up to the castle's object mask.
    np.testing.assert_allclose(masks["/World/Grains/A"] + masks["/World/Grains/B"], masks["/World/Castle"],
                               atol=1e-6)


def test_sample_count_and_variance_and_no_cryptomatte_unless_asked(tmp_path, capsys):
    path, px, ch = _render(tmp_path, capsys, small_scene(tmp_path / "s.usda", _floor))
    assert not any(n.startswith("Crypto") for n in ch)
    assert not any(k.startswith("cryptomatte/") for k in exr_string_attributes(path))
    np.testing.assert_array_equal(px[..., ch.index("sampleCount")], 4.0)
    for n in ("variance.R", "variance.G", "variance.B"):
        v = px[..., ch.index(n)]
        assert np.all(np.isfinite(v)) and np.all(v >= 0), n
        assert v.max() > 0, n  # a sunlit aggregate is noisy somewhere
    # Four non-negative samples of mean m have a sample variance of at most 4 m^2 (all in
    # one sample: ((3m)^2 + 3 m^2) / 3), so the variance of their mean is at most m^2.
    for n in ("R", "G", "B"):
        v = px[..., ch.index("variance." + n)]
        m = px[..., ch.index(n)]
        assert np.all(v <= m ** 2 * (1 + 1e-5) + 1e-9), n


def _instanced(path):
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    UsdGeom.Xformable(cam).AddTranslateOp().Set(Gf.Vec3d(0, 0, 15))
    UsdLux.DomeLight.Define(stage, "/World/Sky")
    inst = UsdGeom.PointInstancer.Define(stage, "/World/Inst")
    cube = UsdGeom.Cube.Define(stage, "/World/Inst/Protos/Box")
    cube.CreateSizeAttr(2.0)
    inst.CreatePrototypesRel().SetTargets([cube.GetPath()])
    inst.CreatePositionsAttr(Vt.Vec3fArray([Gf.Vec3f(-3, 0, 0), Gf.Vec3f(0, 9, 0), Gf.Vec3f(3, 0, 0)]))
    inst.CreateProtoIndicesAttr(Vt.IntArray([0, 0, 0]))
    inst.CreateIdsAttr(Vt.Int64Array([0, 1, 2]))
    inst.CreateInvisibleIdsAttr(Vt.Int64Array([1]))
    stage.Save()
    return str(path)


def test_instance_ids_are_the_point_instancers_indices(tmp_path, capsys):
    _, px, ch = _render(tmp_path, capsys, _instanced(tmp_path / "i.usda"))
    inst = px[..., ch.index("instanceId")]
    alpha = px[..., ch.index("A")]
    assert set(np.unique(inst)) == {-1.0, 0.0, 2.0}  # instance 1 is invisible
    np.testing.assert_array_equal(inst[alpha == 0], -1.0)
    xs = np.arange(inst.shape[1])[None, :].repeat(inst.shape[0], 0)
    assert xs[inst == 0].max() < inst.shape[1] / 2 < xs[inst == 2].min()  # left, right
    np.testing.assert_array_equal(px[..., ch.index("aggregateId")], -1.0)


if __name__ == "__main__":
    pytest.main([__file__])


def test_the_castles_aggregates_cover_its_pixels_once(tmp_path, capsys):
    # The sand castle example (castle aggregates on a floor, under a sun and a sky): where the
    # castle covers a pixel, its aggregates' object masks, decoded through the manifest, add
    # up to its coverage, and every covered pixel's masks add up to 1.
    out = tmp_path / "castle.exr"
    rc, _, err = run_cli(["render", EXAMPLES / "sandcastle.usda", "-o", out, "--width", 40, "--spp", 2,
                          "--quiet", "--cryptomatte"], capsys)
    assert rc == 0, err
    im = core.read_exr(str(out))
    px, ch = np.asarray(im.pixels), list(im.channels)
    c = {n: px[..., ch.index(n)] for n in ch}
    attrs = exr_string_attributes(out)
    key = "%08x" % murmur3_32(b"CryptoObject")
    manifest = json.loads(attrs[f"cryptomatte/{key[:7]}/manifest"])
    ranks = []
    for layer in ("00", "01", "02"):
        n = "CryptoObject" + layer
        ranks += [(c[n + ".R"], c[n + ".G"]), (c[n + ".B"], c[n + ".A"])]
    masks = {name: sum(np.where(float_bits(i) == np.uint32(int(h, 16)), cov, 0.0) for i, cov in ranks)
             for name, h in manifest.items()}
    covered = c["A"] == 1.0
    total = sum(masks.values())
    np.testing.assert_allclose(total[covered], 1.0, atol=1e-6)
    castle = [m for name, m in masks.items() if name.startswith("/World/Castle")]
    assert len(castle) >= 2, sorted(manifest)
    # The castle's pixels: those its aggregates are the first hit of some sample in.
    assert (sum(castle) > 0).sum() > 50
