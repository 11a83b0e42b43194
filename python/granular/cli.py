"""The `granular` command: render a USD stage, report its aggregates, export coarse density.

    granular render SCENE.usda -o OUT.exr [--png OUT.png] [--width W --height H] [--spp N]
                    [--camera /path] [--seed S] [--threads T] [--exposure E] [--quiet]
                    [--technique ept|ept+vpt|hybrid] [--roulette P_a] [--lod L] [--no-default-light]
                    [--no-physical-sun]
                    [--frames A:B[xSTEP]]   (then -o and --png name a run of '#': OUT.####.exr)
                    [--crop X0:X1,Y0:Y1]    (only those pixels; the EXR keeps their place)
    granular merge TILE.exr [TILE.exr ...] -o OUT.exr [--png OUT.png] [--exposure E]
    granular farm SCENE.usda -o OUT.####.exr [--png OUT.####.png] --frames A:B[xSTEP] [--tiles N]
                  [--scheduler ADDRESS | --workers K] [render options]
    granular info SCENE.usda [--json]
    granular export-vdb SCENE.usda --prim /path -o OUT.vdb [--voxel-size S]

Exit status: 0 on success, 2 on bad input (one line `error: prim.attribute: message`,
no traceback, no output file left behind), 1 on any other failure, 130 when interrupted.
"""
import argparse
import hashlib
import json
import math
import os
import re
import struct
import sys
import time

from . import __version__, api
from .errors import UserError

