"""What runs on a Dask worker: the shot's job description, the renderer kept per worker process, the history
restart, the chunk loop and the threads that write its PNGs."""

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


_HOST: dict = {}  # (renderer_key, slots) -> HostFrames of this worker process, kept from chunk to chunk


def host_frames(job: ShotJob, renderer):
    """This worker's :class:`~.ldr.HostFrames` for ``job`` (``2 * writer_threads`` slots), allocated once."""
    from .ldr import HostFrames

    key = (job.renderer_key, 2 * max(1, job.writer_threads))
    if key not in _HOST:
        _HOST.clear()
        _HOST[key] = HostFrames(renderer, key[1])
    return _HOST[key]


def restart_history(renderer, animation, index: int) -> None:
    """Forget every frame-to-frame state and number the next frame ``index`` (its index in the shot).

    Afterwards the renderer behaves as a fresh one whose sequence started ``index`` frames before the shot's
    first frame: the denoiser's history (caustic, SVGF) and the caustics map's empty, no motion into the
    next frame, random streams of frame ``index``.
    """
    renderer.frame = int(index)
    forget = getattr(renderer.denoiser, "reset", None)  # the denoisers that keep a history have reset()
    if forget is not None:
        forget()
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


def prepare(job: ShotJob, measure: bool = False) -> dict:
    """Build this worker's renderer (kernels loaded, buffers allocated, host slots pinned); returns what the
    client shows, and with ``measure`` what its frames cost (:func:`frame_costs`, for the plan)."""
    import platform

    import warp as wp

    t0 = time.perf_counter()
    renderer, animation = worker_renderer(job)
    host_frames(job, renderer)
    dev = wp.get_device(renderer.device)
    return {"device": f"{dev.alias} ({dev.name})", "host": platform.node(), "pid": os.getpid(),
            "cuda_visible_devices": os.environ.get("CUDA_VISIBLE_DEVICES"),
            "fps": animation.clock.time_codes_per_second, "costs": frame_costs(job) if measure else None,
            "seconds": time.perf_counter() - t0}


def shot_exposure(job: ShotJob) -> float:
    """Automatic exposure of the shot: that of its first frame, rendered with a fresh history."""
    from ..image_io import auto_exposure

    renderer, animation = worker_renderer(job)
    restart_history(renderer, animation, 0)
    animation.set_time_code(job.shot_start)
    renderer.render_frame()
    return float(auto_exposure(renderer.final_image()))


class FrameWriter:
    """Write frames on ``threads`` host threads while the device renders the next one.

    ``submit(code, slot, aovs)`` takes a slot of ``frames`` (:class:`~.ldr.HostFrames`: the frame's 8-bit image,
    filtered down and tone mapped on the device, on its way to the host) and, with ``frame_aovs``, host copies of
    the HDR layers on the supersampled grid (filtered down here by ``supersample``), and returns at once
    (``frames`` bounds how many wait). Each frame is written to a hidden temporary name and renamed to
    ``final.####.png`` (atomic on one file system), AOVs first when asked for, so a ``final.####.png`` on disk
    always means a complete frame. ``seconds``: thread time spent writing.
    """

    def __init__(self, job: ShotJob, threads: int, frames, supersample: int = 1):
        self.job = job
        self.frames = frames
        self.supersample = int(supersample)
        self.pool = ThreadPoolExecutor(max_workers=max(1, threads), thread_name_prefix="cisp-png")
        self.futures = []
        self.seconds = 0.0
        self.lock = threading.Lock()

    def _write(self, code: int, slot: int, aovs: dict) -> None:
        try:
            ldr = self.frames.receive(slot)
            t0 = time.perf_counter()
            encode_frame(self.job, code, ldr, aovs, self.supersample)
            with self.lock:
                self.seconds += time.perf_counter() - t0
        finally:
            self.frames.release(slot)

    def submit(self, code: int, slot: int, aovs: dict | None = None) -> None:
        self.futures.append(self.pool.submit(self._write, int(code), slot, aovs or {}))

    def close(self) -> None:
        """Wait for every frame; raises the first write error."""
        self.pool.shutdown(wait=True)
        for f in self.futures:
            f.result()


PNG_LEVEL = 1  #: zlib level of the frames' PNGs (lossless at every level; see the README's distributed section)


def encode_frame(job: ShotJob, code: int, ldr: np.ndarray, aovs: dict, supersample: int, path=None) -> None:
    """Write ``final.####.png`` from ``ldr`` ((H, W, 3) uint8 sRGB) through a temporary name, after the layers of
    ``aovs.####.exr`` when ``aovs`` holds them ((H*s, W*s, 3) float32, ``final`` among them; filtered down here);
    ``path``: a file object instead, for timing."""
    from PIL import Image

    from ..image_io import write_layers
    from ..render import box_filter

    image = Image.fromarray(ldr)
    if path is not None:
        image.save(path, format="PNG", compress_level=PNG_LEVEL)
        return
    if aovs:  # as render_sequence writes them (itself atomic)
        layers = {k: box_filter(v, supersample) for k, v in aovs.items()}
        write_layers(os.path.join(job.out, f"aovs.{code:04d}.exr"), layers)
    tmp = os.path.join(job.out, f".{frame_name(code)}.{os.getpid()}.tmp")
    image.save(tmp, format="PNG", compress_level=PNG_LEVEL)
    os.replace(tmp, job.path(code))


