"""Long shots on many devices: contiguous chunks of a frame range rendered by Dask.distributed workers.

>>> stats = render_shot("scenes_usd/pool.usda", range(0, 1200), "shot", RenderSettings(width=1920, height=1080),
...                     workers=2)                    # a LocalCluster, one worker per GPU (or per CPU process)
>>> stats = render_shot(..., scheduler="tcp://head:8786")  # the workers of a running cluster

Plan (client side, :func:`render_shot`): the frames still to write are cut into one contiguous chunk per
worker (:func:`plan_chunks`, balanced so that a chunk's warm-up counts against it); one exposure for the
whole shot is rendered once (the shot's first frame with a fresh history, exactly as
:func:`cisp_warp.sequence.render_sequence` picks it) or taken from ``--exposure`` or an earlier run's
``shot.json``; then every chunk is a Dask task (:func:`render_chunk`), and the MP4 is assembled once, after
the last chunk, from the PNGs in time-code order.

A chunk, on its worker: the renderer and animation of the shot are built once per worker process and kept
(:func:`worker_renderer`); the temporal state is restarted (:func:`restart_history`) and the chunk renders
``warmup`` frames before its first frame to write (not written), so that its denoiser history matches a
single-process run's (see :func:`warmup_frames` for how many, and what is left). A frame's random streams
come from the seed and its index in the shot (time code − shot start), so every frame, warm-up or not, gets
the photons it gets in one process. Frames go to ``final.####.png`` (#### = the time code: chunks never
collide), tone mapped and PNG-encoded by a per-worker thread pool (:class:`FrameWriter`) while the device
renders the next frame, written to a temporary name and renamed, so a frame on disk is always complete.

Faults: a worker that dies (process killed, host lost) loses its task, and the scheduler runs the chunk
again on another worker (Dask's ``distributed.scheduler.allowed-failures``); the re-run skips the frames
already written in this run and warms up before its first missing one. ``resume=True`` renders only frames
missing from ``out``. Progress over all frames is one bar fed by the frames appearing in ``out``.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import signal
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import SceneError
from .render import RenderSettings

MISSING_ENGINE = ("--workers and --scheduler need Dask.distributed, which is not installed "
                  "(python3 -m pip install -e '.[distributed]')")
MANIFEST = "shot.json"  #: in ``out``: what the shot's frames were rendered with (exposure, settings, range)


def frame_name(code: int) -> str:
    """File name of time code ``code``'s tone-mapped frame, as :func:`cisp_warp.sequence.render_sequence` names it."""
    return f"final.{int(code):04d}.png"


# ------------------------------------------------------------------------------------------ warm-up and plan


OUTPUT_STEP = 1.0 / 255.0  #: one step of the 8-bit output, relative to full scale: what a seam may differ by


def warmup_frames(settings: RenderSettings) -> int:
    """Frames a chunk renders (unwritten) before its first frame so its temporal state matches one process's.

    * ``caustics_map``'s temporal filter is the mean of the last ``cmap_history`` frames: ``cmap_history - 1``
      frames rebuild it exactly (bit for bit on the CPU).
    * SVGF (where it denoises the method's map) blends each frame into its colour and moment histories with
      weight ``max(1/h, alpha)``, ``h`` the pixel's history length. After ``1/alpha`` frames the weights of a
      chunk equal a single-process run's (``h`` differs, but enters only through that weight and the
      spatial-variance threshold of 4 frames); from then on the difference between the two histories is
      multiplied by at most ``1 - alpha`` per frame (the à-trous feedback is non-expansive: energy-conserving
      weights). It starts no larger than the caustic's own range, so ``W = ln(1/255) / ln(1 - alpha)``
      frames (25 at the default alpha = 0.2) bring it below one step of the 8-bit output, relative to the
      frame's peak. Measured on the pool (``tests/test_distributed.py``, 32x18 and 64x36): 0.04% to 0.13% of
      the peak radiance of ``final`` after 25 frames, 1.7% after 8, and float32 resolution only after ~100:
      a chunk after a warm-up is close to one process, not bit-identical; a chunk whose warm-up reaches the
      shot's first frame starts there and is identical.
    * The Gaussian gather, the reference and raw maps keep no history: 0.
    """
    w = 0
    ps = settings.photons
    if settings.method == "caustics_map":
        w = int(ps.cmap_history) - 1
    denoised = settings.method in ("cisp", "sspm") or (settings.method == "caustics_map" and ps.cmap_gather != "light")
    alpha = min(settings.svgf.alpha_color, settings.svgf.alpha_moments)
    if denoised and settings.denoiser == "svgf" and alpha < 1.0:
        w = max(w, math.ceil(1.0 / alpha), math.ceil(math.log(OUTPUT_STEP) / math.log1p(-alpha)))
    return w