EXIT_OK, EXIT_FAILURE, EXIT_USER, EXIT_INTERRUPTED = 0, 1, 2, 130


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line `error: command line.OPTION: message`
    and exit status 2, as the commands report theirs."""

    # argparse's complaints about the shape of the command line rather than a value: these
    # earn a pointer to the command's --help.
    _SHAPE = ("expected ", "ignored explicit argument", "not allowed with argument")

    def error(self, message):
        hint = f" (see {self.prog} --help)"
        m = re.fullmatch(r"argument (\S+): (.*)", message, re.S)
        if m:
            flag, text = m.group(1).split("/")[0], m.group(2)  # -o/--output: -o, as the other checks say
            if text.startswith("expected one argument"):
                # argparse takes '-1e3' or '-5:5' for an option, not a value
                text += f" (for a value that starts with '-', write {flag}=VALUE)"
            elif text.startswith(self._SHAPE):
                text += hint
            raise UserError("command line", flag, text)
        m = re.fullmatch(r"the following arguments are required: (.*)", message, re.S)
        if m:
            names = [n.split("/")[0] for n in m.group(1).split(", ")]
            others = f" (so are {', '.join(names[1:])})" if len(names) > 1 else ""
            raise UserError("command line", names[0], f"is required{others}{hint}")
        m = re.fullmatch(r"unrecognized arguments: (-\S*).*", message, re.S)
        if m:
            raise UserError("command line", m.group(1).split("=")[0], f"is not an option{hint}")
        raise UserError("command line", "", message + hint)


class _SubParser(_Parser):
    """A command's parser: it reports an argument it does not know itself, so that the
    error points at that command's --help rather than the top level's."""

    def parse_known_args(self, args=None, namespace=None):
        namespace, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error("unrecognized arguments: " + " ".join(extras))
        return namespace, extras


def _int_in(lo, hi):
    def parse(text):
        try:
            v = int(text, 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{v} is outside [{lo}, {hi}]")
        return v
    return parse


def _number(text):
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None


def _single(v, text):
    """v, refused where the core's 32-bit float would make it infinite, or 0 when it is not
    (the core would then reject a value the user never typed)."""
    try:
        f = struct.unpack("f", struct.pack("f", v))[0]
    except OverflowError:  # some Pythons raise, others give inf
        f = math.inf
    if math.isinf(f):
        raise argparse.ArgumentTypeError(f"{text} is too large for a 32-bit float")
    if f == 0 and v != 0:
        raise argparse.ArgumentTypeError(f"{text} is too small for a 32-bit float (it rounds to 0)")
    return v


def _positive_float():
    def parse(text):
        v = _number(text)
        if not math.isfinite(v) or v <= 0:
            raise argparse.ArgumentTypeError(f"{text} must be finite and > 0")
        return _single(v, text)
    return parse


def _non_negative_float():
    def parse(text):
        v = _number(text)
        if not math.isfinite(v) or v < 0:
            raise argparse.ArgumentTypeError(f"{text} must be finite and >= 0")
        return _single(v, text)
    return parse


def _exposure(text):
    v = _number(text)
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text} is not finite")
    if abs(v) > 100:  # 2^E must stay a finite, non-zero float, as for a light's exposure
        raise argparse.ArgumentTypeError(f"{text} is outside [-100, 100]")
    return v


def _crop(text):
    """'X0:X1,Y0:Y1' -> (x0, x1, y0, y1), a non-empty pixel window."""
    m = re.fullmatch(r"\s*(\d+)\s*:\s*(\d+)\s*,\s*(\d+)\s*:\s*(\d+)\s*", text)
    if not m:
        raise argparse.ArgumentTypeError(f"'{text}' is not X0:X1,Y0:Y1 (pixels, e.g. 0:320,0:240)")
    x0, x1, y0, y1 = (int(v) for v in m.groups())
    if not (x0 < x1 and y0 < y1):
        raise argparse.ArgumentTypeError(f"'{text}' is empty: X0 < X1 and Y0 < Y1 are needed")
    return x0, x1, y0, y1


def _roulette(text):
    v = _number(text)
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text} is not finite")
    if v < 0:
        return v
    if not 0 < v <= 1:
        raise argparse.ArgumentTypeError(f"{text} must be in (0, 1], or negative for automatic")
    return _single(v, text)


def _prim_path(example):
    """An absolute prim path (whether the stage has it is for the reader to say)."""
    def parse(text):
        from pxr import Sdf
        ok, _ = Sdf.Path.IsValidPathString(text)
        if not (ok and Sdf.Path(text).IsAbsolutePath() and Sdf.Path(text).IsPrimPath()):
            raise argparse.ArgumentTypeError(f'"{text}" is not an absolute prim path such as {example}')
        return text
    return parse


def _render_options(r):
    """The options `render` and `farm` share: what is rendered and how."""
    r.add_argument("--width", type=_int_in(1, 32768), help="image width (default: the render "
                   "settings' resolution, else 640; with only --height, the camera's aspect)")
    r.add_argument("--height", type=_int_in(1, 32768), help="image height (default: as --width)")
    r.add_argument("--spp", type=_int_in(1, 1000000), default=16, help="samples per pixel (16)")
    r.add_argument("--camera", type=_prim_path("/World/Camera"), metavar="PATH",
                   help="camera prim (default: the render settings' camera, else the first camera)")
    r.add_argument("--seed", type=_int_in(0, 2**31 - 1), default=0, help="sampling seed (0)")
    r.add_argument("--threads", type=_int_in(0, 1024), default=0, help="threads (0: all cores)")
    r.add_argument("--exposure", type=_exposure, default=0.0,
                   help="exposure of the PNG in stops, in [-100, 100] (0)")
    r.add_argument("--technique", choices=["ept", "ept+vpt", "hybrid"], default="hybrid",
                   help="transports of the multi-scale integrator: explicit grains only (the reference), "
                        "plus volumetric path tracing in the equivalent media, plus diffusion (default)")
    r.add_argument("--roulette", type=_roulette, default=-1.0, metavar="P_a",
                   help="survival probability of a path at the switch from EPT to the media, in (0, 1]; "
                        "negative (default): tuned by a pre-render")
    r.add_argument("--lod", type=_non_negative_float(), default=0.5, metavar="L",
                   help="level of detail: after the first grain, enter an aggregate's medium where the grain "
                        "radius is under L times the ray footprint (default 0.5: grains narrower than a "
                        "footprint; 0: off, every grain explicit)")
    r.add_argument("--no-default-light", action="store_true",
                   help="a stage without any light (no UsdLux light, no emissive surface) renders black; "
                        "by default it is lit by a uniform white dome of radiance 1, with a warning")
    r.add_argument("--no-physical-sun", action="store_true",
                   help="keep delta suns (distant lights of angle 0) delta; by default, over smooth dielectric "
                        "grains, they are rendered as the physical 0.53 degree sun of the same irradiance, "
                        "with a warning")


def build_parser():
    p = _Parser(prog="granular", description="hdGranular: render granular materials from USD stages.")
    p.add_argument("--version", action="version", version=f"granular {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_SubParser)
    sub.required = True

    r = sub.add_parser("render", help="render a stage to EXR (and PNG)")
    r.add_argument("scene", metavar="SCENE", help="USD stage (.usda, .usdc, .usd)")
    r.add_argument("-o", "--output", required=True, metavar="OUT.exr", help="OpenEXR image (RGBA, Z, N)")
    r.add_argument("--png", metavar="OUT.png", help="also an 8-bit sRGB PNG")
    _render_options(r)
    r.add_argument("--frames", metavar="A:B[xSTEP]",
                   help="render the frames A to B (inclusive) every STEP (default 1; may be fractional), each "
                        "at its own time code; -o (and --png) then contain a run of '#', replaced by the frame "
                        "number padded with zeros to that many digits (out.####.exr: out.0001.exr; frame 1.5: "
                        "out.0001.5.exr). Without it, one image at the stage's start time")
    r.add_argument("--crop", type=_crop, metavar="X0:X1,Y0:Y1",
                   help="render only the pixels X0 <= x < X1, Y0 <= y < Y1 (rows from the top) of the image; the "
                        "EXR holds them with their place in the full image (its data window), and `granular merge` "
                        "joins such tiles bit for bit into the full render. Default: the render settings' "
                        "dataWindowNDC, else every pixel")
    r.add_argument("--quiet", action="store_true", help="no progress or statistics on stderr")

    g = sub.add_parser("merge", help="join tiles (EXRs of --crop renders of one image) into one image")
    g.add_argument("tiles", nargs="+", metavar="TILE.exr")
    g.add_argument("-o", "--output", required=True, metavar="OUT.exr")
    g.add_argument("--png", metavar="OUT.png", help="also an 8-bit sRGB PNG")
    g.add_argument("--exposure", type=_exposure, default=0.0, help="exposure of the PNG in stops, in [-100, 100] (0)")
    g.add_argument("--quiet", action="store_true")

    from . import farm
    farm.add_parser(sub, _render_options)

    i = sub.add_parser("info", help="grain counts, tiles and transport parameters of each aggregate")
    i.add_argument("scene", metavar="SCENE")
    i.add_argument("--json", action="store_true", help="print JSON instead of text")

    e = sub.add_parser("export-vdb", help="coarse density of an aggregate as an OpenVDB grid 'density'")
    e.add_argument("scene", metavar="SCENE")
    e.add_argument("--prim", required=True, type=_prim_path("/World/Sand"), metavar="PATH",
                   help="the aggregate's boundary mesh")
    e.add_argument("-o", "--output", required=True, metavar="OUT.vdb")
    e.add_argument("--voxel-size", type=_positive_float(), default=0.0,
                   help="world units (default: the boundary's largest extent / 128)")
    e.add_argument("--quiet", action="store_true")
    return p


# ---- helpers ------------------------------------------------------------------------------

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


def _check_output(path, flag, extensions):
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


class _Progress:
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


def _log(args, msg):
    if not getattr(args, "quiet", False):
        print(msg, file=sys.stderr)


def _warnings(args, scene):
    for w in scene.warnings:
        _log(args, "warning: " + w)


def _remove(paths):
    for p in paths:
        try:
            os.remove(p)
        except OSError:
            pass


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


def _write_images(image, exr, png, exposure):
    """Writes the EXR (and the PNG): each file appears whole or not at all (core writes
    through a temporary name), and a failure removes the one already written (all or
    nothing). Returns the paths written."""
    import granular_core as core
    written = []
    try:
        warn_if_replaced(core.write_exr(exr, image), exr)
        written.append(exr)
        if png:
            warn_if_replaced(core.write_png(png, image, exposure), png)
            written.append(png)
    except BaseException:
        _remove(written)
        raise
    return written


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


# What a frame's description is made of: a change in any of _SCENE_PARTS needs the scene
# built anew; a change of the view alone ("camera", "settings") is Scene.set_view.
_SCENE_PARTS = ("materials", "meshes", "lights", "aggregates", "build settings")
_CAMERA_FIELDS = ("camera_to_world", "focal_length", "horizontal_aperture", "vertical_aperture",
                  "horizontal_aperture_offset", "vertical_aperture_offset", "clip_near", "clip_far", "lens_radius",
                  "focus_distance")
_SETTINGS_FIELDS = ("width", "height", "spp", "seed", "max_depth", "rr_depth", "threads", "technique", "bundle_size",
                    "tau", "explicit_bounces", "da_depth_factor", "da_min_order", "roulette", "lod", "default_light", "dome_camera_visible", "crop")


def _feed(h, *values):
    """Hashes values exactly: numpy arrays by dtype, shape and bytes, the rest by repr (floats
    round-trip)."""
    import numpy as np
    for v in values:
        if isinstance(v, np.ndarray):
            h.update(f"{v.dtype}{v.shape}".encode())
            h.update(np.ascontiguousarray(v).tobytes())
        else:
            h.update(repr(v).encode())
        h.update(b"\x00")


def _feed_mesh(h, mesh):
    _feed(h, mesh.points, mesh.indices, mesh.uvs)


def _texture_key(t):
    return (t.file, t.source, t.wrap_s, t.wrap_t, tuple(t.scale), tuple(t.bias), t.color_space, t.channel)


def fingerprint(desc):
    """{part: digest} of a core.SceneDesc, parts _SCENE_PARTS, "camera" and "settings": equal
    digests, equal values (meshes compared point by point)."""
    import granular_core as core
    parts = {name: hashlib.blake2b(digest_size=20) for name in (*_SCENE_PARTS, "camera", "settings")}
    h = parts["materials"]
    for m in desc.materials:
        _feed(h, m.name, m.type, m.albedo, m.ior, m.absorption, m.emission, m.roughness, m.energy_compensation,
              m.opacity, m.opacity_threshold, _texture_key(m.albedo_texture), _texture_key(m.emission_texture),
              _texture_key(m.opacity_texture))
    h = parts["meshes"]
    for m in desc.meshes:
        _feed(h, m.name, m.xf, m.material, m.visible, m.id)
        _feed_mesh(h, m.mesh)
    h = parts["lights"]
    for light in desc.lights:
        _feed(h, light.name, light.type, light.xf, light.color, light.intensity, light.exposure, light.normalize,
              light.angle, light.radius, light.width, light.height, light.texture_file)
    h = parts["aggregates"]
    for a in desc.aggregates:
        _feed(h, a.name, a.xf, a.weights, a.grain_radius, a.packing_rate, a.seed, a.tile_spheres, a.id,
              list(a.sizes), a.size_spread)
        _feed_mesh(h, a.boundary)
        for p in a.prototypes:
            _feed(h, p.name, p.material)
            _feed_mesh(h, p.mesh)
    # Settings that take effect when the scene is built: media or none (Scene.set_view
    # refuses a change between ept and the hybrid), the default light of a stage without any,
    # delta suns made physical or not.
    _feed(parts["build settings"], desc.settings.technique == core.Technique.Ept, desc.settings.default_light,
          desc.settings.physical_sun)
    _feed(parts["camera"], *(getattr(desc.camera, f) for f in _CAMERA_FIELDS))
    _feed(parts["settings"], *(getattr(desc.settings, f) for f in _SETTINGS_FIELDS))
    return {name: d.hexdigest() for name, d in parts.items()}


# ---- commands ---------------------------------------------------------------------------------

_DEFAULT_LIGHT_WARNING = ("warning: the stage has no light (no UsdLux light, no emissive surface): it is lit by "
                          "the default white dome of radiance 1 (--no-default-light renders it black)")


def _log_build_warnings(args, built, shown=None):
    """The built scene's warnings (default light, widened suns, textures); with `shown` (a set
    kept over a sequence), each distinct one once."""
    lines = [_DEFAULT_LIGHT_WARNING] if built.default_light_added else []
    if built.widened_suns_warning:
        lines.append("warning: " + built.widened_suns_warning)
    lines += ["warning: " + w for w in built.texture_warnings]
    for line in lines:
        if shown is None or line not in shown:
            _log(args, line)
            if shown is not None:
                shown.add(line)


def _apply_options(args, scene):
    """The command line's render settings on a read scene; returns them."""
    import granular_core as core
    s = scene.desc.settings
    s.spp = args.spp
    s.seed = args.seed
    s.threads = args.threads
    s.technique = core.technique_from_name(args.technique, "command line")
    s.roulette = args.roulette
    s.lod = args.lod
    s.default_light = not args.no_default_light
    s.physical_sun = not args.no_physical_sun
    if getattr(args, "crop", None):
        x0, x1, y0, y1 = args.crop
        if x1 > s.width or y1 > s.height:
            raise UserError("command line", "--crop", f"{x0}:{x1},{y0}:{y1} reaches outside the {s.width}x{s.height} "
                                                      f"image")
        s.crop = args.crop
    return s


