"""The `granular` command: render a USD stage, report its aggregates, export coarse density.

    granular render SCENE.usda -o OUT.exr [--png OUT.png] [--width W --height H] [--spp N]
                    [--camera /path] [--seed S] [--threads T] [--exposure E] [--quiet]
                    [--technique ept|ept+vpt|hybrid] [--roulette P_a] [--lod L] [--no-default-light]
                    [--no-physical-sun] [--sun-regularization DEG] [--switch-for-view] [--no-motion-blur]
                    [--instanced-da]
                    [--frames A:B[xSTEP]]   (then -o and --png name a run of '#': OUT.####.exr)
                    [--crop X0:X1,Y0:Y1]    (only those pixels; the EXR keeps their place)
    granular render SCENE.usda [--settings /Render/Settings] [--frames A:B] [render options]
                    (no -o: every render product of the render settings prim, at its productName)
    granular merge TILE.exr [TILE.exr ...] -o OUT.exr [--png OUT.png] [--exposure E]
    granular farm SCENE.usda -o OUT.####.exr [--png OUT.####.png] --frames A:B[xSTEP] [--tiles N]
                  [--scheduler ADDRESS | --workers K] [render options]
    granular info SCENE.usda [--json]
    granular export-vdb SCENE.usda --prim /path -o OUT.vdb [--voxel-size S]

Exit status: 0 on success, 2 on bad input (one line `error: prim.attribute: message`,
no traceback, no output file left behind), 1 on any other failure, 130 when interrupted.
"""
import argparse
import json
import math
import os
import re
import struct
import sys
import time

from . import __version__, api, farm
from .common import (EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_OK, EXIT_USER, Progress, apply_options, check_output,
                     check_outputs, claim_outputs, frame_outputs, frame_text, int_in, parse_frames, update_scene,
                     warn_if_replaced)
from .errors import UserError, describe_tf_error

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


def _positive_float(limit=None):
    def parse(text):
        v = _number(text)
        if not math.isfinite(v) or v <= 0:
            raise argparse.ArgumentTypeError(f"{text} must be finite and > 0")
        if limit is not None and v > limit:
            raise argparse.ArgumentTypeError(f"{text} is outside (0, {limit:g}]")
        return _single(v, text)
    return parse


def _non_negative_float():
    def parse(text):
        v = _number(text)
        if not math.isfinite(v) or v < 0:
            raise argparse.ArgumentTypeError(f"{text} must be finite and >= 0")
        return _single(v, text)
    return parse


def _sun_regularization(text):
    import granular_core as core
    v, most = _number(text), core.RenderSettings.MAX_SUN_REGULARIZATION
    if not (0 <= v <= most):
        raise argparse.ArgumentTypeError(f"{text} must be in [0, {most:g}] degrees (0: off)")
    return _single(v, text)


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


MAX_SPLIT = 8  # core's RenderSettings::kMaxSplit: the most continuations a path splits into


