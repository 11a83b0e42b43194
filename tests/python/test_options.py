"""Bad command-line values: every option of every command refuses them with exit status 2
and one line `error: command line.OPTION: message`, no traceback and no file written."""
import socket

import pytest
from conftest import run_cli, run_script, small_scene

from granular import farm

SMALL = ["--width", "16", "--height", "12", "--spp", "1", "--quiet"]
LONG = "a" * 260

RENDER = ["render", "{scene}", "-o", "{out}/o.exr", "--png", "{out}/o.png", *SMALL]
FRAMES = ["render", "{scene}", "-o", "{out}/o.####.exr", "--png", "{out}/o.####.png", *SMALL]
MERGE = ["merge", "{out}/t.exr", "-o", "{out}/m.exr", "--png", "{out}/m.png", "--quiet"]
# Farm jobs point at a port where no scheduler listens, so that a value refused only after
# parsing never starts a LocalCluster.
FARM_HERE = ["farm", "{scene}", "-o", "{out}/f.####.exr", "--png", "{out}/f.####.png", "--frames", "1", *SMALL]
FARM = [*FARM_HERE, "--scheduler", "{dead}"]
VDB = ["export-vdb", "{scene}", "--prim", "/World/Castle", "-o", "{out}/d.vdb", "--quiet"]


def _bad(base, option, values, words=""):
    """One case per value of `option` appended to `base` (argparse keeps the last one)."""
    return [(base, [f"{option}={v}" if v.startswith("-") else option, *([] if v.startswith("-") else [v])],
             option, words) for v in values]


CASES = [
    # Numbers: not a number, not finite, out of range, not representable.
    *_bad(RENDER, "--spp", ["0", "-1", "nan", "inf", "1.5", "x", "", "1000001"]),
    *_bad(RENDER, "--width", ["0", "-5", "nan", "1e3", "32769"]),
    *_bad(RENDER, "--height", ["0", "inf", "abc"]),
    *_bad(RENDER, "--threads", ["-1", "1025", "2.5"]),
    *_bad(RENDER, "--seed", ["-1", "2147483648", "nan"]),
    *_bad(RENDER, "--exposure", ["nan", "inf", "-inf", "101", "-101", "1e300", "x"]),
    *_bad(RENDER, "--roulette", ["0", "8.5", "nan", "inf", "-inf", "1e-300", "x"]),
    *_bad(RENDER, "--lod", ["-1", "nan", "inf", "1e39", "x"], ""),
    *_bad(RENDER, "--noise-threshold", ["0", "-0.1", "nan", "inf", "1.5", "x"]),
    *_bad(RENDER, "--time-limit", ["0", "-1", "nan", "inf", "1e8", "x"]),
    *_bad(RENDER, "--technique", ["foo", "EPT", ""], "invalid choice"),
    *_bad(RENDER, "--proxies", ["sometimes", "ON", ""], "invalid choice"),
    *_bad(RENDER, "--camera", ["", "World/Camera", "not a path", "/World/Camera.focalLength"],
          "is not an absolute prim path"),
    (RENDER, ["--camera", "/World/Nope"], "--camera", "is not a prim of the stage"),
    *_bad(RENDER, "--crop", ["1:2", "5:5,0:3", "a:b,0:3", "-1:3,0:3", "0:2,0:2,0:2"]),
    (RENDER, ["--crop", "0:17,0:1"], "--crop", "reaches outside the 16x12 image"),
    # Frame ranges and the file names they make.
    *_bad(FRAMES, "--frames", ["3:1", "1:3x0", "1:3x-1", "nan", "1:inf", "", "1x2", "1:2x", "1:1000000",
                               "-1e308:1e308", "1:2x1e-320", "1e300"]),
    (RENDER, ["--frames", "1:2"], "-o", "has no run of '#'"),
    (["render", "{scene}", "-o", "{out}/o.####.exr", "--png", "{out}/o.png", *SMALL], ["--frames", "1:2"],
     "--png", "has no run of '#'"),
    # Outputs.
    (RENDER, ["-o", "{out}/o.png"], "-o", "must end in .exr"),
    (RENDER, ["-o", "{out}/missing/o.exr"], "-o", "does not exist"),
    (RENDER, ["-o", "{out}"], "-o", ""),
    (RENDER, ["-o", ""], "-o", "must end in .exr"),
    (RENDER, ["-o", "{out}/" + LONG + ".exr"], "-o", "more than"),
    (RENDER, ["--png", "{out}/o.jpg"], "--png", "must end in .png"),
    (RENDER, ["--png", "{out}/" + LONG + ".png"], "--png", "more than"),
    # The shape of the command line.
    (RENDER, ["--quiet=1"], "--quiet", "ignored explicit argument"),
    (RENDER, ["--spp"], "--spp", "expected one argument"),
    (RENDER, ["--exposure", "-1e3"], "--exposure", "write --exposure=VALUE"),
    (RENDER, ["--frobnicate", "3"], "--frobnicate", "is not an option"),
    (["render", "{scene}"], [], "-o", "is required"),
    (["bogus"], [], "COMMAND", "invalid choice"),
    ([], [], "COMMAND", "is required"),
    # merge
    *_bad(MERGE, "--exposure", ["nan", "inf", "101", "x"]),
    (MERGE, ["-o", "{out}/m.png"], "-o", "must end in .exr"),
    (MERGE, ["--png", "{out}/m.exr"], "--png", "must end in .png"),
    (MERGE, ["--crop", "0:1,0:1"], "--crop", "is not an option"),
    # farm: its own options, the render options it shares, and its outputs.
    *_bad(FARM, "--scheduler", ["not an address", "", "x", "tcp://h", "tcp://h:0", "tcp://h:65536", "tcp://h:port",
                                "tls://h:8786", "tcp://[::g]:8786", "tcp://h:8786/x"],
          "is not a scheduler address (tcp://HOST:PORT)"),
    *_bad(FARM_HERE, "--workers", ["0", "1025", "x", "-2"]),
    (FARM, ["--workers", "2"], "--workers", "not allowed with argument --scheduler"),
    *_bad(FARM, "--tiles", ["0", "4097", "x", "-3"]),
    (FARM, ["--tiles", "193"], "--tiles", "193 tiles are more than the 16x12 pixels"),
    *_bad(FARM, "--retries", ["-1", "101", "x"]),
    *_bad(FARM, "--frames", ["3:1", "nan", "1e300"]),
    (FARM, ["-o", "{out}/f.exr"], "-o", "has no run of '#'"),
    (["farm", "{scene}", "-o", "{out}/f.####.exr", "--scheduler", "{dead}"], [], "--frames", "is required"),
    *_bad(FARM, "--spp", ["0", "nan"]),
    *_bad(FARM, "--technique", ["foo"]),
    *_bad(FARM, "--roulette", ["9"]),
    *_bad(FARM, "--exposure", ["inf"]),
    *_bad(FARM, "--camera", [""]),
    (FARM, ["--camera", "/World/Nope"], "--camera", "is not a prim of the stage"),
    (FARM, ["--crop", "0:1,0:1"], "--crop", "is not an option"),
    # info
    (["info", "{scene}"], ["--json=1"], "--json", "ignored explicit argument"),
    (["info"], [], "SCENE", "is required"),
    # export-vdb
    *_bad(VDB, "--voxel-size", ["0", "-1", "nan", "inf", "1e300", "1e-50", "x"]),
    *_bad(VDB, "--prim", ["", "World/Castle", "/World/Castle.points"], "is not an absolute prim path"),
    (VDB, ["--prim", "/World/Nope"], "--prim", "is not a prim of the stage"),
    (VDB, ["-o", "{out}/d.exr"], "-o", "must end in .vdb"),
    (["export-vdb", "{scene}", "-o", "{out}/d.vdb"], [], "--prim", "is required"),
]


