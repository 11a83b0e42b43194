"""`granular farm`: a frame sequence as Dask tasks, one per frame and image tile, merged bit for bit.

    granular farm SCENE.usda -o out/frame.####.exr [--png out/frame.####.png] --frames A:B[xSTEP]
                  [--tiles N] [--scheduler ADDRESS | --workers K] [--retries R] [render options]

Each task renders one tile of one frame through the code of `granular render`: the stage
read at the frame's time, the command line's options, core.Scene.build, core.Renderer, with
the tile as the render's crop (RenderSettings.crop). A pixel's samples depend on the seed,
the pixel and the sample index only, and what is computed once per image (the roulette
pre-render over the whole image, the TT parameters) is the same whatever the crop, so the
merged tiles are the single-process render bit for bit. Tasks return their pixels; the client
merges each frame's tiles (core.merge_tiles) as they arrive and writes the frame's PNG, then
its EXR, each through a temporary name: a frame's EXR appears complete or not at all.

Dask schedules: without --scheduler a LocalCluster of K worker processes (default: the
cores) with one task at a time each and cores/K render threads; with --scheduler, the
workers of that scheduler (start them with `dask worker ADDRESS --nthreads 1` on machines
with this checkout, its venv and a shared GRANULAR_CACHE_DIR), each rendering with all its
cores. A task that fails (an exception, a lost worker) is run again by Dask (--retries); a
stage that cannot be read fails the whole job at once, before any task runs where the
client can see it, else at its first task: exit 2, one `error:` line, no frame written
after it.
"""
import argparse
import ipaddress
import logging
import math
import os
import re
import sys
import threading
import time

from .common import (EXIT_OK, Progress, apply_options, check_outputs, frame_outputs, frame_text, int_in, parse_frames,
                     update_scene, warn_if_replaced)
from .errors import UserError

DEFAULT_TILES = 4
# How long the client keeps trying a --scheduler that does not answer (Dask retries a refused
# connection meanwhile, so a scheduler may still be starting).
CONNECT_TIMEOUT = "20s"

_ADDRESS = re.compile(r"(?:tcp://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_](?:[A-Za-z0-9_.-]*[A-Za-z0-9_])?):([0-9]{1,5})")


def scheduler_address(text):
    """--scheduler: tcp://HOST:PORT (HOST:PORT is tcp to Dask too), refused here rather than
    by Dask, whose ValueError would not name the option."""
    m = _ADDRESS.fullmatch(text)
    ok = bool(m) and 1 <= int(m.group(2)) <= 65535
    if ok and m.group(1).startswith("["):
        try:
            ipaddress.IPv6Address(m.group(1)[1:-1])
        except ValueError:
            ok = False
    if not ok:
        raise argparse.ArgumentTypeError(f"'{text}' is not a scheduler address (tcp://HOST:PORT)")
    return text


def add_parser(sub, render_options):
    f = sub.add_parser("farm", help="render a frame sequence as Dask tasks (frames x tiles), on this machine "
                                    "or a farm")
    f.add_argument("scene", metavar="SCENE", help="USD stage (.usda, .usdc, .usd)")
    f.add_argument("-o", "--output", required=True, metavar="OUT.####.exr",
                   help="OpenEXR per frame; a run of '#' is replaced by the frame number, as in render --frames")
    f.add_argument("--png", metavar="OUT.####.png", help="also an 8-bit sRGB PNG per frame")
    f.add_argument("--frames", required=True, metavar="A:B[xSTEP]", help="the frames, as in render --frames")
    f.add_argument("--tiles", type=int_in(1, 4096), default=DEFAULT_TILES, metavar="N",
                   help=f"tiles per frame, each its own task (default {DEFAULT_TILES}): a grid of about "
                        "sqrt(N) x sqrt(N)")
    where = f.add_mutually_exclusive_group()
    where.add_argument("--scheduler", type=scheduler_address, metavar="ADDRESS",
                       help="a running Dask scheduler (tcp://host:8786); default: a LocalCluster here")
    where.add_argument("--workers", type=int_in(1, 1024), metavar="K",
                       help="worker processes of the LocalCluster (default: the cores)")
    f.add_argument("--retries", type=int_in(0, 100), default=2,
                   help="times Dask runs a failed task again (default 2; a lost worker's tasks are rescheduled "
                        "besides)")
    render_options(f)
    f.add_argument("--quiet", action="store_true", help="no progress or log on stderr")
    return f