def _crop_text(settings):
    x0, x1, y0, y1 = settings.crop
    return f" (pixels {x0}:{x1},{y0}:{y1})" if (x0, x1, y0, y1) != (0, 0, 0, 0) else ""


def _log_aggregates(args, built):
    for a in built.aggregates:
        _log(args, f"  aggregate {a['name']}: ~{a['approx_grains']:.3g} grains, {a['cells']} tiles "
                   f"({a['inside_cells']} inside, {a['partial_cells']} partial)")


def _render_image(args, built):
    import granular_core as core
    renderer = core.Renderer(built)
    renderer.render(1, _Progress(not args.quiet), 0.5)
    return renderer, renderer.image()


def _log_transports(args, built, renderer, image):
    if built.has_media:
        rt = renderer.roulette
        tuned = f" (tuned on {rt['pixels']} pixels)" if rt["pixels"] else ""
        means = []
        for part in ("ept", "vpt", "da"):
            c = image.channels.index(part + ".R")
            means.append(float((image.pixels[..., c:c + 3] @ [0.2126, 0.7152, 0.0722]).mean()))
        lod = f"; level of detail: {100 * renderer.shortcut_fraction:.1f}% of paths entered a medium directly" \
            if args.lod > 0 else ""
        _log(args, f"  technique {args.technique}, bundles of {renderer.bundle_size}, P_a {rt['pa']:.3f}{tuned}; "
                   f"mean luminance by transport: EPT {means[0]:.4g}, VPT {means[1]:.4g}, DA {means[2]:.4g}{lod}")
    elif args.technique != "ept":
        _log(args, f"  technique {args.technique}: every aggregate is thinner than its mean free path, "
                   f"so explicit grains (EPT) render it all")