@dataclass(frozen=True)
class Chunk:
    """Time codes ``start`` .. ``stop - 1`` of a shot, written by one task (those not yet on disk)."""

    start: int
    stop: int

    def __len__(self) -> int:
        return self.stop - self.start


def plan_chunks(todo, shot_start: int, workers: int, warmup: int) -> list[Chunk]:
    """Cut the time codes ``todo`` (to write) into at most ``max(workers, runs)`` contiguous chunks.

    A chunk's cost is its frames plus its warm-up, ``min(warmup, start - shot_start)`` frames (warm-up and
    written frames cost about the same on a device: both trace, denoise and shade; writing is overlapped).
    The chunks minimise the largest cost (binary search on it, greedy cuts), so with ``warmup`` > 0 the
    first chunk of a shot is longer than the others. ``runs``: stretches of consecutive codes; a run's gap
    to the next one is rendered through (not written) when it is no longer than ``warmup``.
    """
    codes = sorted(set(int(c) for c in todo))
    if not codes:
        return []
    spans: list[list[int]] = [[codes[0], codes[0] + 1]]
    for c in codes[1:]:
        if c - spans[-1][1] <= warmup:  # rendering through the gap is no dearer than a warm-up
            spans[-1][1] = c + 1
        else:
            spans.append([c, c + 1])

    def warm(start: int) -> int:
        return min(warmup, start - shot_start)

    def cut(limit: int) -> list[Chunk] | None:
        """Greedy chunks of cost <= limit, or None where a chunk's warm-up alone reaches the limit."""
        out = []
        for a, b in spans:
            while a < b:
                n = limit - warm(a)
                if n < 1:
                    return None
                out.append(Chunk(a, min(b, a + n)))
                a += n
        return out

    pieces = max(workers, len(spans))
    lo, hi = 1, max(b - a + warm(a) for a, b in spans)
    while lo < hi:  # smallest largest-cost with no more than `pieces` chunks
        mid = (lo + hi) // 2
        chunks = cut(mid)
        if chunks is not None and len(chunks) <= pieces:
            hi = mid
        else:
            lo = mid + 1
    return cut(lo)


# ------------------------------------------------------------------------------------------ the job


@dataclass(frozen=True)
class ShotJob:
    """Everything a worker needs to render frames of one shot; hashable, sent with every task.

    Paths are absolute: every worker must see ``scene`` and ``out`` at the same place (a shared file system
    on a multi-host cluster). ``device``: Warp device on the worker, None = ``cuda:0`` when the worker sees a
    GPU (one per worker, pinned by ``CUDA_VISIBLE_DEVICES``), else ``cpu``. ``exposure``: linear scale.
    ``overwrite_before_ns``: files older than this (``st_mtime_ns``) are stale and rewritten; None (resume):
    every frame on disk is kept. ``fault``: test hook ``(code, marker_path)``: the first worker to reach
    ``code`` while ``marker_path`` does not exist waits for its written frames, creates the marker and kills its
    own process (SIGKILL).
    """

    scene: str
    out: str
    settings: RenderSettings
    shot_start: int
    shot_stop: int
    warmup: int
    device: str | None = None
    camera: str | None = None
    simulate: bool = True
    exposure: float | None = None
    frame_aovs: bool = False
    writer_threads: int = 2
    overwrite_before_ns: int | None = None
    fault: tuple[int, str] | None = None

    @property
    def renderer_key(self) -> tuple:
        return (self.scene, self.settings, self.device, self.camera, self.simulate, self.shot_start)

    def path(self, code: int) -> str:
        return os.path.join(self.out, frame_name(code))

    def done(self, code: int) -> bool:
        """Whether time code ``code``'s frame is on disk and not to be (re)written in this run."""
        try:
            st = os.stat(self.path(code))
        except FileNotFoundError:
            return False
        return self.overwrite_before_ns is None or st.st_mtime_ns >= self.overwrite_before_ns


