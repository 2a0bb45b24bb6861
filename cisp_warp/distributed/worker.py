"""What runs on a Dask worker: the shot's job description, the renderer kept per worker process, the history
restart, the chunk loop and the threads that tone map and write its PNGs."""

from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..render import RenderSettings
from .plan import Chunk


def frame_name(code: int) -> str:
    """File name of time code ``code``'s tone-mapped frame, as :func:`cisp_warp.sequence.render_sequence` names it."""
    return f"final.{int(code):04d}.png"


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

    from ..animation import Animation
    from ..errors import SceneWarning
    from ..render import Renderer
    from ..usd import load_usd

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
    from ..denoise import SVGF

    renderer.frame = int(index)
    if isinstance(renderer.denoiser, SVGF):
        renderer.denoiser.reset()
    reset = getattr(renderer.photons, "reset_history", None)
    if reset is not None:
        reset()
    animation.frames = 0


def host_samples(renderer, image) -> np.ndarray:
    """Host copy of a per-sample (H*W) vec3 buffer, (H, W, 3) on the (supersampled) G-buffer grid; never a view
    of device memory (on the CPU ``numpy()`` is one, and the next frame overwrites it). The writer threads
    filter it down (:func:`~cisp_warp.render.box_filter`, as :meth:`~cisp_warp.render.Renderer.final_image`),
    off the render loop."""
    g = renderer.gbuffer
    host = image.numpy().reshape(g.height, g.width, 3)
    return host.copy() if renderer.device.is_cpu else host


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
    from ..image_io import auto_exposure

    renderer, animation = worker_renderer(job)
    restart_history(renderer, animation, 0)
    animation.set_time_code(job.shot_start)
    renderer.render_frame()
    return float(auto_exposure(renderer.final_image()))


class FrameWriter:
    """Tone map and write frames on ``threads`` host threads while the device renders the next one.

    ``submit(code, final, aovs)`` takes host copies of ``final`` (H, W, 3 float32 radiance) and of the AOVs on
    the supersampled grid (filtered down here, by ``supersample``), and returns at once
    unless ``2 * threads`` frames are already waiting (bounded memory). Each frame is written to a hidden
    temporary name and renamed to ``final.####.png`` (atomic on one file system), AOVs first when asked for,
    so a ``final.####.png`` on disk always means a complete frame. ``seconds``: thread time spent writing.
    """

    def __init__(self, job: ShotJob, threads: int, supersample: int = 1):
        self.job = job
        self.supersample = int(supersample)
        self.pool = ThreadPoolExecutor(max_workers=max(1, threads), thread_name_prefix="cisp-png")
        self.slots = threading.BoundedSemaphore(2 * max(1, threads))
        self.futures = []
        self.seconds = 0.0
        self.lock = threading.Lock()

    def _write(self, code: int, final: np.ndarray, aovs: dict) -> None:
        from PIL import Image

        from ..image_io import tonemap, write_layers
        from ..render import box_filter

        try:
            t0 = time.perf_counter()
            final = box_filter(final, self.supersample)
            if self.job.frame_aovs:  # layers of aovs.####.exr, as render_sequence writes them (itself atomic)
                layers = {"final": final, **{k: box_filter(v, self.supersample) for k, v in aovs.items()}}
                write_layers(os.path.join(self.job.out, f"aovs.{code:04d}.exr"), layers)
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
    first, last = todo[0], todo[-1]
    begin = max(job.shot_start, first - job.warmup)
    restart_history(renderer, animation, begin - job.shot_start)
    wanted = set(todo)
    writer = FrameWriter(job, job.writer_threads, renderer.settings.supersample)
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
                final = host_samples(renderer, renderer.final)  # the frame's one host copy
                aovs = {}
                if job.frame_aovs and renderer.photons is not None:  # as render_sequence writes them
                    aovs["caustics"] = host_samples(renderer, renderer.caustic_irradiance)
                    aovs["photon_map"] = host_samples(renderer, renderer.photons.photon_map)
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


__all__ = ["FrameWriter", "ShotJob", "frame_name", "prepare", "render_chunk", "restart_history", "shot_exposure",
           "worker_renderer"]
