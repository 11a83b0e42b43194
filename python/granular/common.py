"""What `granular render` (cli.py) and `granular farm` (farm.py) share: exit statuses, option
types, output checks, frame sequences, the progress bar, the command line's render settings and
bringing a built scene up to date for the next frame. Both import it; it imports neither, so
the two commands' modules import each other nowhere."""
import argparse
import math
import os
import re
import sys

from .errors import UserError

EXIT_OK, EXIT_FAILURE, EXIT_USER, EXIT_INTERRUPTED = 0, 1, 2, 130


def int_in(lo, hi):
    """An argparse type: an integer in [lo, hi]."""
    def parse(text):
        try:
            v = int(text, 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{v} is outside [{lo}, {hi}]")
        return v
    return parse


# ---- outputs ---------------------------------------------------------------------------------

def _name_max(folder):
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        return 255


def _name_too_long(path, name_max):
    """The length of path's file name while it is written (the core writes .NAME.XXXXXX, a
    new temporary file, then renames it) when the folder cannot hold it, else None."""
    n = len(os.fsencode("." + os.path.basename(path) + ".XXXXXX"))
    return n if n > name_max else None


def check_output(path, flag, extensions):
    if not path.lower().endswith(extensions):
        raise UserError("command line", flag, f'"{path}" must end in {" or ".join(extensions)}')
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise UserError("command line", flag, f'folder "{folder}" does not exist')
    if os.path.isdir(path):
        raise UserError("command line", flag, f'"{path}" is a folder')
    if not os.access(folder, os.W_OK):
        raise UserError("command line", flag, f'folder "{folder}" is not writable')
    limit = _name_max(folder)
    n = _name_too_long(path, limit)
    if n:
        raise UserError("command line", flag, f"the file name (with 8 more bytes while it is written) has {n} "
                                              f"bytes, more than the {limit} its folder allows")


def claim_outputs(*paths):
    """Notes what each output is before the render, so that writing it can tell whether
    another process wrote it meanwhile (core.claim_output)."""
    import granular_core as core
    for p in paths:
        if p:
            core.claim_output(p)


def warn_if_replaced(replaced, path):
    """The writer's word that another process wrote path during this render."""
    if replaced:
        print(f"warning: {path} was written by another process during this render; this render's image replaced "
              f"it", file=sys.stderr)


def check_outputs(args):
    """-o (an EXR) and --png (a PNG, another file) can be written."""
    check_output(args.output, "-o", (".exr",))
    if args.png:
        check_output(args.png, "--png", (".png",))
    if args.png and os.path.abspath(args.png) == os.path.abspath(args.output):
        raise UserError("command line", "--png", "is the same file as -o")


# ---- rendering -------------------------------------------------------------------------------

class Progress:
    """A progress bar on stderr; on a terminal it redraws one line, else it prints a few."""

    def __init__(self, enabled, stream=sys.stderr, unit="spp"):
        self.enabled = enabled
        self.unit = unit
        self.stream = stream
        self.tty = enabled and stream.isatty()
        self.last_quarter = -1
        self.last_len = 0

    def __call__(self, done, target, seconds):
        if not self.enabled:
            return
        frac = done / target if target else 1.0
        eta = seconds / frac - seconds if frac > 0 else 0.0
        width = 30
        bar = "#" * int(frac * width) + "-" * (width - int(frac * width))
        count = f"{done:.1f}" if self.unit == "spp" else f"{done:g}"
        line = f"  [{bar}] {count}/{target} {self.unit}  {seconds:.1f} s  eta {eta:.0f} s"
        if self.tty:
            pad = " " * max(0, self.last_len - len(line))  # wipe the rest of a longer previous line
            self.last_len = len(line)
            self.stream.write("\r" + line + pad + ("\n" if done >= target else ""))
            self.stream.flush()
        else:
            quarter = int(frac * 4)
            if quarter != self.last_quarter:
                self.last_quarter = quarter
                self.stream.write(line + "\n")
                self.stream.flush()


def apply_options(args, scene):
    """The command line's render settings on a read scene; returns them."""
    import granular_core as core
    s = scene.desc.settings
    s.spp = args.spp
    s.seed = args.seed
    s.threads = args.threads
    s.technique = core.technique_from_name(args.technique, "command line")
    s.roulette = args.roulette
    s.lod = args.lod
    s.proxies = core.proxy_use_from_name(args.proxies, "command line")
    if getattr(args, "medium_model", None):
        s.medium_model = core.medium_model_from_name(args.medium_model, "command line")
    s.default_light = not args.no_default_light
    s.physical_sun = not args.no_physical_sun
    if getattr(args, "sun_regularization", None) is not None:
        s.sun_regularization = args.sun_regularization
    if getattr(args, "instanced_da", False):
        s.da_instanced = True
    if getattr(args, "switch_for_view", False):
        s.switch_for_view = True
    if getattr(args, "no_motion_blur", False):
        core.still_frame(scene.desc)
    if getattr(args, "crop", None):
        x0, x1, y0, y1 = args.crop
        if x1 > s.width or y1 > s.height:
            raise UserError("command line", "--crop", f"{x0}:{x1},{y0}:{y1} reaches outside the {s.width}x{s.height} "
                                                      f"image")
        s.crop = args.crop
    return s


# ---- frame sequences (render --frames) ------------------------------------------------------

MAX_FRAMES = 100000


def _frame_number(text, what):
    try:
        v = float(text)
    except ValueError:
        raise UserError("command line", "--frames", f"{what} '{text.strip()}' is not a number") from None
    if not math.isfinite(v):
        raise UserError("command line", "--frames", f"{what} {text.strip()} is not finite")
    return v


def parse_frames(spec):
    """'A:B[xSTEP]' (or 'A', one frame) -> the frames A, A+STEP, ... up to B inclusive, as
    floats; UserError on command line.--frames for anything else."""
    body, sep, step_text = spec.partition("x")
    parts = body.split(":")
    if len(parts) > 2 or (sep and len(parts) != 2) or not all(p.strip() for p in parts) or (sep and not step_text.strip()):
        raise UserError("command line", "--frames", f"'{spec}' is not A:B or A:BxSTEP (e.g. 1:24 or 1:2x0.5)")
    a = _frame_number(parts[0], "start")
    b = _frame_number(parts[1], "end") if len(parts) == 2 else a
    step = _frame_number(step_text, "step") if sep else 1.0
    if a > b:
        raise UserError("command line", "--frames", f"start {a:g} is after end {b:g}")
    if step <= 0:
        raise UserError("command line", "--frames", f"step {step:g} must be > 0")
    span = (b - a) / step
    if not math.isfinite(span):  # B - A or 1 / STEP overflows
        raise UserError("command line", "--frames", f"'{spec}' has more than {MAX_FRAMES} frames")
    count = math.floor(span * (1 + 1e-12) + 1e-9) + 1  # B itself despite rounding in (B-A)/STEP
    if count > MAX_FRAMES:
        raise UserError("command line", "--frames", f"'{spec}' has {count} frames, more than {MAX_FRAMES}")
    # A + k STEP (not a running sum), rid of binary noise (1 + 3 x 0.1 is frame 1.3).
    return [round(a + k * step, 9) for k in range(count)]


def frame_text(frame, digits=0):
    """A frame number for file names and the log: the integer part zero-padded to `digits`,
    then the fraction, if any, to at most 6 decimals: (1, 4) -> '0001', (1.5, 4) -> '0001.5',
    (-2, 4) -> '-0002', (12.25, 0) -> '12.25'."""
    text = f"{abs(frame):.6f}".rstrip("0").rstrip(".")
    whole, _, fraction = text.partition(".")
    sign = "-" if frame < 0 and text != "0" else ""
    return sign + whole.zfill(digits) + ("." + fraction if fraction else "")


_HASHES = re.compile(r"#+")


def frame_path(pattern, flag):
    """A function frame -> file name: the last run of '#' in the file name of `pattern`
    replaced by frame_text(frame, len(run)); UserError on command line.<flag> without one."""
    folder, base = os.path.split(pattern)
    runs = list(_HASHES.finditer(base))
    if not runs:
        raise UserError("command line", flag, f'"{pattern}" has no run of \'#\' for the frame number '
                                              f"(needed with --frames, e.g. out.####{os.path.splitext(base)[1]})")
    run = runs[-1]
    return lambda frame: os.path.join(folder, base[:run.start()] + frame_text(frame, len(run.group())) +
                                      base[run.end():])


def frame_outputs(args, frames):
    """(exr_name, png_name or None): frame -> file name of -o and --png, checked to give each
    frame files of its own, with names their folders can hold."""
    exr_name = frame_path(args.output, "-o")
    png_name = frame_path(args.png, "--png") if args.png else None
    names = [(exr_name, _name_max(os.path.dirname(os.path.abspath(args.output))))]
    if png_name:
        names.append((png_name, _name_max(os.path.dirname(os.path.abspath(args.png)))))
    seen = {}
    for f in frames:
        other = seen.setdefault(exr_name(f), f)
        if other != f:  # frame numbers in names have 6 decimals at most
            raise UserError("command line", "--frames", f"step too small: frames {other!r} and {f!r} would both "
                                                        f"write {exr_name(f)}")
        for name, limit in names:  # a large frame number is written out in full
            claim_outputs(name(f))
            n = _name_too_long(name(f), limit)
            if n:
                raise UserError("command line", "--frames", f"frame {f:g} makes a file name of {n} bytes (with 8 "
                                                            f"more while it is written), more than the {limit} its "
                                                            f"folder allows")
    return exr_name, png_name


def update_scene(scene, built):
    """The built scene that renders scene.desc (a StageScene), from `built`, the one that
    rendered the previous frame (None: nothing built yet), by what core.compare_scenes finds
    between the description `built` holds and scene.desc: `built` itself when nothing changed;
    `built` with the new view (Scene.set_view: no voxelising, no TT work) when only the camera
    or the settings set_view takes did; else a new build that takes every unchanged aggregate
    from `built`. Returns (scene, changes), changes None for the first build."""
    import granular_core as core
    from . import api
    from .usd_reader import translate_core_error

    if built is None:
        return api.build_scene(scene), None
    changes = built.changes(scene.desc)
    if changes.level == core.SceneChange.Unchanged:
        return built, changes
    if changes.level == core.SceneChange.View:
        try:
            built.set_view(scene.desc.camera, scene.desc.settings)
        except core.InputError as e:
            raise translate_core_error(e, scene) from None
        return built, changes
    return api.build_scene(scene, previous=built), changes