# ------------------------------------------------------------------------------------------ worker side

_WORKER: dict = {}  # renderer_key -> (renderer, animation); one shot at a time per worker process


def worker_device(job: ShotJob) -> str:
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    return job.device or ("cuda:0" if wp.is_cuda_available() else "cpu")


def worker_renderer(job: ShotJob):
    """The (renderer, animation) of ``job`` in this worker process, built on first use and kept."""
    import warnings

    from .animation import Animation
    from .errors import SceneWarning
    from .render import Renderer
    from .usd import load_usd

    key = job.renderer_key
    if key not in _WORKER:
        _WORKER.clear()  # one shot's buffers at a time
        device = worker_device(job)
        s = job.settings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)  # the client said them once
            scene = load_usd(job.scene, time_code=job.shot_start, width=s.width, height=s.height,
                             camera_path=job.camera, device=device)
        renderer = Renderer(scene, s, device=device)
        _WORKER[key] = (renderer, Animation(renderer, job.scene, camera_path=job.camera, simulate=job.simulate))
    return _WORKER[key]


def restart_history(renderer, animation, index: int) -> None:
    """Forget every frame-to-frame state and number the next frame ``index`` (its index in the shot).

    Afterwards the renderer behaves as a fresh one whose sequence started ``index`` frames before the shot's
    first frame: SVGF and caustics-map histories empty, no motion into the next frame, random streams of
    frame ``index``.
    """
    from .denoise import SVGF

    renderer.frame = int(index)
    if isinstance(renderer.denoiser, SVGF):
        renderer.denoiser.reset()
    reset = getattr(renderer.photons, "reset_history", None)
    if reset is not None:
        reset()
    animation.frames = 0


def prepare(job: ShotJob) -> dict:
    """Build this worker's renderer (kernels loaded, buffers allocated); returns what the client shows."""
    import platform

    import warp as wp

    t0 = time.perf_counter()
    renderer, animation = worker_renderer(job)
    dev = wp.get_device(renderer.device)
    return {"device": f"{dev.alias} ({dev.name})", "host": platform.node(), "pid": os.getpid(),
            "cuda_visible_devices": os.environ.get("CUDA_VISIBLE_DEVICES"),
            "fps": animation.clock.time_codes_per_second, "seconds": time.perf_counter() - t0}


def shot_exposure(job: ShotJob) -> float:
    """Automatic exposure of the shot: that of its first frame, rendered with a fresh history."""
    from .image_io import auto_exposure

    renderer, animation = worker_renderer(job)
    restart_history(renderer, animation, 0)
    animation.set_time_code(job.shot_start)
    renderer.render_frame()
    g = renderer.gbuffer
    return float(auto_exposure(renderer.final.numpy().reshape(g.height, g.width, 3)))