def _roulette(text):
    v = _number(text)
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text} is not finite")
    if v < 0:
        return v
    if not 0 < v <= MAX_SPLIT:
        raise argparse.ArgumentTypeError(f"{text} must be in (0, {MAX_SPLIT}] (above 1: splitting), or negative for "
                                         "automatic")
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
    r.add_argument("--width", type=int_in(1, 32768), help="image width (default: the render "
                   "settings' resolution, else 640; with only --height, the camera's aspect)")
    r.add_argument("--height", type=int_in(1, 32768), help="image height (default: as --width)")
    r.add_argument("--spp", type=int_in(1, 1000000), default=16, help="samples per pixel (16)")
    r.add_argument("--camera", type=_prim_path("/World/Camera"), metavar="PATH",
                   help="camera prim (default: the render settings' camera, else the first camera)")
    r.add_argument("--seed", type=int_in(0, 2**31 - 1), default=0, help="sampling seed (0)")
    r.add_argument("--threads", type=int_in(0, 1024), default=0, help="threads (0: all cores)")
    r.add_argument("--exposure", type=_exposure, default=0.0,
                   help="exposure of the PNG in stops, in [-100, 100] (0)")
    r.add_argument("--technique", choices=["ept", "ept+vpt", "hybrid"], default="hybrid",
                   help="transports of the multi-scale integrator: explicit grains only (the reference), "
                        "plus volumetric path tracing in the equivalent media, plus diffusion (default)")
    r.add_argument("--roulette", type=_roulette, default=-1.0, metavar="P_a",
                   help="continuations of a path at the switch from EPT to the media, in (0, 8]: below 1 "
                        "the chance it survives (Russian roulette), above 1 splitting; negative (default): "
                        "tuned by a pre-render")
    r.add_argument("--lod", type=_non_negative_float(), default=0.5, metavar="L",
                   help="level of detail: after the first grain, enter an aggregate's medium where the grain "
                        "radius is under L times the ray footprint (default 0.5: grains narrower than a "
                        "footprint; 0: off, every grain explicit)")
    r.add_argument("--proxies", choices=["auto", "on", "off"], default="auto",
                   help="after a path's first grain, trace its low orders among the grains' bounding spheres "
                        "with tabulated grain scattering (proxies) instead of the grains themselves: on, off, "
                        "or auto (default): where the medium could not see the light, under a sun narrower "
                        "than 5 degrees (ept+vpt and hybrid)")
    r.add_argument("--medium-model", choices=["tt", "exits"], default="tt",
                   help="the equivalent medium's transport: tt (default), Meng et al. 2015's teleportation "
                        "transport; or exits, flights to the next grain met and each scattering's light moved "
                        "as the grain moves light it turns by that angle (light sent back leaves near where it "
                        "came in)")
    r.add_argument("--no-default-light", action="store_true",
                   help="a stage without any light (no UsdLux light, no emissive surface) renders black; "
                        "by default it is lit by a uniform white dome of radiance 1, with a warning")
    r.add_argument("--no-physical-sun", action="store_true",
                   help="keep delta suns (distant lights of angle 0) delta; by default, over smooth dielectric "
                        "grains, they are rendered as the physical 0.53 degree sun of the same irradiance, "
                        "with a warning")
    r.add_argument("--sun-regularization", type=_sun_regularization, default=None, metavar="DEGREES",
                   help="paths whose last bounce was smooth and that met a grain, and the light samples "
                        "of rough grains, see a sun narrower than this as a disk of this angle with the same "
                        "irradiance: the glints and caustics of grains under the 0.53 degree sun without "
                        "their fireflies, blurred to this size, or to the spread of the grain's reflections "
                        "over the pixel if less (biased; default 20, 0: exact)")
    r.add_argument("--switch-for-view", action="store_true",
                   help="measure when paths leave the proxies for the medium for this camera and these lights "
                        "too, not only for a dome: each aggregate the camera sees keeps its proxies as long as "
                        "either measurement asks (a beach seen at a grazing angle with the sun behind the camera "
                        "needs more); costs seconds per aggregate per new view, cached on disk")
    r.add_argument("--no-motion-blur", action="store_true",
                   help="render the frame's instant: the camera's shutter closed, moving grains and meshes "
                        "still (as the render settings' disableMotionBlur)")
    r.add_argument("--instanced-da", action="store_true",
                   help="the diffusion approximation also in the media of simulated grains (PointInstancers), "
                        "where the medium is uniform enough (hybrid; by default VPT to the end there)")