# ---- tiles -----------------------------------------------------------------------------------

def grid(n):
    """(rows, columns) of n tiles: the most nearly square factorisation, more columns than
    rows (images are wider than tall)."""
    rows = int(math.isqrt(n))
    while n % rows:
        rows -= 1
    return rows, n // rows


def tile_windows(window, n):
    """n pixel windows (x0, x1, y0, y1) tiling `window` in a grid (rows, then columns), their
    edges spread as evenly as whole pixels allow; fewer rows or columns than the grid asks
    where the window is too narrow for them (never an empty tile)."""
    x0, x1, y0, y1 = window
    rows, cols = grid(n)
    rows, cols = min(rows, y1 - y0), min(cols, x1 - x0)
    xs = [x0 + (x1 - x0) * c // cols for c in range(cols + 1)]
    ys = [y0 + (y1 - y0) * r // rows for r in range(rows + 1)]
    return [(xs[c], xs[c + 1], ys[r], ys[r + 1]) for r in range(rows) for c in range(cols)]


# ---- the task (runs on a worker) ---------------------------------------------------------------

class _WorkerState:
    """What a worker process keeps between tasks: the open stage, and the last built scene
    (which holds its description), so that the tiles of a frame build it once and the next
    frame reuses what did not change (common.update_scene, as render --frames does). One task
    at a time: a render already uses every core it is given."""

    def __init__(self):
        self.lock = threading.Lock()
        self.key = None
        self.stage = None
        self.built = None
        # P_a tuned by the pre-render of a frame, by (frame, the job's options): the frame's
        # later tiles pass it on as the roulette setting instead of tuning again — the same
        # float, so the same image (the pre-render covers the whole image anyway). The stage
        # read again forgets them.
        self.tuned = {}

    def use_stage(self, path):
        """The stage at `path` (absolute), opened again when the file changed; forgets
        everything else then. The caller holds the lock."""
        from .usd_reader import open_stage
        try:
            key = (path, os.stat(path).st_mtime_ns)
        except OSError:
            key = (path, None)
        if self.key != key:
            self.stage = open_stage(path)
            self.key, self.built = key, None
            self.tuned.clear()
        return self.stage


_STATE = _WorkerState()


def render_tile(job, frame, window):
    """Renders one tile of one frame; returns its pixels and where they lie, or
    {"error": (object, attribute, message)} for bad input, which no retry can fix. `job`
    holds the command line's render options (the names of `granular render`'s)."""
    import argparse
    import granular_core as core
    from pxr import Tf
    from .errors import describe_tf_error
    from .usd_reader import read_stage

    args = argparse.Namespace(**job)
    t0 = time.monotonic()
    with _STATE.lock:
        try:
            scene = read_stage(job["scene"], camera=args.camera, width=args.width, height=args.height,
                               stage=_STATE.use_stage(job["scene"]), time=frame)
            s = apply_options(args, scene)
            frame_key = (frame, tuple(sorted(job.items())))
            if frame_key in _STATE.tuned:
                s.roulette = _STATE.tuned[frame_key]
            s.crop = tuple(window)
            # Another tile of the frame, or a frame that moves only the camera: a new view.
            built, changes = update_scene(scene, _STATE.built)
            action = "reused" if changes is not None and changes.level in (
                core.SceneChange.Unchanged, core.SceneChange.View) else "built"
            _STATE.built = built
            t1 = time.monotonic()
            renderer = core.Renderer(built)
            if not renderer.render(1, None, 0.5):
                raise RuntimeError("render cancelled")
            image = renderer.image()
            if s.roulette < 0 and built.has_media:
                if len(_STATE.tuned) > 64:
                    _STATE.tuned.clear()
                _STATE.tuned[frame_key] = renderer.roulette["pa"]
        except (UserError, core.InputError, Tf.ErrorException) as e:
            _STATE.key = None  # read the stage again next time
            if isinstance(e, UserError):
                return {"error": (e.object, e.attribute, e.message)}
            if isinstance(e, core.InputError):
                return {"error": (e.object, e.attribute, e.detail)}
            return {"error": (job["scene"], "", " ".join(describe_tf_error(e).split()))}
    return {"frame": frame, "window": tuple(window), "pixels": image.pixels, "channels": list(image.channels),
            "x": image.x, "y": image.y, "full": (image.full_width, image.full_height), "scene": action,
            "build_seconds": t1 - t0, "render_seconds": time.monotonic() - t1, "pid": os.getpid()}


# Options a task needs; everything else (outputs, scheduling) stays on the client.
_JOB_OPTIONS = ("scene", "camera", "width", "height", "spp", "seed", "threads", "technique", "roulette", "lod", "proxies", "medium_model",
                "no_default_light", "no_physical_sun", "sun_regularization", "switch_for_view", "no_motion_blur",
                "instanced_da")


# ---- the client ------------------------------------------------------------------------------

def _log(args, msg):
    if not args.quiet:
        print(msg, file=sys.stderr)


def _check_scene(args, frames):
    """Reads every frame's description here, as a task would (no build), so that a stage that
    cannot be read fails the job before any task runs; returns each frame's pixel window."""
    import granular_core as core
    from .usd_reader import open_stage, read_stage, validate

    stage = open_stage(args.scene)
    windows = {}
    for frame in frames:
        scene = read_stage(args.scene, camera=args.camera, width=args.width, height=args.height, stage=stage,
                           time=frame)
        s = apply_options(args, scene)
        validate(scene)
        windows[frame] = core.render_window(s)
        if frame == frames[0]:
            for w in scene.warnings:
                _log(args, "warning: " + w)
            _log(args, f"{args.scene}: camera {scene.camera_path}, {s.width}x{s.height}, {s.spp} spp")
    return windows


def _warm(scene):
    """On a worker: the imports and the stage opened before its first task (while the client
    reads the frames), so that no task waits for them."""
    import granular_core  # noqa: F401
    from . import api, usd_reader  # noqa: F401
    with _STATE.lock:
        try:
            _STATE.use_stage(scene)
        except Exception:  # the task reports it, with the stage's own words
            return False
    return True


def _quiet():
    """On a worker about to be shut down on purpose: its lost heartbeat to the scheduler that
    closes first is not an error to print."""
    logging.getLogger("distributed").setLevel(logging.CRITICAL)


class _Cluster:
    """Starts the Dask client (and, without --scheduler, its LocalCluster) on a thread and
    warms its workers, while the caller reads the stage; result() waits for it."""

    def __init__(self, args):
        self.args = args
        self.client = self.cluster = self.where = self.error = None
        self.thread = threading.Thread(target=self._start, daemon=True)
        self.thread.start()

    def _start(self):
        import dask
        from distributed import Client, LocalCluster
        args = self.args
        # Workers render with every core they are given: their statistical profiler (a stack
        # sample every 10 ms) and a 20 ms event-loop tick only take cycles from the render.
        dask.config.set({"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "200ms"})
        try:
            if args.scheduler:
                try:
                    self.client = Client(args.scheduler, timeout=CONNECT_TIMEOUT)
                except (OSError, TimeoutError, ValueError) as e:
                    raise UserError("command line", "--scheduler", f"cannot reach {args.scheduler}: "
                                                                   f"{' '.join(str(e).split())}") from None
                workers = len(self.client.scheduler_info().get("workers", {}))
                self.where = f"scheduler {args.scheduler} ({workers} workers now)"
            else:
                k = args.workers or os.cpu_count() or 1
                self.cluster = LocalCluster(n_workers=k, threads_per_worker=1, processes=True,
                                            dashboard_address=None, silence_logs=logging.ERROR)
                self.client = Client(self.cluster)
                self.where = f"a LocalCluster of {k} worker processes"
            self.client.run(_warm, os.path.abspath(args.scene))
        except BaseException as e:  # handed to the caller by result()
            self.error = e

    def result(self):
        self.thread.join()
        if self.error is not None:
            self.close()
            raise self.error
        return self.client, self.where

    def close(self):
        self.thread.join()
        if self.client is not None:
            if self.cluster is not None:  # our own workers
                try:
                    self.client.run(_quiet)
                except Exception:  # a worker already gone has nothing left to print
                    pass
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def _write_frame(image, exr, png, exposure):
    """The PNG, then the EXR, each written whole or not at all: the EXR marks a finished frame."""
    import granular_core as core
    if png:
        warn_if_replaced(core.write_png(png, image, exposure), png)
    warn_if_replaced(core.write_exr(exr, image), exr)
    return [p for p in (png, exr) if p]


def run(args):
    check_outputs(args)
    frames = parse_frames(args.frames)
    exr_name, png_name = frame_outputs(args, frames)
    t0 = time.monotonic()
    cluster = _Cluster(args)  # starts while the frames are read
    try:
        windows = _check_scene(args, frames)
        for frame, w in windows.items():
            if args.tiles > (w[1] - w[0]) * (w[3] - w[2]):
                raise UserError("command line", "--tiles", f"{args.tiles} tiles are more than the {w[1] - w[0]}x"
                                                           f"{w[3] - w[2]} pixels of frame {frame_text(frame)}")
        job = {name: getattr(args, name) for name in _JOB_OPTIONS}
        job["scene"] = os.path.abspath(args.scene)
        if not args.scheduler and not args.threads:  # share this machine's cores among its workers
            job["threads"] = max(1, (os.cpu_count() or 1) // (args.workers or os.cpu_count() or 1))
        client, where = cluster.result()
        tasks = {}
        futures = []
        for frame in frames:
            tiles = tile_windows(windows[frame], args.tiles)
            tasks[frame] = len(tiles)
            for k, w in enumerate(tiles):
                futures.append(client.submit(render_tile, job, frame, w, retries=args.retries, pure=False,
                                             key=f"granular-tile-{frame_text(frame)}-{k}-{os.getpid()}-{t0}"))
        _log(args, f"farm: {len(frames)} frames x {args.tiles} tiles = {len(futures)} tasks on {where}; set-up "
                   f"{time.monotonic() - t0:.2f} s")
        return _collect(args, client, futures, tasks, exr_name, png_name, t0)
    finally:
        cluster.close()


def _collect(args, client, futures, tasks, exr_name, png_name, t0):
    import granular_core as core
    from distributed import as_completed

    progress = Progress(not args.quiet, unit="tasks")
    pending = {frame: [] for frame in tasks}
    done = 0
    builds = 0
    busy = 0.0  # seconds the tasks spent building and rendering
    workers = set()
    for future in as_completed(futures):
        result = future.result()  # re-raises a task's exception once its retries are spent
        if "error" in result:
            for f in futures:
                f.cancel()
            raise UserError(*result["error"])
        done += 1
        builds += result["scene"] == "built"
        busy += result["build_seconds"] + result["render_seconds"]
        workers.add(result["pid"])
        frame = result["frame"]
        pending[frame].append(core.Image(result["pixels"], result["channels"], result["x"], result["y"],
                                         *result["full"]))
        progress(done, len(futures), time.monotonic() - t0)
        if len(pending[frame]) == tasks[frame]:
            image = core.merge_tiles(pending.pop(frame))
            written = _write_frame(image, exr_name(frame), png_name(frame) if png_name else None, args.exposure)
            if not progress.tty:
                _log(args, f"frame {frame_text(frame)}: {tasks[frame]} tiles merged; wrote {' and '.join(written)}")
    _log(args, f"{len(tasks)} frames, {done} tasks in {time.monotonic() - t0:.1f} s ({builds} scene builds on "
               f"{len(workers)} worker processes; the tasks read, built and rendered for {busy:.1f} s in all)")
    return EXIT_OK