class FrameWriter:
    """Tone map and write frames on ``threads`` host threads while the device renders the next one.

    ``submit(code, final)`` takes a host copy of ``final`` (H, W, 3 float32 radiance) and returns at once
    unless ``2 * threads`` frames are already waiting (bounded memory). Each frame is written to a hidden
    temporary name and renamed to ``final.####.png`` (atomic on one file system), AOVs first when asked for,
    so a ``final.####.png`` on disk always means a complete frame. ``seconds``: thread time spent writing.
    """

    def __init__(self, job: ShotJob, threads: int):
        self.job = job
        self.pool = ThreadPoolExecutor(max_workers=max(1, threads), thread_name_prefix="cisp-png")
        self.slots = threading.BoundedSemaphore(2 * max(1, threads))
        self.futures = []
        self.seconds = 0.0
        self.lock = threading.Lock()

    def _write(self, code: int, final: np.ndarray, aovs: dict) -> None:
        from PIL import Image

        from .image_io import tonemap, write_aovs

        try:
            t0 = time.perf_counter()
            if aovs:
                write_aovs(self.job.out, aovs)
            path = self.job.path(code)
            tmp = os.path.join(self.job.out, f".{frame_name(code)}.{os.getpid()}.tmp")
            Image.fromarray(tonemap(final, self.job.exposure)).save(tmp, format="PNG")
            os.replace(tmp, path)
            with self.lock:
                self.seconds += time.perf_counter() - t0
        finally:
            self.slots.release()

    def submit(self, code: int, final: np.ndarray, aovs: dict | None = None) -> None:
        self.slots.acquire()
        self.futures.append(self.pool.submit(self._write, int(code), final, aovs or {}))

    def close(self) -> None:
        """Wait for every frame; raises the first write error."""
        self.pool.shutdown(wait=True)
        for f in self.futures:
            f.result()


def render_chunk(job: ShotJob, chunk: Chunk) -> dict:
    """Render ``chunk``'s frames that are not yet done, after the warm-up; returns what it did.

    Runs on a worker. The frames of ``chunk`` already on disk are skipped (a retried or resumed chunk starts
    ``warmup`` frames before its first missing frame); frames between missing ones are rendered, not written.
    """
    import warp as wp

    t0 = time.perf_counter()
    todo = [c for c in range(chunk.start, chunk.stop) if not job.done(c)]
    report = {"chunk": (chunk.start, chunk.stop), "written": [], "rendered": 0, "warmup": 0, "pid": os.getpid(),
              "render_seconds": 0.0, "write_seconds": 0.0, "write_wait_seconds": 0.0}
    if not todo:
        return report
    renderer, animation = worker_renderer(job)
    g = renderer.gbuffer
    shape = (g.height, g.width, 3)
    first, last = todo[0], todo[-1]
    begin = max(job.shot_start, first - job.warmup)
    restart_history(renderer, animation, begin - job.shot_start)
    wanted = set(todo)
    writer = FrameWriter(job, job.writer_threads)
    try:
        for code in range(begin, last + 1):
            if job.fault is not None and code == job.fault[0] and not os.path.exists(job.fault[1]):
                writer.close()  # the frames before `code` are on disk, as after any worker's death mid-chunk
                with open(job.fault[1], "w") as f:
                    f.write(str(os.getpid()))
                os.kill(os.getpid(), signal.SIGKILL)  # a worker dying mid-chunk (tests)
            animation.set_time_code(code)
            renderer.render_frame()
            report["rendered"] += 1
            if code < first:
                report["warmup"] += 1
            if code in wanted and not job.done(code):
                final = renderer.final.numpy().reshape(shape)  # the frame's one host copy (CUDA: a new array)
                if renderer.device.is_cpu:
                    final = final.copy()  # on the CPU numpy() is a view of the buffer the next frame overwrites
                aovs = {}
                if job.frame_aovs:
                    aovs[f"final.{code:04d}"] = final
                    if renderer.photons is not None:
                        aovs[f"photon_map.{code:04d}"] = renderer.photons.photon_map.numpy().reshape(shape).copy()
                        aovs[f"caustics.{code:04d}"] = renderer.caustic_irradiance.numpy().reshape(shape).copy()
                writer.submit(code, final, aovs)
                report["written"].append(code)
        wp.synchronize_device(renderer.device)
        report["render_seconds"] = time.perf_counter() - t0
    finally:
        t1 = time.perf_counter()
        writer.close()
        report["write_wait_seconds"] = time.perf_counter() - t1
    report["write_seconds"] = writer.seconds
    return report