def check_outputs(args):
    """-o (an EXR) and --png (a PNG, another file) can be written."""
    _check_output(args.output, "-o", (".exr",))
    if args.png:
        _check_output(args.png, "--png", (".png",))
    if args.png and os.path.abspath(args.png) == os.path.abspath(args.output):
        raise UserError("command line", "--png", "is the same file as -o")


def cmd_render(args):
    from .usd_reader import read_stage

    check_outputs(args)
    if args.frames is not None:
        return _render_frames(args)  # frame_outputs claims each frame's files
    claim_outputs(args.output, args.png)
    t0 = time.monotonic()
    scene = read_stage(args.scene, camera=args.camera, width=args.width, height=args.height)
    s = _apply_options(args, scene)
    _warnings(args, scene)
    built = api.build_scene(scene)
    _log_build_warnings(args, built)
    _log(args, f"{args.scene}: camera {scene.camera_path}, {s.width}x{s.height}{_crop_text(s)}, {s.spp} spp; "
               f"scene read and built in {time.monotonic() - t0:.2f} s")
    _log_aggregates(args, built)
    t1 = time.monotonic()
    renderer, image = _render_image(args, built)
    _log_transports(args, built, renderer, image)
    written = _write_images(image, args.output, args.png, args.exposure)
    _log(args, f"wrote {' and '.join(written)} (render {time.monotonic() - t1:.1f} s, "
               f"total {time.monotonic() - t0:.1f} s)")
    return EXIT_OK


