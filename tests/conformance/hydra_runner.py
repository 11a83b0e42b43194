#!/usr/bin/env python3
"""Renders every conformance stage through hdGranular in ONE OpenUSD-Python process and
records, per stage, the image and the errors and warnings the host and the delegate raised.

Runs with the OpenUSD build's Python (not the venv's usd-core), the delegate on the plugin
path:
  PYTHONPATH=/opt/openusd/lib/python PXR_PLUGINPATH_NAME=<build>/hdGranular/plugin:<repo>/schemas \\
  /usr/bin/python3 tests/conformance/hydra_runner.py MANIFEST.json OUTDIR

MANIFEST.json (written by compare.py) lists the stages: name, path, time (or null),
hydra_camera, width, limit_s (a stage still rendering after that many seconds ends the
process by SIGALRM; compare.py records it and runs the rest). Each stage is rendered with a fresh UsdAppUtils.FrameRecorder: the
frame recorder of usdrecord, which owns a UsdImagingGLEngine with gpuEnabled False and the
renderer plugin "Granular", renders until the engine reports convergence and writes the
color AOV (linear, color correction disabled, dome lights visible to the camera, the
purposes default and render, as a final render draws them) —
OpenUSD 24.08's Python binding of UsdImagingGLEngine has no AOV read-back of its own. The
frame recorder exposes no renderer settings, so the delegate renders at its defaults; this
process reads them from a UsdImagingGL.Engine of the same plugin and writes them to
OUTDIR/settings.json ("convergedSamplesPerPixel", "granular:seed"), and the command line
is run at the same values.

The host's and the delegate's diagnostics (TF_WARN, TF_RUNTIME_ERROR, TF_CODING_ERROR) are
caught by pointing file descriptor 2 at a file around each stage; errors that Tf raises in
Python (Tf.ErrorException) are caught too. OUTDIR/<name>.json holds
{"recorded", "errors", "warnings" (each distinct message once), "repeats" (how many there
were), "stderr" (its end), "exception", "image", "seconds"} and
OUTDIR/<name>.exr the image (RGBA).
"""
import json
import os
import re
import signal
import sys
import tempfile
import time

from pxr import Tf, Usd, UsdAppUtils, UsdGeom, UsdImagingGL

PLUGIN = "HdGranularRendererPlugin"

# "Warning: in _Execute at line 195 of /x/renderPass.cpp -- hdGranular: ..."
_WARNING = re.compile(r"^Warning: in .* at line \d+ of .* -- (.*)$")
# "Error in 'pxr::...::_Execute' at line 210 in file /x/renderPass.cpp : 'hdGranular: ...'"
_ERROR = re.compile(r"^\s*(?:Runtime |Coding )?Error:? in '.*' at line \d+ in file .* : '(.*)'\s*$")
# TF_RUNTIME_ERROR reported outside any error mark: "Runtime Error: in _Execute at line 210 of /x.cpp -- msg"
_ERROR2 = re.compile(r"^\s*(?:Runtime |Coding |Fatal )?Error: in .* at line \d+ of .* -- (.*)$")


def classify(text):
    """(errors, warnings): the diagnostic messages in `text`, without Tf's location prefix."""
    errors, warnings = [], []
    for line in text.splitlines():
        m = _WARNING.match(line)
        if m:
            warnings.append(m.group(1))
            continue
        m = _ERROR.match(line) or _ERROR2.match(line)
        if m:
            errors.append(m.group(1))
        elif re.match(r"^\s*(Runtime |Coding |Fatal )?Error", line):
            errors.append(line.strip())
    return errors, warnings


class CapturedStderr:
    """Points file descriptor 2 (C++'s and Python's stderr) at a temporary file."""

    def __enter__(self):
        sys.stderr.flush()
        self._file = tempfile.TemporaryFile(mode="w+b")
        self._saved = os.dup(2)
        os.dup2(self._file.fileno(), 2)
        return self

    def __exit__(self, *exc):
        sys.stderr.flush()
        os.dup2(self._saved, 2)
        os.close(self._saved)
        self._file.seek(0)
        self.text = self._file.read().decode("utf-8", "replace")
        self._file.close()
        return False


def delegate_settings():
    params = UsdImagingGL.Engine.Parameters()
    params.gpuEnabled = False
    engine = UsdImagingGL.Engine(params)
    if not engine.SetRendererPlugin(PLUGIN):
        raise SystemExit(f"the {PLUGIN} renderer plugin was not found (PXR_PLUGINPATH_NAME)")
    return {key: engine.GetRendererSetting(key) for key in ("convergedSamplesPerPixel", "granular:seed")}


def render_stage(entry, outdir):
    name = entry["name"]
    image = os.path.join(outdir, name + ".exr")
    if os.path.exists(image):
        os.remove(image)
    result = {"recorded": False, "exception": None}
    t0 = time.monotonic()
    with CapturedStderr() as cap:
        try:
            stage = Usd.Stage.Open(entry["path"])
            recorder = UsdAppUtils.FrameRecorder(PLUGIN, False)
            recorder.SetImageWidth(entry["width"])
            recorder.SetDomeLightVisibility(True)
            recorder.SetColorCorrectionMode("disabled")
            # A final render's purposes, as `granular render` draws them (default and render;
            # usdrecord's default would add proxy).
            recorder.SetIncludedPurposes(["render"])
            camera = UsdGeom.Camera(stage.GetPrimAtPath(entry["hydra_camera"]))
            time_code = Usd.TimeCode(entry["time"]) if entry["time"] is not None else Usd.TimeCode.Default()
            result["recorded"] = bool(recorder.Record(stage, camera, time_code, image))
            del recorder  # the engine and its render thread end here, inside the capture
        except Tf.ErrorException as e:
            result["exception"] = str(e)
        except Exception as e:  # noqa: BLE001  (recorded, the comparison reports it)
            result["exception"] = f"{type(e).__name__}: {e}"
    result["seconds"] = time.monotonic() - t0
    errors, warnings = classify(cap.text)
    if result["exception"]:
        errors += classify(result["exception"])[0] or [result["exception"].strip()]
    # Each distinct message once, in order (a delegate may repeat one on every pass).
    result["repeats"] = {"errors": len(errors), "warnings": len(warnings)}
    errors, warnings = list(dict.fromkeys(errors)), list(dict.fromkeys(warnings))
    result.update(errors=errors, warnings=warnings, stderr=cap.text[-20000:],
                  image=image if os.path.exists(image) and os.path.getsize(image) > 0 else None)
    with open(os.path.join(outdir, name + ".json"), "w") as f:
        json.dump(result, f, indent=1)
    return result


def main():
    manifest, outdir = sys.argv[1:3]
    only = set(sys.argv[3:])
    os.makedirs(outdir, exist_ok=True)
    with open(manifest) as f:
        entries = json.load(f)
    with open(os.path.join(outdir, "settings.json"), "w") as f:
        json.dump(delegate_settings(), f)
    for entry in entries:
        if only and entry["name"] not in only:
            continue
        # A render that never converges would hold the frame recorder (C++) forever: the alarm's
        # default action ends the process, and compare.py records the stage and runs the rest.
        signal.alarm(int(entry.get("limit_s", 120)))
        r = render_stage(entry, outdir)
        signal.alarm(0)
        state = "image" if r["image"] and not r["errors"] else ("error" if r["errors"] else "no image")
        print(f"hydra {entry['name']}: {state} ({r['seconds']:.2f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
