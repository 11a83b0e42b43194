"""The aggregate build cache through `granular render`: a render that takes its aggregates
from the cache is the first render bit for bit; two renders filling one empty cache at once
both succeed with the same image; a damaged entry is named once and rebuilt."""
import os
import sys
import subprocess

import numpy as np
from conftest import BUILD, EXAMPLES, GRANULAR, ROOT

import granular_core as core

SCENE = EXAMPLES / "sugarcube.usda"
ARGS = ["--width", 40, "--spp", 2, "--seed", 3]


def _command(out):
    exe = [str(GRANULAR)] if GRANULAR.exists() else [sys.executable, "-m", "granular.cli"]
    return exe + ["render", str(SCENE)] + [str(a) for a in ARGS] + ["-o", str(out)]


def _env(cache):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "python"), str(BUILD / "python")])
    env["GRANULAR_CACHE_DIR"] = str(cache)
    env.pop("GRANULAR_CACHE_MAX_MB", None)
    return env


def _render(cache, out):
    p = subprocess.run(_command(out), capture_output=True, text=True, env=_env(cache))
    assert p.returncode == 0, p.stderr
    return p


def _same_pixels(a, b):
    ia, ib = core.read_exr(str(a)), core.read_exr(str(b))
    assert (ia.width, ia.height, list(ia.channels)) == (ib.width, ib.height, list(ib.channels))
    assert np.array_equal(np.asarray(ia.pixels).view(np.uint32), np.asarray(ib.pixels).view(np.uint32))


def _entries(cache):
    return sorted(cache.glob("build-*.bin"))


def test_a_render_from_the_cache_is_bit_identical(tmp_path):
    cache = tmp_path / "cache"
    cache.mkdir()
    first = _render(cache, tmp_path / "cold.exr")
    assert _entries(cache), "the first render stores its aggregates' builds"
    second = _render(cache, tmp_path / "warm.exr")
    assert "build cache" not in first.stderr + second.stderr
    # What the first render waited for, and that the second did not.
    assert "waiting for aggregate /World/SugarCube: building its distance field" in first.stderr, first.stderr
    assert "waiting for" not in second.stderr
    _same_pixels(tmp_path / "cold.exr", tmp_path / "warm.exr")
    # With the build cache off, the same image again.
    env = _env(cache)
    env["GRANULAR_CACHE_MAX_MB"] = "0"
    p = subprocess.run(_command(tmp_path / "off.exr"), capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    _same_pixels(tmp_path / "cold.exr", tmp_path / "off.exr")


def test_two_renders_filling_an_empty_cache_both_succeed(tmp_path):
    cache = tmp_path / "cache"
    cache.mkdir()
    procs = [subprocess.Popen(_command(tmp_path / f"r{k}.exr"), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env=_env(cache)) for k in range(2)]
    results = [p.communicate(timeout=600) for p in procs]
    for p, (out, err) in zip(procs, results):
        assert p.returncode == 0, err
        assert "build cache" not in err
    _same_pixels(tmp_path / "r0.exr", tmp_path / "r1.exr")
    assert not list(cache.glob("*.tmp*")), "no temporary file is left behind"
    # What they left is a valid entry: a third render takes it silently, the same image.
    third = _render(cache, tmp_path / "r2.exr")
    assert "build cache" not in third.stderr
    _same_pixels(tmp_path / "r0.exr", tmp_path / "r2.exr")


def test_a_damaged_entry_is_named_once_and_rebuilt(tmp_path):
    cache = tmp_path / "cache"
    cache.mkdir()
    _render(cache, tmp_path / "a.exr")
    entries = _entries(cache)
    assert entries
    size = entries[0].stat().st_size
    with open(entries[0], "r+b") as f:
        f.truncate(size // 2)
    p = _render(cache, tmp_path / "b.exr")
    damaged = [line for line in p.stderr.splitlines() if "build cache" in line]
    assert len(damaged) == 1, p.stderr
    assert damaged[0].startswith("warning:") and str(entries[0]) in damaged[0] and "damaged" in damaged[0]
    assert entries[0].stat().st_size == size, "the rebuilt entry replaced it"
    _same_pixels(tmp_path / "a.exr", tmp_path / "b.exr")
    assert "build cache" not in _render(cache, tmp_path / "c.exr").stderr