def _render_frames(args):
    """render --frames: the stage opened once, each frame's description read at its time and
    compared with the previous frame's; the built scene is kept when only the view (camera,
    render settings) changed (Scene.set_view: no voxelising, no TT work) and built anew when
    lights, meshes, materials or aggregates changed, reusing every aggregate whose inputs did
    not (a moving light voxelises nothing, a deforming boundary only its aggregate). Each
    frame's files are written atomically as it completes; a failure leaves the frames before
    it, complete, and nothing of its own."""
    import granular_core as core
    from .usd_reader import open_stage, read_stage, translate_core_error

    frames = parse_frames(args.frames)
    exr_name, png_name = frame_outputs(args, frames)
    t0 = time.monotonic()
    stage = open_stage(args.scene)
    built = previous = None
    shown = set()
    for k, frame in enumerate(frames):
        tf = time.monotonic()
        scene = read_stage(args.scene, camera=args.camera, width=args.width, height=args.height, stage=stage,
                           time=frame)
        s = _apply_options(args, scene)
        for w in scene.warnings:
            if w not in shown:
                shown.add(w)
                _log(args, "warning: " + w)
        current = fingerprint(scene.desc)
        changed = [p for p in _SCENE_PARTS if previous is None or current[p] != previous[p]]
        if changed:
            first = built is None
            built = api.build_scene(scene, previous=built)
            _log_build_warnings(args, built, shown)  # a later frame may bring its own
            if first:
                _log(args, f"{args.scene}: frames {frame_text(frames[0])} to {frame_text(frames[-1])} "
                           f"({len(frames)}), camera {scene.camera_path}, {s.width}x{s.height}{_crop_text(s)}, {s.spp} spp")
                _log_aggregates(args, built)
                action = f"scene built in {time.monotonic() - tf:.2f} s"
            else:
                action = (f"scene rebuilt ({', '.join(changed)} changed; aggregates: {built.aggregates_built} "
                          f"built, {built.aggregates_reused} reused) in {time.monotonic() - tf:.2f} s")
        elif current["camera"] != previous["camera"] or current["settings"] != previous["settings"]:
            try:
                built.set_view(scene.desc.camera, scene.desc.settings)
            except core.InputError as e:
                raise translate_core_error(e, scene) from None
            new = [p for p in ("camera", "settings") if current[p] != previous[p]]
            action = f"scene reused (new {' and '.join(new)})"
        else:
            action = "scene reused (unchanged)"
        previous = current
        t1 = time.monotonic()
        renderer, image = _render_image(args, built)
        seconds = time.monotonic() - t1
        if k == 0:
            _log_transports(args, built, renderer, image)
        written = _write_images(image, exr_name(frame), png_name(frame) if png_name else None, args.exposure)
        _log(args, f"frame {frame_text(frame)}: {action}; render {seconds:.2f} s; wrote {' and '.join(written)}")
    _log(args, f"{len(frames)} frames in {time.monotonic() - t0:.1f} s")
    return EXIT_OK