# ------------------------------------------------------------------------------------------ client side


@dataclass
class ShotStats:
    """What a distributed shot did and cost (seconds are wall-clock on the client)."""

    frames: int = 0  #: frames written in this run
    rendered: int = 0  #: frames rendered over all chunks, warm-up included
    warmup: int = 0  #: warm-up frames rendered (not written)
    chunks: list = field(default_factory=list)  #: the tasks' reports
    workers: list = field(default_factory=list)  #: per worker: device, host, pid, set-up seconds
    exposure: float = 1.0
    setup_seconds: float = 0.0  #: cluster start, workers' renderers, exposure
    render_seconds: float = 0.0  #: first chunk submitted -> last frame on disk
    video_seconds: float = 0.0
    write_seconds: float = 0.0  #: writer-thread time summed over workers (tone map + PNG)
    video: str | None = None

    def summary(self) -> str:
        fps = self.frames / self.render_seconds if self.render_seconds > 0 else 0.0
        return (f"{self.frames} frames written ({self.warmup} warm-up frames rendered) by {len(self.workers)} workers "
                f"in {len(self.chunks)} chunks: set-up {self.setup_seconds:.1f} s, frames {self.render_seconds:.1f} s "
                f"({fps:.2f} frames/s), tone map + PNG {self.write_seconds:.1f} s of writer threads"
                + (f", video {self.video_seconds:.1f} s" if self.video else ""))


def import_engine():
    """``dask.distributed``, or :class:`SceneError` with the one sentence that says how to install it."""
    try:
        import distributed
    except ImportError:
        raise SceneError(MISSING_ENGINE) from None
    return distributed


def local_cluster(distributed, workers: int, gpus: int):
    """A cluster on this host: one worker process per GPU (``CUDA_VISIBLE_DEVICES`` = its GPU; dask-cuda's
    ``LocalCUDACluster`` where installed) when ``gpus`` > 0, else ``workers`` single-threaded CPU processes."""
    if gpus:
        if workers > gpus:
            raise SceneError(f"--workers {workers} asks for more GPU workers than the {gpus} GPUs Warp sees "
                             f"(one worker per GPU); use --workers {gpus} or --device cpu")
        visible = os.environ.get("CUDA_VISIBLE_DEVICES")  # GPU i of Warp is this process's i-th visible GPU
        ids = [v.strip() for v in visible.split(",")][:workers] if visible else [str(i) for i in range(workers)]
        try:
            from dask_cuda import LocalCUDACluster

            return LocalCUDACluster(CUDA_VISIBLE_DEVICES=ids, threads_per_worker=1, dashboard_address=None)
        except ImportError:
            pass
        from distributed import Nanny, Scheduler, SpecCluster

        spec = {f"gpu{gpu}": {"cls": Nanny, "options": {"nthreads": 1, "silence_logs": 40,
                                                      "env": {"CUDA_VISIBLE_DEVICES": gpu}}}
                for gpu in ids}
        return SpecCluster(workers=spec, scheduler={"cls": Scheduler, "options": {"dashboard_address": None}},
                           silence_logs=40)
    return distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                    dashboard_address=None, silence_logs=40)


def file_system_now_ns(out: str) -> int:
    """The time stamp a file written now in ``out`` gets, by the file system's own clock and granularity (a
    shared file system's server may be another host), so that frames of this run are told from older ones."""
    probe = os.path.join(out, f".start.{os.getpid()}.tmp")
    with open(probe, "w"):
        pass
    try:
        return os.stat(probe).st_mtime_ns
    finally:
        os.remove(probe)


def read_manifest(out: str) -> dict | None:
    try:
        with open(os.path.join(out, MANIFEST)) as f:
            return json.load(f)
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise SceneError(f"cannot read the shot manifest ({exc}); move it away to start the shot afresh",
                         file=os.path.join(out, MANIFEST)) from None