def _id(case):
    base, extra, option, _ = case
    return " ".join([*base[:1], option, *(a.replace("{out}/", "") for a in extra if a != option)])[:60]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return small_scene(tmp_path_factory.mktemp("scene") / "scene.usda")


@pytest.fixture(scope="module")
def dead():
    """tcp://127.0.0.1:PORT where nothing listens."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{s.getsockname()[1]}"


@pytest.fixture
def quick_connect(monkeypatch):
    monkeypatch.setattr(farm, "CONNECT_TIMEOUT", "1s")


def _check(rc, err, option, words, out):
    lines = err.strip().splitlines()
    assert rc == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"error: command line.{option}: "), lines[0]
    assert words in lines[0], lines[0]
    assert "Traceback" not in err
    assert not list(out.iterdir()), f"left behind: {list(out.iterdir())}"


@pytest.mark.parametrize("case", CASES, ids=[_id(c) for c in CASES])
def test_a_bad_value_names_its_option(case, scene, dead, tmp_path, capsys, quick_connect):
    base, extra, option, words = case
    argv = [a.format(scene=scene, out=tmp_path, dead=dead) for a in (*base, *extra)]
    rc, _, err = run_cli(argv, capsys)
    _check(rc, err, option, words, tmp_path)


def test_an_unreachable_scheduler_names_the_option(scene, dead, tmp_path, capsys, quick_connect):
    argv = [a.format(scene=scene, out=tmp_path, dead=dead) for a in FARM]
    rc, _, err = run_cli(argv, capsys)
    _check(rc, err, "--scheduler", f"cannot reach {dead}: ", tmp_path)


def test_the_installed_script_refuses_a_bad_scheduler(scene, tmp_path):
    r = run_script(["farm", scene, "-o", tmp_path / "f.####.exr", "--frames", "1", "--scheduler", "not an address"],
                   timeout=120)
    assert r.returncode == 2, r.stderr
    assert r.stderr.splitlines() == ["error: command line.--scheduler: 'not an address' is not a scheduler address "
                                     "(tcp://HOST:PORT)"]
    assert not list(tmp_path.iterdir())
