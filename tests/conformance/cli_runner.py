"""Runs `granular render` (the usd-core command line) on one conformance stage and records
what it did: exit status, the `error:` line, the `warning:` lines and the image file.

    run_cli(granular, stage, outdir, spp, seed, width) -> dict (also written as outdir/<name>.json)
"""
import json
import os
import subprocess
import time


def run_cli(granular, stage, outdir, spp, seed, width, suffix=""):
    """One render of `stage` (a stages.Stage) at width x stage.height; returns
    {"rc", "error", "warnings", "stderr", "image" (path or None), "seconds"}."""
    os.makedirs(outdir, exist_ok=True)
    name = stage.name + suffix
    cmd = [granular, "render", stage.path, "--width", str(width), "--height", str(stage.height),
           "--spp", str(spp), "--seed", str(seed)]
    if stage.camera:
        cmd += ["--camera", stage.camera]
    if stage.time is not None:
        # --frames T renders that one time code; the file name then needs a run of '#'.
        frame = f"{stage.time:g}"
        out_pattern = os.path.join(outdir, name + ".####.exr")
        image = os.path.join(outdir, f"{name}.{int(stage.time):04d}.exr")
        if stage.time != int(stage.time):
            raise ValueError("fractional frames are not used by the suite")
        cmd += ["--frames", frame, "-o", out_pattern]
    else:
        image = os.path.join(outdir, name + ".exr")
        cmd += ["-o", image]
    if os.path.exists(image):
        os.remove(image)
    t0 = time.monotonic()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        rc, stderr = r.returncode, r.stderr
    except subprocess.TimeoutExpired as e:
        partial = e.stderr or ""
        partial = partial.decode("utf-8", "replace") if isinstance(partial, bytes) else partial
        rc, stderr = -1, partial + "\nerror: timed out after 300 s\n"
    seconds = time.monotonic() - t0
    lines = stderr.splitlines()
    errors = [ln[len("error: "):] for ln in lines if ln.startswith("error: ")]
    result = {
        "command": cmd,
        "rc": rc,
        "error": errors[-1] if errors else None,
        "warnings": [ln[len("warning: "):] for ln in lines if ln.startswith("warning: ")],
        "stderr": stderr,
        "image": image if rc == 0 and os.path.exists(image) else None,
        "seconds": seconds,
    }
    with open(os.path.join(outdir, name + ".json"), "w") as f:
        json.dump(result, f, indent=1)
    return result