def build_parser():
    p = _Parser(prog="granular", description="hdGranular: render granular materials from USD stages.")
    p.add_argument("--version", action="version", version=f"granular {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_SubParser)
    sub.required = True

    r = sub.add_parser("render", help="render a stage to EXR (and PNG)")
    r.add_argument("scene", metavar="SCENE", help="USD stage (.usda, .usdc, .usd)")
    r.add_argument("-o", "--output", metavar="OUT.exr",
                   help="OpenEXR image (RGBA, Z, N, ...); without it, every render product of the stage's render "
                        "settings prim is written (its productName, vars, resolution, camera and data window)")
    r.add_argument("--png", metavar="OUT.png", help="also an 8-bit sRGB PNG")
    r.add_argument("--settings", type=_prim_path("/Render/Settings"), metavar="PRIM",
                   help="the RenderSettings prim (default: the stage's renderSettingsPrimPath, else the first)")
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
    r.add_argument("--noise-threshold", type=_positive_float(1.0), metavar="T",
                   help="adaptive sampling: each pixel stops before --spp once its standard error is at most T "
                        "times its luminance + 0.01 (checked before each of its bundles, from two bundles and "
                        "16 samples on; the delegate's convergedVariance rule), the render once every pixel has; "
                        "e.g. 0.02")
    r.add_argument("--time-limit", type=_positive_float(1e7), metavar="SECONDS",
                   help="stop rendering after SECONDS (once the first pass is complete, so that every pixel "
                        "has samples) and write the image")
    r.add_argument("--denoise", action="store_true",
                   help="also denoise the beauty with Intel Open Image Denoise (core's, found when the build "
                        "was configured), guided by the albedo and normal AOVs: channels denoised.R/G/B beside "
                        "the raw ones in the EXR, and the denoised beauty in the PNG")
    r.add_argument("--cryptomatte", action="store_true",
                   help="also the Cryptomatte layers CryptoObject00-02 and CryptoMaterial00-02 (6 ranks of prim "
                        "paths and material names by coverage) with their manifests in the EXR header")
    r.add_argument("--quiet", action="store_true", help="no progress or statistics on stderr")

    g = sub.add_parser("merge", help="join tiles (EXRs of --crop renders of one image) into one image")
    g.add_argument("tiles", nargs="+", metavar="TILE.exr")
    g.add_argument("-o", "--output", required=True, metavar="OUT.exr")
    g.add_argument("--png", metavar="OUT.png", help="also an 8-bit sRGB PNG")
    g.add_argument("--exposure", type=_exposure, default=0.0, help="exposure of the PNG in stops, in [-100, 100] (0)")
    g.add_argument("--quiet", action="store_true")

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

def _log(args, msg):
    if not getattr(args, "quiet", False):
        print(msg, file=sys.stderr)


def _warnings(args, scene):
    for w in scene.warnings:
        _log(args, "warning: " + w)


def _log_new_warnings(args, scene, shown):
    """The scene's warnings not in `shown` (kept over a sequence of frames), each once."""
    for w in scene.warnings:
        if w not in shown:
            shown.add(w)
            _log(args, "warning: " + w)


def _remove(paths):
    for p in paths:
        try:
            os.remove(p)
        except OSError:
            pass


def _apply_options(args, scene):
    """apply_options, and render's own --cryptomatte (core computes the layers)."""
    s = apply_options(args, scene)
    s.cryptomatte = bool(getattr(args, "cryptomatte", False))
    return s


def _write_images(image, exr, png, exposure):
    """Writes the EXR (and the PNG, of the denoised beauty when the image has one): each
    file appears whole or not at all (core writes through a temporary name), and a failure
    removes the one already written (all or nothing). Returns the paths written."""
    import granular_core as core
    written = []
    try:
        warn_if_replaced(core.write_exr(exr, image), exr)
        written.append(exr)
        if png:
            warn_if_replaced(core.write_png(png, _png_image(image), exposure), png)
            written.append(png)
    except BaseException:
        _remove(written)
        raise
    return written


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


def _crop_text(settings):
    x0, x1, y0, y1 = settings.crop
    return f" (pixels {x0}:{x1},{y0}:{y1})" if (x0, x1, y0, y1) != (0, 0, 0, 0) else ""


def _log_aggregates(args, built):
    for a in built.aggregates:
        _log(args, f"  aggregate {a['name']}: ~{a['approx_grains']:.3g} grains, {a['cells']} tiles "
                   f"({a['inside_cells']} inside, {a['partial_cells']} partial)")


DENOISED = ["denoised.R", "denoised.G", "denoised.B"]


def _denoise(args, image):
    """--denoise: the beauty denoised by core's Intel Open Image Denoise (core/denoise.h),
    guided by the albedo and normal AOVs, added as channels denoised.R/G/B beside the raw
    ones, which it never replaces. Without it: one warning, and the image as it is."""
    import numpy as np

    import granular_core as core
    if not core.denoiser_available():
        print(f"warning: --denoise: {core.denoiser_unavailable_reason()}; the image is written undenoised "
              "(configure the build with pyoidn in its Python, or OpenImageDenoise_DIR)", file=sys.stderr)
        return image
    px = image.pixels
    ch = list(image.channels)

    def take(names):
        return np.ascontiguousarray(px[..., [ch.index(n) for n in names]], dtype=np.float32)
    # The film holds finite, non-negative radiance, albedo in [0, 1] and unit (or zero)
    # normals: handed over as they are.
    color, albedo = take(["R", "G", "B"]), take(["albedo.R", "albedo.G", "albedo.B"])
    normal = take(["N.X", "N.Y", "N.Z"])
    out = core.denoise(color, albedo, normal)
    denoised = core.Image(np.concatenate([px, np.asarray(out, dtype=np.float32)], axis=2), ch + DENOISED,
                          image.x, image.y, image.full_width, image.full_height)
    denoised.attributes = image.attributes  # the Cryptomatte manifests
    return denoised


def _png_image(image):
    """What the PNG shows: the denoised beauty when there is one, else the image."""
    import numpy as np

    import granular_core as core
    ch = list(image.channels)
    if DENOISED[0] not in ch:
        return image
    px = image.pixels
    rgba = px[..., [ch.index(n) for n in (*DENOISED, "A")]]
    return core.Image(np.ascontiguousarray(rgba, dtype=np.float32), ["R", "G", "B", "A"], image.x, image.y,
                      image.full_width, image.full_height)


def _render_image(args, built):
    import granular_core as core
    renderer = core.Renderer(built)
    renderer.render(1, Progress(not args.quiet), 0.5, noise_threshold=getattr(args, "noise_threshold", None) or 0.0,
                    time_limit=getattr(args, "time_limit", None) or 0.0)
    if renderer.stopped_by != "samples":
        _log(args, f"  stopped at the {renderer.stopped_by} after {renderer.samples_per_pixel} of "
                   f"{args.spp} samples per pixel")
    if getattr(args, "noise_threshold", None):
        c = renderer.sample_counts
        _log(args, f"  adaptive sampling: {c['mean']:.1f} samples per pixel on average, {c['max']} at most "
                   f"(of {args.spp})")
    image = renderer.image()
    if getattr(args, "denoise", False):
        image = _denoise(args, image)
    return renderer, image


def _low_orders(built):
    """What carries the paths' low orders after their first grain: one line per aggregate
    (switching.h: measured per aggregate when explicit bounces are automatic)."""
    if not built.has_media:
        level = "proxies" if built.use_proxies else "explicit grains"
        return [f"after the first grain: {level}"]
    return [f"after the first grain: {built.low_orders_text(a)} — {info['name']}"
            for a, info in enumerate(built.aggregates)]


def _log_transports(args, built, renderer, image):
    if renderer.lost_paths:
        # Never expected: a numerical failure ended these paths and their light is missing.
        print(f"warning: {renderer.lost_paths} of {renderer.paths} paths ended by a numerical failure (a leak "
              f"through a medium's boundary); the image is darker by their light. Please report the scene.",
              file=sys.stderr)
    if built.has_media:
        rt = renderer.roulette
        tuned = f" (tuned on {rt['pixels']} pixels)" if rt["pixels"] else ""
        means = []
        for part in ("ept", "ppt", "vpt", "da"):
            c = image.channels.index(part + ".R")
            means.append(float((image.pixels[..., c:c + 3] @ [0.2126, 0.7152, 0.0722]).mean()))
        lod = f"; level of detail: {100 * renderer.shortcut_fraction:.1f}% of paths entered a medium directly" \
            if args.lod > 0 else ""
        da = f" ({100 * renderer.diffusion_fraction:.1f}% of paths)" if args.technique == "hybrid" else ""
        _log(args, f"  technique {args.technique}, bundles of {renderer.bundle_size}, P_a {rt['pa']:.3f}{tuned}; "
                   f"mean luminance by transport: EPT {means[0]:.4g}, PPT {means[1]:.4g}, VPT {means[2]:.4g}, "
                   f"DA {means[3]:.4g}{da}{lod}")
    if built.light_picks:
        _log(args, f"  light sampling picks: {built.light_picks}")
    if built.ies_profiles:
        _log(args, f"  IES profiles: {built.ies_profiles}")
    if built.light_links:
        _log(args, f"  light linking: {built.light_links}")
    if built.shadow_links:
        _log(args, f"  shadow linking: {built.shadow_links}")
    if args.technique != "ept":
        for line in _low_orders(built):
            _log(args, "  " + line)
    if not built.has_media and args.technique != "ept" and built.aggregates:
        _log(args, f"  technique {args.technique}: every aggregate is thinner than its mean free path, "
                   f"so explicit grains (EPT) render it all")
    for g in built.instanced_grains:
        if args.technique != "ept":
            _log(args, f"  {g['name']}: {g['grains']} explicit grains; after the first grain: {g['low_orders']}")
            if g["has_medium"]:
                _log(args, f"  {g['name']}: {g['diffusion']}")


def cmd_render(args):
    from .usd_reader import read_stage

    if args.output is None:
        return _render_products(args)
    check_outputs(args)
    if args.frames is not None:
        return _render_frames(args)  # frame_outputs claims each frame's files
    claim_outputs(args.output, args.png)
    t0 = time.monotonic()
    scene = read_stage(args.scene, camera=args.camera, width=args.width, height=args.height,
                       settings_path=args.settings)
    s = _apply_options(args, scene)
    _warnings(args, scene)
    built = api.build_scene(scene, log=lambda line: _log(args, "  waiting for aggregate " + line))
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
    compared with the one the built scene holds (core.compare_scenes, every field): the built
    scene is kept as it is when nothing changed, given the new view when only the camera or the
    view's settings changed (Scene.set_view: no voxelising, no TT work), else built anew,
    reusing every aggregate whose inputs did not change (a moving light voxelises nothing, a
    deforming boundary or a grain material only its aggregates). Each frame's files are written
    atomically as it completes; a failure leaves the frames before it, complete, and nothing
    of its own."""
    import granular_core as core
    from .usd_reader import open_stage, read_stage

    frames = parse_frames(args.frames)
    exr_name, png_name = frame_outputs(args, frames)
    t0 = time.monotonic()
    stage = open_stage(args.scene)
    built = None
    shown = set()
    for k, frame in enumerate(frames):
        tf = time.monotonic()
        scene = read_stage(args.scene, camera=args.camera, width=args.width, height=args.height, stage=stage,
                           time=frame, settings_path=getattr(args, "settings", None))
        s = _apply_options(args, scene)
        _log_new_warnings(args, scene, shown)
        built, changes = update_scene(scene, built)
        if changes is None:
            _log_build_warnings(args, built, shown)
            _log(args, f"{args.scene}: frames {frame_text(frames[0])} to {frame_text(frames[-1])} "
                       f"({len(frames)}), camera {scene.camera_path}, {s.width}x{s.height}{_crop_text(s)}, {s.spp} spp")
            _log_aggregates(args, built)
            action = f"scene built in {time.monotonic() - tf:.2f} s"
        elif changes.level in (core.SceneChange.Unchanged, core.SceneChange.View):
            action = f"scene reused ({changes.description})"
        else:
            _log_build_warnings(args, built, shown)  # a later frame may bring its own
            action = (f"scene rebuilt ({changes.description}; aggregates: {built.aggregates_built} built, "
                      f"{built.aggregates_reused} reused) in {time.monotonic() - tf:.2f} s")
        t1 = time.monotonic()
        renderer, image = _render_image(args, built)
        seconds = time.monotonic() - t1
        if k == 0:
            _log_transports(args, built, renderer, image)
        written = _write_images(image, exr_name(frame), png_name(frame) if png_name else None, args.exposure)
        _log(args, f"frame {frame_text(frame)}: {action}; render {seconds:.2f} s; wrote {' and '.join(written)}")
    _log(args, f"{len(frames)} frames in {time.monotonic() - t0:.1f} s")
    return EXIT_OK


# Options that say what one image is; products say that themselves.
_IMAGE_ONLY = (("png", "--png"), ("width", "--width"), ("height", "--height"), ("camera", "--camera"),
               ("crop", "--crop"), ("denoise", "--denoise"))


def _product_frames(args, stage):
    """[(frame for file names, time to read)]: --frames, else the stage's start (no frame
    number when the stage has no authored time range: a productName with frame tokens then
    needs --frames)."""
    if args.frames is not None:
        return [(f, f) for f in parse_frames(args.frames)]
    return [(stage.GetStartTimeCode() if stage.HasAuthoredTimeCodeRange() else math.nan, None)]


def _render_products(args):
    """render without -o: every product of the active render settings prim (usd_reader
    read_render_products, core's render_products.h), each frame's products grouped by camera
    and resolution, each group rendered once over the union of its products' data windows,
    each product written by core.write_product (the delegate's writer too). Every product's
    file is checked for every frame before anything is rendered; a frame's files are written
    whole, all or none."""
    import granular_core as core
    from pxr import UsdGeom

    from .usd_reader import open_stage, read_render_products, read_stage

    for attr, flag in _IMAGE_ONLY:
        if getattr(args, attr, None):
            raise UserError("command line", flag, "applies to -o; without -o the render settings' products say "
                                                  "what is rendered and written")
    t0 = time.monotonic()
    stage = open_stage(args.scene)
    plan, seen, shown = [], {}, set()
    for frame, when in _product_frames(args, stage):
        settings, products, warnings = read_render_products(stage, when, args.settings)
        for w in warnings:
            if w not in shown:
                shown.add(w)
                _log(args, "warning: " + w)
        if settings is None:
            raise UserError("command line", "-o", "is required: the stage has no RenderSettings prim whose "
                                                  "products could be written instead")
        if not products:
            raise UserError(str(settings.GetPath()), "products", "no render product to write (give -o, or add "
                                                                 "RenderProducts to the render settings)")
        for p in products:
            try:
                core.check_product_output(p, frame)
                name = os.path.abspath(core.product_file_name(p, frame))
            except core.InputError as e:
                raise UserError(e.object, e.attribute, e.detail) from None
            if name in seen:  # one file per product and frame
                raise UserError(p.path, "productName", f'"{name}" is also written by {seen[name]}'
                                                       + (" (frame tokens $F4 or #### give each frame its file)"
                                                          if seen[name].startswith(p.path + " ") else ""))
            seen[name] = f"{p.path} at frame {frame_text(frame) if math.isfinite(frame) else '-'}"
        plan.append((frame, when, {"products": products,
                                   "names": [os.path.abspath(core.product_file_name(p, frame)) for p in products]}))
    claim_outputs(*(n for _, _, ps in plan for n in ps["names"]))
    built = None
    for frame, when, ps in plan:
        groups = {}
        for p in ps["products"]:
            groups.setdefault((p.camera, p.width, p.height), []).append(p)
        written = []
        try:
            for (camera, width, height), products in groups.items():
                if camera:
                    prim = stage.GetPrimAtPath(camera)
                    if not prim or not prim.IsA(UsdGeom.Camera):
                        raise UserError(products[0].path, "camera", f"target {camera} is not a Camera")
                scene = read_stage(args.scene, camera=camera or None, width=width, height=height, stage=stage,
                                   time=when, settings_path=args.settings)
                s = apply_options(args, scene)
                # Cryptomatte layers exist only in a film that keeps them.
                s.cryptomatte = s.cryptomatte or any(p.needs_cryptomatte for p in products)
                x0, x1, y0, y1 = core.union_window(products)
                s.crop = (0, 0, 0, 0) if (x0, x1, y0, y1) == (0, width, 0, height) else (x0, x1, y0, y1)
                _log_new_warnings(args, scene, shown)
                built, changes = update_scene(scene, built)
                if changes is None:
                    _log_build_warnings(args, built, shown)
                    _log_aggregates(args, built)
                t1 = time.monotonic()
                renderer, image = _render_image(args, built)
                _log(args, f"{args.scene}: frame {frame_text(frame) if math.isfinite(frame) else '-'}: camera "
                           f"{scene.camera_path}, {width}x{height}{_crop_text(s)}, {s.spp} spp, rendered in "
                           f"{time.monotonic() - t1:.2f} s for {', '.join(p.path for p in products)}")
                for p in products:
                    name = core.product_file_name(p, frame)
                    warn_if_replaced(core.write_product(p, image, frame), name)
                    written.append(name)
                    _log(args, f"wrote {name} (product {p.path}: {', '.join(p.channels)})")
        except BaseException:
            _remove(written)
            raise
    _log(args, f"{sum(len(ps['products']) for _, _, ps in plan)} product file(s) in {time.monotonic() - t0:.1f} s")
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


def _explicit_grains_report(scene):
    """Per PointInstancer of simulated grains: what was read and what its grid costs
    (core/instanced_grains.h)."""
    import granular_core as core
    from .usd_reader import read_instanced_grains, translate_core_error
    report = []
    for prim in scene.explicit_grains:
        desc = read_instanced_grains(scene, prim)
        grid = core.InstancedGrains()
        try:
            grid.build(desc)
        except core.InputError as e:
            raise translate_core_error(e) from None
        st = grid.stats
        report.append({"prim": str(prim.GetPath()), "prototypes": [p.name for p in desc.prototypes],
                       "grains": st["grains"], "motion": desc.has_motion, "cells": list(st["cells"]),
                       "cell_size": st["cell_size"], "entries": st["entries"], "blocks": st["occupied_blocks"],
                       "grid_bytes": st["grid_bytes"], "bytes_per_grain": st["bytes_per_grain"],
                       "input_bytes": st["input_bytes"], "build_seconds": st["build_seconds"],
                       "overlap_seconds": st["overlap_seconds"], "rendered": True})
    return report


def _explicit_lines(r):
    c = r["cells"]
    return [
        f"{r['prim']}  (explicit grains of a PointInstancer, traced grain by grain)",
        f"  prototypes    {', '.join(r['prototypes'])}",
        f"  grains        {r['grains']}  ({'with' if r['motion'] else 'no'} velocities)",
        f"  grid          {c[0]} x {c[1]} x {c[2]} cells of edge {r['cell_size']:.4g}, {r['entries']} entries "
        f"in {r['blocks']} occupied blocks",
        f"  memory        {r['grid_bytes'] / 2**20:.3g} MiB grid ({r['bytes_per_grain']:.1f} bytes per grain) beyond "
        f"{r['input_bytes'] / 2**20:.3g} MiB of grain arrays",
        f"  build         {1e3 * r['build_seconds']:.3g} ms grid, {1e3 * r['overlap_seconds']:.3g} ms overlap check",
    ]


def cmd_info(args):
    scene = api.read_aggregates(args.scene)
    report = api.aggregate_report(scene=scene)
    explicit = _explicit_grains_report(scene)
    if args.json:
        print(json.dumps({"scene": args.scene, "aggregates": report, "explicit_grains": explicit}, indent=2))
        return EXIT_OK
    _warnings(args, scene)
    if not report and not explicit:
        print(f"{args.scene}: no granular aggregates (no Mesh with GranularAggregateAPI)")
    for r in report:
        print("\n".join(api.report_lines(r)))
    for r in explicit:
        print("\n".join(_explicit_lines(r)))
    return EXIT_OK


def cmd_export_vdb(args):
    """An aggregate's coarse density (sigma_t inside its boundary), or an instancer of
    explicit grains' packing rate (grain_density.py)."""
    from . import grain_density
    check_output(args.output, "-o", (".vdb",))
    claim_outputs(args.output)
    scene = api.read_aggregates(args.scene)
    instancer = grain_density.explicit_grains_prim(scene, args.prim)
    if instancer is not None:
        r = grain_density.export_grain_density(scene, instancer, args.output, args.voxel_size, source=args.scene)
        summary = grain_density.export_summary(args.prim, args.output, r)
    else:
        r = api.export_density(args.prim, args.output, args.voxel_size, path=args.scene, stage=scene.stage)
        summary = api.export_summary(args.prim, args.output, r)
    warn_if_replaced(r.get("replaced_other"), args.output)
    _log(args, summary)
    return EXIT_OK


def cmd_farm(args):
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