def frame_costs(job: ShotJob, frames: int = 3) -> dict:
    """What a written and a warm-up frame cost on this worker, seconds each (medians over ``frames``), measured
    on the shot's first frames after one untimed frame of each kind (kernels loaded, buffers touched).

    ``written``: the animation step, a full frame, its 8-bit image's copy to the host and the wait for them (what
    the render loop pays when the device is the bottleneck); ``warmup``: the animation step,
    :func:`~cisp_warp.sequence.render_history_frame` and the wait; ``encode``: one writer thread's PNG of that
    frame (to memory, at the shot's exposure); ``ratio``: what a warm-up frame costs in written frames,
    ``warmup / max(written, encode / threads)`` (the render loop goes no faster than its writers)."""
    import io
    import statistics

    import warp as wp

    from ..image_io import auto_exposure
    from ..sequence import render_history_frame

    renderer, animation = worker_renderer(job)
    slots = host_frames(job, renderer)
    times = {"written": [], "warmup": [], "encode": []}
    exposure = job.exposure
    restart_history(renderer, animation, 0)
    for i in range(2 * (frames + 1)):
        wp.synchronize_device(renderer.device)
        t0 = time.perf_counter()
        animation.set_time_code(job.shot_start + i)  # both kinds pay the animation step (camera, water, BVH)
        if i % 2:
            render_history_frame(renderer)
            wp.synchronize_device(renderer.device)
            kind = "warmup"
        else:
            renderer.render_frame()
            if exposure is None:  # the PNG's cost depends on the picture: the shot's exposure, not a white frame
                exposure = auto_exposure(renderer.final_image())
            k = slots.send(renderer.final, exposure)
            ldr = slots.receive(k)
            kind = "written"
        dt = time.perf_counter() - t0
        if kind == "written":
            t1 = time.perf_counter()
            encode_frame(job, 0, ldr, {}, renderer.settings.supersample, path=io.BytesIO())
            slots.release(k)
            if i >= 2:
                times["encode"].append(time.perf_counter() - t1)
        if i >= 2:
            times[kind].append(dt)
    out = {k: statistics.median(v) for k, v in times.items()}
    out["ratio"] = out["warmup"] / max(out["written"], out["encode"] / max(1, job.writer_threads))
    return out


def render_chunk(job: ShotJob, chunk: Chunk) -> dict:
    """Render ``chunk``'s frames that are not yet done, after the warm-up; returns what it did.

    Runs on a worker. The frames of ``chunk`` already on disk are skipped (a retried or resumed chunk starts
    ``warmup`` frames before its first missing frame); frames between missing ones are rendered, not written.
    A frame not written (warm-up or between) renders only what the next frames' histories read
    (:func:`~cisp_warp.sequence.render_history_frame`). ``warmup_seconds``: first frame to the end of the
    warm-up (device synchronised); ``render_seconds``: the whole loop, the last frame's copy to the host included.
    """
    import warp as wp

    from ..sequence import render_history_frame

    t0 = time.perf_counter()
    todo = [c for c in range(chunk.start, chunk.stop) if not job.done(c)]
    report = {"chunk": (chunk.start, chunk.stop), "written": [], "rendered": 0, "warmup": 0, "pid": os.getpid(),
              "render_seconds": 0.0, "warmup_seconds": 0.0, "write_seconds": 0.0, "write_wait_seconds": 0.0}
    if not todo:
        return report
    renderer, animation = worker_renderer(job)
    slots = host_frames(job, renderer)
    first, last = todo[0], todo[-1]
    begin = max(job.shot_start, first - job.warmup)
    restart_history(renderer, animation, begin - job.shot_start)
    wanted = set(todo)
    writer = FrameWriter(job, job.writer_threads, slots, renderer.settings.supersample)
    try:
        for code in range(begin, last + 1):
            if job.fault is not None and code == job.fault[0] and not os.path.exists(job.fault[1]):
                writer.close()  # the frames before `code` are on disk, as after any worker's death mid-chunk
                with open(job.fault[1], "w") as f:
                    f.write(str(os.getpid()))
                os.kill(os.getpid(), signal.SIGKILL)  # a worker dying mid-chunk (tests)
            if code == first and code > begin:
                wp.synchronize_device(renderer.device)
                report["warmup_seconds"] = time.perf_counter() - t0
            animation.set_time_code(code)
            report["rendered"] += 1
            if code < first:
                report["warmup"] += 1
            if code in wanted and not job.done(code):
                renderer.render_frame()
                aovs = {}
                if job.frame_aovs:  # as render_sequence writes them (host copies, the loop waits: for checks)
                    aovs["final"] = host_samples(renderer, renderer.final)
                    if renderer.photons is not None:
                        aovs["caustics"] = host_samples(renderer, renderer.caustic_irradiance)
                        aovs["photon_map"] = host_samples(renderer, renderer.photons.photon_map)
                writer.submit(code, slots.send(renderer.final, job.exposure), aovs)  # the 8-bit frame, queued
                report["written"].append(code)
            else:
                render_history_frame(renderer)
        wp.synchronize_device(renderer.device)
        report["render_seconds"] = time.perf_counter() - t0
    finally:
        t1 = time.perf_counter()
        writer.close()
        report["write_wait_seconds"] = time.perf_counter() - t1
    report["write_seconds"] = writer.seconds
    return report


__all__ = ["FrameWriter", "ShotJob", "encode_frame", "frame_costs", "frame_name", "prepare", "render_chunk",
           "restart_history", "shot_exposure", "worker_renderer"]