def cmd_merge(args):
    import granular_core as core
    check_outputs(args)
    claim_outputs(args.output, args.png)
    outputs = {os.path.abspath(p) for p in (args.output, args.png) if p}
    tiles = []
    for path in args.tiles:
        if os.path.abspath(path) in outputs:
            raise UserError("command line", "-o", f'"{path}" is both a tile and an output')
        if not os.path.isfile(path):
            raise UserError(path, "", "no such file")
        tiles.append(core.read_tile_exr(path))
    try:
        image = core.merge_tiles(tiles)
    except core.InputError as e:  # name the files, not the tiles' indices
        detail = re.sub(r"tile (\d+)", lambda m: f"tile {args.tiles[int(m.group(1))]}", e.detail)
        raise UserError("command line", "tiles", detail) from None
    written = _write_images(image, args.output, args.png, args.exposure)
    where = "" if image.full_width == image.width and image.full_height == image.height else \
        f" at ({image.x}, {image.y}) of {image.full_width}x{image.full_height}"
    _log(args, f"merged {len(tiles)} tiles into {image.width}x{image.height}{where}; wrote {' and '.join(written)}")
    return EXIT_OK


def cmd_info(args):
    scene = api.read_aggregates(args.scene)
    report = api.aggregate_report(scene=scene)
    if args.json:
        print(json.dumps({"scene": args.scene, "aggregates": report}, indent=2))
        return EXIT_OK
    _warnings(args, scene)
    if not report:
        print(f"{args.scene}: no granular aggregates (no Mesh with GranularAggregateAPI)")
    for r in report:
        print("\n".join(api.report_lines(r)))
    return EXIT_OK


def cmd_export_vdb(args):
    _check_output(args.output, "-o", (".vdb",))
    claim_outputs(args.output)
    r = api.export_density(args.prim, args.output, args.voxel_size, path=args.scene)
    warn_if_replaced(r.get("replaced_other"), args.output)
    _log(args, api.export_summary(args.prim, args.output, r))
    return EXIT_OK


def cmd_farm(args):
    from . import farm
    return farm.run(args)


COMMANDS = {"render": cmd_render, "merge": cmd_merge, "farm": cmd_farm, "info": cmd_info, "export-vdb": cmd_export_vdb}


def main(argv=None):
    try:
        args = build_parser().parse_args(argv)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_USER
    try:
        import granular_core as core
    except ImportError as e:
        print(f"error: the granular_core module is not built or not on the path ({e}); run `make`", file=sys.stderr)
        return EXIT_FAILURE
    from pxr import Tf
    try:
        return COMMANDS[args.command](args)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_USER
    except core.InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_USER
    except Tf.ErrorException as e:
        from .usd_reader import describe_tf_error
        print(f"error: {args.scene}: {' '.join(describe_tf_error(e).split())}", file=sys.stderr)
        return EXIT_USER
    except KeyboardInterrupt:
        print("\nerror: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as e:  # a bug, not bad input: say so, with the traceback on request
        if os.environ.get("GRANULAR_DEBUG"):
            raise
        print(f"error: {type(e).__name__}: {e} (set GRANULAR_DEBUG=1 for a traceback)", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
