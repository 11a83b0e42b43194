"""The C++ command line `granular-render` (JSON scenes) and motion blur: --no-motion-blur
renders the frame's instant, as the render setting "motion_blur": false and `granular
render --no-motion-blur` do. A box that slides over the camera's open shutter and two glass
grains moving apart vertically: with the switch, the image is the still frame's (the same
description: bit for bit at the same seed, within noise at another) and differs from the
blurred one far beyond noise (noise_check.py)."""
import copy
import json
import subprocess

import pytest
from conftest import BUILD
from noise_check import block_chi2, noise_limit, rgb_and_variance

EXE = BUILD / "core" / "granular-render"
WIDTH, HEIGHT, SPP = 48, 32, 16

# The shutter is open 1/24 s about the frame; the box slides 1.2 units over it, each grain
# 0.8 units.
MOVING = {
    "render": {"width": WIDTH, "height": HEIGHT, "spp": SPP, "seed": 0},
    "camera": {"look_at": {"eye": [0, 1.2, 3.2], "target": [0, 0.3, 0], "up": [0, 1, 0]},
               "focal_length": 35, "horizontal_aperture": 36, "vertical_aperture": 24,
               "shutter_open": -1 / 48, "shutter_close": 1 / 48},
    "materials": {"glass": {"type": "dielectric", "ior": 1.5, "absorption": [0.5, 1.0, 2.0]},
                  "floor": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]},
                  "paint": {"type": "lambert", "albedo": [0.9, 0.3, 0.1]}},
    "meshes": [{"name": "floor", "shape": {"box": {"lo": [-3, -0.1, -3], "hi": [3, 0, 3]}}, "material": "floor"},
               {"name": "box", "shape": {"box": {"lo": [-0.35, 0, -0.35], "hi": [0.35, 0.7, 0.35]}},
                "material": "paint",
                "shutter_transforms": [{"translate": [-0.6, 0, 0]}, {"translate": [0.6, 0, 0]}]}],
    "lights": [{"type": "dome"}, {"type": "distant", "direction": [-0.3, -1, -0.5], "intensity": 2}],
    "instanced_grains": [{"name": "pile",
                          "prototypes": [{"name": "round", "shape": {"icosphere": {"subdivisions": 2, "radius": 0.15}},
                                          "material": "glass"}],
                          "positions": [[-0.9, 0.8, 0.6], [0.9, 0.8, 0.6]], "proto_indices": [0, 0],
                          "velocities": [[0, 19.2, 0], [0, -19.2, 0]]}],
}


def _still():
    """The same scene at the frame's instant: shutter closed, the box at its transform."""
    s = copy.deepcopy(MOVING)
    s["camera"]["shutter_open"] = s["camera"]["shutter_close"] = 0
    del s["meshes"][1]["shutter_transforms"]
    return s


def _render(tmp_path, name, scene, *extra):
    path, out = tmp_path / f"{name}.json", tmp_path / f"{name}.exr"
    path.write_text(json.dumps(scene))
    r = subprocess.run([str(EXE), str(path), "-o", str(out), "--quiet", *map(str, extra)], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr
    return rgb_and_variance(out)


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    assert EXE.exists(), f"{EXE} is not built"
    d = tmp_path_factory.mktemp("json_motion_blur")
    off = copy.deepcopy(MOVING)
    off["render"]["motion_blur"] = False
    return {
        "blurred": _render(d, "blurred", MOVING, "--seed", 1),
        "switch": _render(d, "switch", MOVING, "--no-motion-blur"),
        "setting": _render(d, "setting", off),
        "still": _render(d, "still", _still()),
        "still_seed1": _render(d, "still_seed1", _still(), "--seed", 1),
    }


def test_no_motion_blur_is_the_frames_instant(images):
    switch, still, setting = images["switch"], images["still"], images["setting"]
    # The same description as the still scene and as "motion_blur": false: the same image.
    assert (switch[0] == still[0]).all() and (switch[0] == setting[0]).all()
    # And, at another seed, the still frame within noise.
    chi2, m = block_chi2(*switch, *images["still_seed1"])
    print(f"--no-motion-blur vs still (seed 1): chi2 {chi2:.1f} over {m} terms, limit {noise_limit(m):.1f}")
    assert m > 100 and chi2 < noise_limit(m)


def test_no_motion_blur_differs_from_the_blurred_frame_beyond_noise(images):
    chi2, m = block_chi2(*images["switch"], *images["blurred"])
    print(f"--no-motion-blur vs blurred: chi2 {chi2:.1f} over {m} terms, limit {noise_limit(m):.1f}")
    assert chi2 > noise_limit(m)


def test_help_lists_the_switch():
    r = subprocess.run([str(EXE), "--help"], capture_output=True, text=True)
    assert r.returncode == 0
    assert "--no-motion-blur" in r.stderr and '"motion_blur": false' in r.stderr
