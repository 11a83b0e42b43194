"""The `granular` command: render a USD stage, report its aggregates, export coarse density.

    granular render SCENE.usda -o OUT.exr [--png OUT.png] [--width W --height H] [--spp N]
                    [--camera /path] [--seed S] [--threads T] [--exposure E] [--quiet]
                    [--technique ept|ept+vpt|hybrid] [--roulette P_a] [--lod L]
    granular info SCENE.usda [--json]
    granular export-vdb SCENE.usda --prim /path -o OUT.vdb [--voxel-size S]

Exit status: 0 on success, 2 on bad input (one line `error: prim.attribute: message`,
no traceback, no output file left behind), 1 on any other failure, 130 when interrupted.
"""
import argparse
import json
import math
import os
import sys
import time

from . import __version__, api
from .errors import UserError

EXIT_OK, EXIT_FAILURE, EXIT_USER, EXIT_INTERRUPTED = 0, 1, 2, 130


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one `error:` line and exit status 2."""

    def error(self, message):
        raise UserError("command line", "", message)


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


def _positive_float():
    def parse(text):
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
        if not math.isfinite(v) or v <= 0:
            raise argparse.ArgumentTypeError(f"{text} must be finite and > 0")
        return v
    return parse


def _non_negative_float():
    def parse(text):
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
        if not math.isfinite(v) or v < 0:
            raise argparse.ArgumentTypeError(f"{text} must be finite and >= 0")
        return v
    return parse


def _finite_float():
    def parse(text):
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"{text} is not finite")
        return v
    return parse


def _roulette(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if math.isnan(v) or v == 0 or v > 1:
        raise argparse.ArgumentTypeError(f"{text} must be in (0, 1], or negative for automatic")
    return v


def build_parser():
    p = _Parser(prog="granular", description="hdGranular: render granular materials from USD stages.")
    p.add_argument("--version", action="version", version=f"granular {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    r = sub.add_parser("render", help="render a stage to EXR (and PNG)")
    r.add_argument("scene", metavar="SCENE", help="USD stage (.usda, .usdc, .usd)")
    r.add_argument("-o", "--output", required=True, metavar="OUT.exr", help="OpenEXR image (RGBA, Z, N)")
    r.add_argument("--png", metavar="OUT.png", help="also an 8-bit sRGB PNG")
    r.add_argument("--width", type=_int_in(1, 32768), help="image width (default: the render "
                   "settings' resolution, else 640; with only --height, the camera's aspect)")
    r.add_argument("--height", type=_int_in(1, 32768), help="image height (default: as --width)")
    r.add_argument("--spp", type=_int_in(1, 1000000), default=16, help="samples per pixel (16)")
    r.add_argument("--camera", metavar="PATH", help="camera prim (default: the render settings' camera, "
                   "else the first camera)")
    r.add_argument("--seed", type=_int_in(0, 2**31 - 1), default=0, help="sampling seed (0)")
    r.add_argument("--threads", type=_int_in(0, 1024), default=0, help="threads (0: all cores)")
    r.add_argument("--exposure", type=_finite_float(), default=0.0,
                   help="exposure of the PNG in stops (0)")
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
    r.add_argument("--quiet", action="store_true", help="no progress or statistics on stderr")

    i = sub.add_parser("info", help="grain counts, tiles and transport parameters of each aggregate")
    i.add_argument("scene", metavar="SCENE")
    i.add_argument("--json", action="store_true", help="print JSON instead of text")

    e = sub.add_parser("export-vdb", help="coarse density of an aggregate as an OpenVDB grid 'density'")
    e.add_argument("scene", metavar="SCENE")
    e.add_argument("--prim", required=True, metavar="PATH", help="the aggregate's boundary mesh")
    e.add_argument("-o", "--output", required=True, metavar="OUT.vdb")
    e.add_argument("--voxel-size", type=_positive_float(), default=0.0,
                   help="world units (default: the boundary's largest extent / 128)")
    e.add_argument("--quiet", action="store_true")
    return p


# ---- helpers ------------------------------------------------------------------------------

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


class _Progress:
    """A progress bar on stderr; on a terminal it redraws one line, else it prints a few."""

    def __init__(self, enabled, stream=sys.stderr):
        self.enabled = enabled
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
        line = f"  [{bar}] {done:.1f}/{target} spp  {seconds:.1f} s  eta {eta:.0f} s"
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


# ---- commands ---------------------------------------------------------------------------------

def cmd_render(args):
    import granular_core as core
    from .usd_reader import read_stage

    _check_output(args.output, "-o", (".exr",))
    if args.png:
        _check_output(args.png, "--png", (".png",))
    if args.png and os.path.abspath(args.png) == os.path.abspath(args.output):
        raise UserError("command line", "--png", "is the same file as -o")
    t0 = time.monotonic()
    scene = read_stage(args.scene, camera=args.camera, width=args.width, height=args.height)
    s = scene.desc.settings
    s.spp = args.spp
    s.seed = args.seed
    s.threads = args.threads
    s.technique = core.technique_from_name(args.technique, "command line")
    s.roulette = args.roulette
    s.lod = args.lod
    _warnings(args, scene)
    built = api.build_scene(scene)
    _log(args, f"{args.scene}: camera {scene.camera_path}, {s.width}x{s.height}, {s.spp} spp; "
               f"scene read and built in {time.monotonic() - t0:.2f} s")
    for a in built.aggregates:
        _log(args, f"  aggregate {a['name']}: ~{a['approx_grains']:.3g} grains, {a['cells']} tiles "
                   f"({a['inside_cells']} inside, {a['partial_cells']} partial)")
    renderer = core.Renderer(built)
    t1 = time.monotonic()
    renderer.render(1, _Progress(not args.quiet), 0.5)
    image = renderer.image()
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
    written = []
    try:
        core.write_exr(args.output, image)
        written.append(args.output)
        if args.png:
            core.write_png(args.png, image, args.exposure)
            written.append(args.png)
    except BaseException:
        _remove(written)  # all or nothing
        raise
    _log(args, f"wrote {' and '.join(written)} (render {time.monotonic() - t1:.1f} s, "
               f"total {time.monotonic() - t0:.1f} s)")
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
    r = api.export_density(args.prim, args.output, args.voxel_size, path=args.scene)
    _log(args, api.export_summary(args.prim, args.output, r))
    return EXIT_OK


COMMANDS = {"render": cmd_render, "info": cmd_info, "export-vdb": cmd_export_vdb}


def main(argv=None):
    try:
        args = build_parser().parse_args(argv)
    except UserError as e:
        print(f"error: {e.message} (see granular --help)", file=sys.stderr)
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