def manifest_of(job: ShotJob) -> dict:
    return {"scene": job.scene, "frames": [job.shot_start, job.shot_stop], "camera": job.camera,
            "simulate": job.simulate, "warmup": job.warmup, "settings": repr(job.settings),
            "exposure": job.exposure}


def write_manifest(out: str, manifest: dict) -> None:
    tmp = os.path.join(out, f".{MANIFEST}.{os.getpid()}.tmp")
    with open(tmp, "w") as f:
        json.dump(manifest, f, indent=1)
    os.replace(tmp, os.path.join(out, MANIFEST))


def assemble_video(out: str, codes, fps: float) -> str | None:
    """``final.mp4`` from ``final.####.png`` in time-code order (written to a temporary name, then renamed)."""
    from PIL import Image

    from .sequence import VideoWriter

    tmp = os.path.join(out, f".final.{os.getpid()}.tmp.mp4")
    writer = VideoWriter(tmp, fps)
    try:
        for code in codes:
            with Image.open(os.path.join(out, frame_name(code))) as im:
                writer.append(np.asarray(im.convert("RGB")))
            if writer.error is not None:
                break
    finally:
        writer.close()
    if writer.error is not None or not writer.frames:
        if os.path.exists(tmp):
            os.remove(tmp)
        return None
    path = os.path.join(out, "final.mp4")
    os.replace(tmp, path)
    return path


