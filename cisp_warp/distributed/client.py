"""The client side of a distributed shot: cluster, exposure, chunk tasks, progress, manifest, video, and the
command line's call (``cisp-render --frames A:B --workers N | --scheduler ADDRESS [--resume]``)."""

from __future__ import annotations

import asyncio
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import SceneError
from ..render import RenderSettings
from .plan import plan_chunks, warmup_frames
from .worker import ShotJob, frame_name, prepare, render_chunk, shot_exposure

MISSING_ENGINE = ("--workers and --scheduler need Dask.distributed, which is not installed "
                  "(python3 -m pip install -e '.[distributed]')")
MANIFEST = "shot.json"  #: in ``out``: what the shot's frames were rendered with (exposure, settings, range)


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
    video_seconds: float = 0.0  #: MP4 assembly after the last frame (the rest overlapped the chunks)
    write_seconds: float = 0.0  #: writer-thread time summed over workers (PNG, EXR layers when asked for)
    warmup_cost: float = 1.0  #: a warm-up frame's cost in written frames, as the plan took it
    video: str | None = None

    def summary(self) -> str:
        fps = self.frames / self.render_seconds if self.render_seconds > 0 else 0.0
        cost = f", each costing {self.warmup_cost:.2f} of a written one" if self.warmup else ""
        return (f"{self.frames} frames written ({self.warmup} warm-up frames rendered{cost}) by {len(self.workers)} "
                f"workers in {len(self.chunks)} chunks: set-up {self.setup_seconds:.1f} s, frames "
                f"{self.render_seconds:.1f} s ({fps:.2f} frames/s), PNG {self.write_seconds:.1f} s of writer threads"
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

        spec = {f"gpu{gpu}": {"cls": Nanny, "options": {"nthreads": 1, "silence_logs": 40, "host": "127.0.0.1",
                                                      "env": {"CUDA_VISIBLE_DEVICES": gpu}}}
                for gpu in ids}  # on this host only, as LocalCluster
        scheduler = {"cls": Scheduler, "options": {"dashboard": False, "dashboard_address": ":0", "host": "127.0.0.1"}}
        return SpecCluster(workers=spec, scheduler=scheduler, silence_logs=40)
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


class VideoAssembler:
    """``final.mp4`` from ``final.####.png`` in time-code order, fed while the chunks render: ``feed(ready)``
    appends the frames from the next missing time code on for which ``ready(code)`` holds (a frame of this run on
    disk), so the frames of the first chunk are encoded while the others render, and ``close()`` appends the rest
    and renames the file into place (written to a temporary name; None when no video could be written)."""

    def __init__(self, out: str, codes, fps: float):
        from ..sequence import VideoWriter

        self.out, self.codes, self.next = out, list(codes), 0
        self.tmp = os.path.join(out, f".final.{os.getpid()}.tmp.mp4")
        self.writer = VideoWriter(self.tmp, fps)
        self.seconds = 0.0  #: spent appending frames

    def feed(self, ready=lambda code: True) -> None:
        from PIL import Image

        t0 = time.perf_counter()
        while self.next < len(self.codes) and self.writer.error is None and ready(self.codes[self.next]):
            with Image.open(os.path.join(self.out, frame_name(self.codes[self.next]))) as im:
                self.writer.append(np.asarray(im.convert("RGB")))
            self.next += 1
        self.seconds += time.perf_counter() - t0

    def discard(self) -> None:
        """Stop without a video (a chunk failed): ffmpeg closed, the temporary file removed."""
        self.writer.close()
        if os.path.exists(self.tmp):
            os.remove(self.tmp)

    def close(self) -> str | None:
        try:
            self.feed()
        finally:
            self.writer.close()
        if self.writer.error is not None or not self.writer.frames:
            if os.path.exists(self.tmp):
                os.remove(self.tmp)
            return None
        path = os.path.join(self.out, "final.mp4")
        os.replace(self.tmp, path)
        return path


def assemble_video(out: str, codes, fps: float) -> str | None:
    """``final.mp4`` from ``final.####.png`` in time-code order, all at once."""
    return VideoAssembler(out, codes, fps).close()


def render_shot(scene, codes: range, out: str, settings: RenderSettings, *, workers: int | None = None,
                scheduler: str | None = None, device: str | None = None, camera: str | None = None,
                simulate: bool = True, exposure: float | None = None, warmup: int | None = None,
                resume: bool = False, video: bool = True, frame_aovs: bool = False,
                writer_threads: int | None = None, warmup_cost: float | None = None, progress=None, fault=None,
                client=None) -> ShotStats:
    """Render time codes ``codes`` of ``scene`` into ``out`` on Dask workers (see the module docstring).

    ``workers``: size of a :func:`local_cluster`, or with ``scheduler`` (the address of a running cluster) or
    ``client`` (an open ``distributed.Client``) how many of its workers to use (None: all); ``exposure``: linear scale, None = the shot's automatic
    exposure (an earlier run's from ``out/shot.json`` when resuming); ``warmup``: frames before each chunk,
    None = :func:`warmup_frames`; ``resume``: keep every frame on disk, render the missing ones; otherwise
    frames on disk from earlier runs are rewritten; ``video``: assemble ``final.mp4``; ``writer_threads``:
    PNG threads per worker (default: this host's cores shared by the workers, 1 to 8);
    ``warmup_cost``: what a warm-up frame costs in written frames, for the plan (:func:`plan_chunks`); None =
    measured on the workers before the chunks start (:func:`~.worker.frame_costs`, the median of the workers'),
    when there is more than one worker to plan for; ``progress``: tqdm-like factory ``progress(total=...)``.
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
    assembler = None
    t0 = time.perf_counter()
    if todo or job.exposure is None:
        opened = []  # what this call opened and closes: a client, and a local cluster
        if client is None:
            client, opened, job = connect(distributed, job, workers, scheduler)
        try:
            addresses = sorted(client.scheduler_info()["workers"])
            if workers is not None and len(opened) != 2:  # --workers N of a running cluster: N of its workers
                if len(addresses) < workers:
                    raise SceneError(f"--workers {workers}: the cluster has {len(addresses)} workers")
                addresses = addresses[:workers]
            if writer_threads is None:
                writer_threads = max(1, min(8, (os.cpu_count() or 2) // max(1, len(addresses))))
            job = replace(job, writer_threads=int(writer_threads))
            # every worker builds its renderer now, in parallel; the exposure then costs one frame on one of them
            measure = warmup_cost is None and job.warmup > 0 and len(addresses) > 1 and len(todo) > 1
            ready = [client.submit(prepare, job, measure, workers=[a], allow_other_workers=True, pure=False)
                     for a in addresses]  # loose: a worker lost now must not leave its task waiting for it
            if job.exposure is None:
                job = replace(job, exposure=client.submit(shot_exposure, job, workers=addresses, pure=False).result())
            stats.workers = client.gather(ready)
            stats.exposure = job.exposure
            ratios = sorted(w["costs"]["ratio"] for w in stats.workers if w.get("costs"))
            stats.warmup_cost = float(warmup_cost if warmup_cost is not None else
                                      (ratios[len(ratios) // 2] if ratios else 1.0))
            write_manifest(out, manifest_of(job))
            stats.setup_seconds = time.perf_counter() - t0
            t1 = time.perf_counter()
            chunks = plan_chunks(todo, job.shot_start, len(addresses), job.warmup, stats.warmup_cost)
            if video:
                from ..animation import StageClock

                assembler = VideoAssembler(out, codes, StageClock(scene, camera).time_codes_per_second)
            try:
                stats.chunks = run_chunks(distributed, client, job, chunks, addresses, todo, progress, assembler)
            except BaseException:
                if assembler is not None:
                    assembler.discard()
                raise
            stats.render_seconds = time.perf_counter() - t1
        finally:
            for thing in opened:
                thing.close()
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
        if assembler is None:  # every frame was on disk: no chunk ran
            from ..animation import StageClock

            assembler = VideoAssembler(out, codes, StageClock(scene, camera).time_codes_per_second)
        t2 = time.perf_counter()
        stats.video = assembler.close()
        stats.video_seconds = time.perf_counter() - t2  # after the last frame: what the overlap left
    return stats


def connect(distributed, job: ShotJob, workers: int | None, scheduler: str | None):
    """``(client, [what to close], job)``: a client of the cluster at ``scheduler``, or of a new
    :func:`local_cluster` (then ``job.device`` becomes each pinned GPU worker's ``cuda:0``)."""
    if scheduler:
        try:
            client = distributed.Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise SceneError(f"cannot reach the Dask scheduler at {scheduler!r} ({exc})") from None
        return client, wait_for(client, [client], int(workers or 1), scheduler), job
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
    try:
        client = distributed.Client(cluster)
    except BaseException:
        cluster.close()
        raise
    return client, wait_for(client, [client, cluster], n, "the local cluster"), job


def wait_for(client, opened: list, n: int, where: str, seconds: float = 120.0) -> list:
    """Wait until ``n`` workers have joined; else close what was opened and say so in one sentence."""
    try:
        client.wait_for_workers(n, timeout=seconds)
    except BaseException as exc:
        for thing in opened:
            thing.close()
        if isinstance(exc, (TimeoutError, asyncio.TimeoutError)):
            raise SceneError(f"fewer than {n} Dask workers joined {where} within {seconds:.0f} s") from None
        raise
    return opened


def run_chunks(distributed, client, job: ShotJob, chunks, addresses, todo, progress, video=None) -> list[dict]:
    """Submit one :func:`render_chunk` task per chunk and wait, the progress bar and ``video``
    (:class:`VideoAssembler`) fed by the frames on disk; the first task error is raised here (the other tasks
    cancelled). Returns the tasks' reports."""
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
                    chunk = chunks[futures.index(f)]
                    try:
                        f.result()
                    except SceneError:
                        raise  # bad input, said in one sentence
                    except Exception as exc:  # e.g. KilledWorker: the chunk killed allowed-failures workers
                        raise SceneError(f"time codes {chunk.start}..{chunk.stop - 1} failed on the workers "
                                         f"({type(exc).__name__}: {exc}); the frames written are kept, "
                                         "--resume renders the rest") from exc
            if bar is not None:
                now = sum(job.done(c) for c in todo)
                bar.update(now - shown)
                shown = now
            if video is not None:
                video.feed(job.done)
        reports = client.gather(futures)
    finally:
        if reports is None:  # an error or Ctrl-C: stop the other chunks
            for f in futures:
                f.cancel()
        if bar is not None:
            bar.close()
    return reports


def main_distributed(args, settings: RenderSettings, frames: range | None, say, scene: str | None = None) -> int:
    """``cisp-render --frames A:B --workers N | --scheduler ADDRESS [--resume]``: the command line's call."""
    from functools import partial

    scene = scene or args.scene  # the stage (--demo's shipped one, or the file given)

    if frames is None:
        raise SceneError("--workers, --scheduler and --resume render sequences: give --frames A:B")
    if args.workers is not None and args.workers < 1:
        raise SceneError(f"--workers must be >= 1, got {args.workers}")
    import_engine()
    if args.stats:
        say("warning: --stats prints no ledgers with --workers or --scheduler (the frames render on the workers)")
    import warnings

    from tqdm import tqdm

    from ..errors import SceneWarning
    from ..usd import load_usd

    with warnings.catch_warnings(record=True) as caught:  # the stage's warnings, said once here, not per worker
        warnings.simplefilter("always", SceneWarning)
        load_usd(scene, time_code=frames.start, width=args.width, height=args.height, camera_path=args.camera,
                 device="cpu")
    for w in caught:
        say(f"warning: {w.message}")
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            exposure = None if args.exposure is None else 2.0 ** args.exposure
            stats = render_shot(scene, frames, args.out, settings, workers=args.workers, scheduler=args.scheduler,
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
    say(f"rendered {scene} time codes {frames.start}..{frames.stop - 1} on {devices} in "
        f"{time.perf_counter() - t0:.2f} s to {args.out} (final.####.png{', final.mp4' if stats.video else ''}): "
        f"{stats.summary()}")
    return 0


__all__ = ["MANIFEST", "MISSING_ENGINE", "ShotStats", "VideoAssembler", "assemble_video", "import_engine", "local_cluster",
           "main_distributed", "render_shot"]