def render_shot(scene, codes: range, out: str, settings: RenderSettings, *, workers: int | None = None,
                scheduler: str | None = None, device: str | None = None, camera: str | None = None,
                simulate: bool = True, exposure: float | None = None, warmup: int | None = None,
                resume: bool = False, video: bool = True, frame_aovs: bool = False,
                writer_threads: int | None = None, progress=None, fault=None, client=None) -> ShotStats:
    """Render time codes ``codes`` of ``scene`` into ``out`` on Dask workers (see the module docstring).

    ``workers``: size of a :func:`local_cluster`, or with ``scheduler`` (the address of a running cluster) or
    ``client`` (an open ``distributed.Client``) how many of its workers to use (None: all); ``exposure``: linear scale, None = the shot's automatic
    exposure (an earlier run's from ``out/shot.json`` when resuming); ``warmup``: frames before each chunk,
    None = :func:`warmup_frames`; ``resume``: keep every frame on disk, render the missing ones; otherwise
    frames on disk from earlier runs are rewritten; ``video``: assemble ``final.mp4``; ``writer_threads``:
    tone-map/PNG threads per worker (default: this host's cores shared by the workers, 1 to 8);
    ``progress``: tqdm-like factory ``progress(total=...)``.
    """
    distributed = import_engine()
    codes = range(int(codes.start), int(codes.stop))
    if len(codes) == 0:
        raise SceneError("--frames is empty")
    scene = os.path.abspath(os.fspath(scene))
    if not os.path.isfile(scene):
        raise SceneError("no such file", file=scene)
    out = os.path.abspath(out)
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as exc:
        raise SceneError(f"cannot create output directory: {exc.strerror}", file=out) from None
    settings.validate()
    warmup = warmup_frames(settings) if warmup is None else int(warmup)
    if warmup < 0:
        raise SceneError(f"--warmup must be >= 0, got {warmup}")
    job = ShotJob(scene=scene, out=out, settings=settings, shot_start=codes.start, shot_stop=codes.stop,
                  warmup=warmup, device=device, camera=camera, simulate=simulate, exposure=exposure,
                  frame_aovs=frame_aovs, overwrite_before_ns=None if resume else file_system_now_ns(out), fault=fault)
    earlier = read_manifest(out) if resume else None
    if earlier is not None:
        mine = manifest_of(job)
        differ = [k for k in mine if k != "exposure" and earlier.get(k) != mine[k]]
        if differ:
            raise SceneError(f"--resume: the frames there were rendered with other {', '.join(differ)}; "
                             "render into another --out, or drop --resume to render the shot afresh",
                             file=os.path.join(out, MANIFEST))
        if exposure is None:
            job = replace(job, exposure=earlier["exposure"])
        elif not math.isclose(exposure, earlier["exposure"], rel_tol=1e-6):
            raise SceneError(f"--resume: the frames there were tone mapped with exposure scale {earlier['exposure']:g}, "
                             f"not {exposure:g}; drop --exposure or --resume", file=os.path.join(out, MANIFEST))
    todo = [c for c in codes if not job.done(c)]
    stats = ShotStats(exposure=job.exposure or 1.0)
    t0 = time.perf_counter()
    if todo or job.exposure is None:
        own = None
        if client is None:
            client, own, job = connect(distributed, job, workers, scheduler)
        try:
            addresses = sorted(client.scheduler_info()["workers"])
            if workers is not None and own is None:  # --workers N of a running cluster: its first N workers
                if len(addresses) < workers:
                    raise SceneError(f"--workers {workers}: the cluster has {len(addresses)} workers")
                addresses = addresses[:workers]
            if writer_threads is None:
                writer_threads = max(1, min(8, (os.cpu_count() or 2) // max(1, len(addresses))))
            job = replace(job, writer_threads=int(writer_threads))
            # every worker builds its renderer now, in parallel; the exposure then costs one frame on one of them
            ready = [client.submit(prepare, job, workers=[a], allow_other_workers=False, pure=False)
                     for a in addresses]
            if job.exposure is None:
                job = replace(job, exposure=client.submit(shot_exposure, job, workers=addresses, pure=False).result())
            stats.workers = client.gather(ready)
            stats.exposure = job.exposure
            write_manifest(out, manifest_of(job))
            stats.setup_seconds = time.perf_counter() - t0
            t1 = time.perf_counter()
            chunks = plan_chunks(todo, job.shot_start, len(addresses), job.warmup)
            stats.chunks = run_chunks(distributed, client, job, chunks, addresses, todo, progress)
            stats.render_seconds = time.perf_counter() - t1
        finally:
            if own is not None:
                own[0].close()
                own[1].close()
    for name in os.listdir(out):  # writers' temporary files left by workers that died while writing
        if name.startswith(".final.") and name.endswith(".tmp"):
            os.remove(os.path.join(out, name))
    missing = [c for c in codes if not os.path.exists(job.path(c))]
    if missing:
        raise SceneError(f"{len(missing)} frames are missing after every chunk finished (first: {missing[0]})", file=out)
    stats.frames = sum(len(r["written"]) for r in stats.chunks)
    stats.rendered = sum(r["rendered"] for r in stats.chunks)
    stats.warmup = sum(r["warmup"] for r in stats.chunks)
    stats.write_seconds = sum(r["write_seconds"] for r in stats.chunks)
    if video:
        from .animation import StageClock

        t2 = time.perf_counter()
        stats.video = assemble_video(out, codes, StageClock(scene, camera).time_codes_per_second)
        stats.video_seconds = time.perf_counter() - t2
    return stats


def connect(distributed, job: ShotJob, workers: int | None, scheduler: str | None):
    """``(client, (client, cluster) or None, job)``: a client of the cluster at ``scheduler``, or of a new
    :func:`local_cluster` (then ``job.device`` becomes each pinned GPU worker's ``cuda:0``)."""
    if scheduler:
        try:
            client = distributed.Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise SceneError(f"cannot reach the Dask scheduler at {scheduler!r} ({exc})") from None
        client.wait_for_workers(int(workers or 1), timeout=120)
        return client, None, job
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    device = job.device
    gpus = wp.get_cuda_device_count() if (device or "cuda").startswith("cuda") else 0
    if device is not None and device.startswith("cuda") and not gpus:
        raise SceneError(f"--device {device}: Warp sees no GPU here; use --device cpu")
    n = int(workers or max(1, gpus))
    if n < 1:
        raise SceneError(f"--workers must be >= 1, got {n}")
    if gpus:
        job = replace(job, device="cuda:0")  # each worker sees its one GPU as cuda:0
    cluster = local_cluster(distributed, n, gpus)
    client = distributed.Client(cluster)
    client.wait_for_workers(n, timeout=120)
    return client, (client, cluster), job


def run_chunks(distributed, client, job: ShotJob, chunks, addresses, todo, progress) -> list[dict]:
    """Submit one :func:`render_chunk` task per chunk and wait, the progress bar fed by the frames on disk;
    the first task error is raised here (the other tasks cancelled). Returns the tasks' reports."""
    futures = [client.submit(render_chunk, job, c, workers=addresses, pure=False, retries=0) for c in chunks]
    bar = progress(total=len(todo)) if (progress and todo) else None
    shown = 0
    pending = set(futures)
    reports = None
    try:
        while pending:
            try:
                distributed.wait(list(pending), timeout=0.25, return_when="FIRST_COMPLETED")
            except (TimeoutError, asyncio.TimeoutError):
                pass
            finished = {f for f in pending if f.done()}
            pending -= finished
            for f in finished:
                if f.status == "error":
                    f.result()  # raises the task's error here (a SceneError prints as one sentence)
            if bar is not None:
                now = sum(job.done(c) for c in todo)
                bar.update(now - shown)
                shown = now
        reports = client.gather(futures)
    finally:
        if reports is None:  # an error or Ctrl-C: stop the other chunks
            for f in futures:
                f.cancel()
        if bar is not None:
            bar.close()
    return reports


def main_distributed(args, settings: RenderSettings, frames: range | None, say) -> int:
    """``cisp-render --frames A:B --workers N | --scheduler ADDRESS [--resume]``: the command line's call."""
    from functools import partial

    if frames is None:
        raise SceneError("--workers, --scheduler and --resume render sequences: give --frames A:B")
    if args.workers is not None and args.workers < 1:
        raise SceneError(f"--workers must be >= 1, got {args.workers}")
    import_engine()
    if args.stats:
        say("warning: --stats prints no ledgers with --workers or --scheduler (the frames render on the workers)")
    import warnings

    from tqdm import tqdm

    from .errors import SceneWarning
    from .usd import load_usd

    with warnings.catch_warnings(record=True) as caught:  # the stage's warnings, said once here, not per worker
        warnings.simplefilter("always", SceneWarning)
        load_usd(args.scene, time_code=frames.start, width=args.width, height=args.height, camera_path=args.camera,
                 device="cpu")
    for w in caught:
        say(f"warning: {w.message}")
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            exposure = None if args.exposure is None else 2.0 ** args.exposure
            stats = render_shot(args.scene, frames, args.out, settings, workers=args.workers, scheduler=args.scheduler,
                                device=args.device, camera=args.camera, simulate=not args.no_sim, exposure=exposure,
                                warmup=args.warmup, resume=args.resume, frame_aovs=args.frame_aovs,
                                progress=partial(tqdm, desc="frames", unit="frame", disable=args.quiet))
        except KeyboardInterrupt:  # the cluster is closed (local) or its chunks cancelled; frames on disk are whole
            done = sum(os.path.exists(os.path.join(args.out, frame_name(c))) for c in frames)
            print(f"cisp-render: interrupted with {done} of {len(frames)} frames in {args.out}; run the same command "
                  "with --resume to render the rest", file=sys.stderr)
            return 130
    for w in caught:
        say(f"warning: {w.message}")
    devices = ", ".join(sorted({w["device"] for w in stats.workers})) or "no worker (every frame was on disk)"
    say(f"rendered {args.scene} time codes {frames.start}..{frames.stop - 1} on {devices} in "
        f"{time.perf_counter() - t0:.2f} s to {args.out} (final.####.png{', final.mp4' if stats.video else ''}): "
        f"{stats.summary()}")
    return 0


__all__ = ["Chunk", "FrameWriter", "ShotJob", "ShotStats", "frame_name", "main_distributed", "plan_chunks",
           "render_chunk", "render_shot", "restart_history", "warmup_frames"]
