"""Frames per second of a distributed shot with 1, 2, ... workers (one per GPU) and the scaling efficiency.

    python3 tools/bench_distributed.py                       # pool, 240 frames at 1920x1080, 1 and 2 GPU workers
    python3 tools/bench_distributed.py --workers 1,2,4 --frames 480 --no-video
    python3 tools/bench_distributed.py --smoke               # 30 tiny frames on 1 and 2 CPU workers, ~30 s

Each worker count renders the same shot (``cisp_warp.distributed.render_shot``, a fresh local cluster each time,
or the first N workers of ``--scheduler``'s cluster) into its own folder. Reported per run: the set-up (cluster start, every worker's renderer, the exposure frame),
the frames phase (first chunk submitted -> last PNG on disk), frames/s over that phase, the speed-up and
scaling efficiency against 1 worker (frames phase, and wall-clock with the set-up), the warm-up frames rendered,
the host time spent PNG-encoding in the workers' writer threads (summed; the tone map runs on the device; it overlaps the
rendering) and how long the chunks waited for their writers at the end, the MP4 assembly, and how far the frames
differ from the 1-worker run (a single chunk: the single-process frames) in 8-bit steps. On CUDA photon deposits
are float atomics in no fixed order, so even two single-process runs differ in the last bits.

A first untimed 2-frame run with one worker fills Warp's kernel cache, so no timed run compiles kernels
(not with ``--smoke``, whose CPU kernels the tests have compiled).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def parse_args(argv=None):
    from cisp_warp.cli import parse_count

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--scene", default=str(ROOT / "scenes_usd" / "pool.usda"))
    p.add_argument("--start", type=int, default=0, help="first time code")
    p.add_argument("--frames", type=int, default=240, help="frames in the shot")
    p.add_argument("--workers", default="1,2", help="comma-separated worker counts; the first is the baseline")
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--photons", type=parse_count, default=parse_count("1M"), help="photons per light per frame")
    p.add_argument("--rsm-size", type=int, default=1024)
    p.add_argument("--method", default="cisp")
    p.add_argument("--denoiser", default=None, help="caustic, svgf, gather or none (default: the renderer's)")
    p.add_argument("--supersample", type=int, default=2, help="N x N samples per pixel (cisp-render's default: 2)")
    p.add_argument("--device", default=None, help="cpu for CPU workers; default: one worker per GPU when Warp sees GPUs")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="use the first N workers of a running Dask cluster instead of a local cluster per run")
    p.add_argument("--warmup", type=int, default=None, help="warm-up frames per chunk (default: from the denoiser)")
    p.add_argument("--writer-threads", type=int, default=None,
                   help="PNG threads per worker (default: the cores shared by the most workers, at most 8)")
    p.add_argument("--no-video", action="store_true", help="skip the MP4 (no imageio-ffmpeg on the machine)")
    p.add_argument("--no-compare", action="store_true", help="skip comparing the frames with the 1-worker run")
    p.add_argument("--out", default=None, help="folder for the runs' frames (default: a temporary folder, removed)")
    p.add_argument("--warmup-cost", type=float, default=None,
                   help="a warm-up frame's cost in written frames, for the plan (default: measured on the workers)")
    p.add_argument("--seam", action="store_true",
                   help="after the timed runs, measure the seam at the last run's second chunk in this process: the "
                   "caustic layer of the chunk's first 4 frames against one process's, over one process's own "
                   "frame-to-frame change (the tolerance of tests/test_distributed.py, caustic_seam_factor)")
    p.add_argument("--costs", action="store_true",
                   help="after the timed runs, measure a written and a warm-up frame in this process on the workers' "
                   "device (frame_costs) and print the chunks and speed-up the plan predicts for 2, 4 and 8 workers")
    p.add_argument("--json", default=None, help="write the runs' figures to this JSON file")
    p.add_argument("--keep", default=None, metavar="FOLDER",
                   help="copy each run's frames at the last run's chunk starts (and the frame before) here")
    p.add_argument("--smoke", action="store_true",
                   help="tiny CPU run (32x18, 1 sample per pixel, 30 frames, 1000 photons, warm-up cost 0.5: 2 "
                   "workers split it after a full warm-up)")
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.frames, args.photons, args.rsm_size = 32, 18, 30, 1000, 32
        args.device, args.no_video, args.supersample = "cpu", True, 1
        args.denoiser = "svgf"  # its 25-frame warm-up fits a 30-frame shot (the caustics denoiser's is 63)
        if args.warmup_cost is None:  # tiny CPU frames on workers sharing 2 cores: a measured ratio is noise
            args.warmup_cost = 0.5
    return args


def compare(a: str, b: str, codes) -> tuple[int, float]:
    """Largest 8-bit difference and the fraction of pixel channels that differ between two runs' frames."""
    from PIL import Image

    from cisp_warp.distributed import frame_name

    worst, differ, total = 0, 0, 0
    for c in codes:
        x = np.asarray(Image.open(os.path.join(a, frame_name(c))), dtype=np.int16)
        y = np.asarray(Image.open(os.path.join(b, frame_name(c))), dtype=np.int16)
        d = np.abs(x - y)
        worst = max(worst, int(d.max()))
        differ += int(np.count_nonzero(d))
        total += d.size
    return worst, differ / max(total, 1)


def predict(args, settings, codes, threads: int) -> dict:
    """frame_costs in this process on the workers' device, and the plan it gives for 2, 4 and 8 workers: the
    largest chunk's cost in written frames and the speed-up over one worker it bounds (the frames phase)."""
    import warp as wp

    from cisp_warp.distributed import ShotJob, plan_chunks, warmup_frames
    from cisp_warp.distributed import worker as W

    device = args.device or ("cuda:0" if wp.is_cuda_available() else "cpu")
    warmup = warmup_frames(settings) if args.warmup is None else args.warmup
    job = ShotJob(scene=os.path.abspath(args.scene), out=tempfile.gettempdir(), settings=settings,
                  shot_start=codes.start, shot_stop=codes.stop, warmup=warmup, device=device, writer_threads=threads)
    costs = W.frame_costs(job, frames=5)
    W._WORKER.clear()  # its buffers freed for the seam check
    W._HOST.clear()
    out = {"device": f"{wp.get_device(device).alias} ({wp.get_device(device).name})", **costs, "plans": {}}
    print(f"frame costs on {out['device']}: written {1e3 * costs['written']:.1f} ms, warm-up "
          f"{1e3 * costs['warmup']:.1f} ms, one writer thread's PNG {1e3 * costs['encode']:.1f} ms ({threads} threads) "
          f"-> warm-up cost {costs['ratio']:.3f}", flush=True)
    for n in (2, 4, 8):
        chunks = plan_chunks(codes, codes.start, n, warmup, costs["ratio"])
        worst = max(len(c) + costs["ratio"] * min(warmup, c.start - codes.start) for c in chunks)
        dear = max(len(c) + min(warmup, c.start - codes.start) for c in plan_chunks(codes, codes.start, n, warmup))
        out["plans"][n] = {"chunks": [(c.start, c.stop) for c in chunks], "speedup": len(codes) / worst}
        print(f"  {n} workers: chunks {', '.join(f'{c.start}..{c.stop - 1}' for c in chunks)}; predicted speed-up "
              f"{len(codes) / worst:.2f}x (frames phase; with warm-up frames as dear as written ones "
              f"{len(codes) / dear:.2f}x)", flush=True)
    return out


def seam_check(args, settings, codes, start: int, stats, written: int = 4) -> dict:
    """The seam of a chunk starting at ``start`` (after the shot's warm-up), measured in this process on the
    workers' device: the denoised caustic irradiance (filtered down) of the chunk's first ``written`` frames against
    one process's, as tests/test_distributed.py measures it (mean absolute difference over one process's mean
    absolute change from the frame before), and the noise model's bound caustic_seam_factor(N, W)."""
    import warp as wp

    from cisp_warp.animation import Animation
    from cisp_warp.distributed import caustic_seam_factor, restart_history
    from cisp_warp.render import Renderer, box_filter
    from cisp_warp.sequence import render_history_frame
    from cisp_warp.usd import load_usd

    device = args.device or ("cuda:0" if wp.is_cuda_available() else "cpu")
    renderer = Renderer(load_usd(args.scene, time_code=codes.start, device=device), settings, device=device)
    animation = Animation(renderer, args.scene)
    g, ss = renderer.gbuffer, settings.supersample

    def caustics():
        return box_filter(renderer.caustic_irradiance.numpy().reshape(g.height, g.width, 3), ss)

    from cisp_warp.distributed import warmup_frames

    warmup = min(warmup_frames(settings) if args.warmup is None else args.warmup, start - codes.start)
    t0 = time.perf_counter()
    one = {}
    for c in range(codes.start, start + written):  # one process from the shot's first frame
        animation.set_time_code(c)
        renderer.render_frame()
        if c >= start - 1:
            one[c] = caustics()
    chunk = {}
    restart_history(renderer, animation, start - warmup - codes.start)  # the chunk, as render_chunk renders it
    for c in range(start - warmup, start + written):
        animation.set_time_code(c)
        if c < start:
            render_history_frame(renderer)
        else:
            renderer.render_frame()
            chunk[c] = caustics()
    ratios = [float(np.abs(chunk[c] - one[c]).mean() / change) if (change := np.abs(one[c] - one[c - 1]).mean()) > 0
              else None for c in range(start, start + written)]  # None: no caustic change to measure against
    n = settings.caustic.max_history
    bound = caustic_seam_factor(n, warmup) if settings.denoiser == "caustic" and warmup >= n - 1 else None
    out = {"start": start, "warmup": warmup, "ratios": ratios, "bound": bound, "seconds": time.perf_counter() - t0}
    print(f"seam at time code {start} after {warmup} warm-up frames: denoised caustics differ from one process's by "
          f"{', '.join('-' if r is None else f'{r:.2f}' for r in ratios)} x its own frame-to-frame change"
          + (f" (bound caustic_seam_factor({n}, {warmup}) = {bound:.2f})" if bound else ""), flush=True)
    return out


def main(argv=None) -> int:
    args = parse_args(argv)
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    from cisp_warp.distributed import render_shot, warmup_frames
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.render import RenderSettings

    counts = [int(n) for n in args.workers.split(",")]
    settings = RenderSettings(width=args.width, height=args.height, rsm_size=args.rsm_size, method=args.method,
                              photons=PhotonSettings(photons=args.photons), supersample=args.supersample,
                              **({"denoiser": args.denoiser} if args.denoiser else {}))
    codes = range(args.start, args.start + args.frames)
    threads = args.writer_threads or max(1, min(8, (os.cpu_count() or 2) // max(counts)))
    root = args.out or tempfile.mkdtemp(prefix="bench_distributed_")
    common = dict(device=args.device, warmup=args.warmup, writer_threads=threads, scheduler=args.scheduler,
                  warmup_cost=args.warmup_cost)
    print(f"{args.scene}: {len(codes)} frames at {args.width}x{args.height}, {args.photons} photons per light, "
          f"method {args.method}, {settings.supersample}x{settings.supersample} samples per pixel, warm-up {warmup_frames(settings) if args.warmup is None else args.warmup} frames "
          f"per chunk, {threads} writer threads per worker, {os.cpu_count()} host cores", flush=True)
    if not args.smoke and not args.scheduler:  # Warp's kernel cache filled: no timed run compiles
        render_shot(args.scene, range(args.start, args.start + 2), os.path.join(root, "prime"), settings, workers=1,
                    video=False, **common)
    rows = []
    try:
        for n in counts:
            out = os.path.join(root, f"workers{n}")
            t0 = time.perf_counter()
            stats = render_shot(args.scene, codes, out, settings, workers=n, video=not args.no_video, **common)
            wall = time.perf_counter() - t0
            rows.append((n, out, stats, wall))
            print(f"{n} workers: {stats.summary()}", flush=True)
            for w in stats.workers:
                if w.get("costs"):
                    c = w["costs"]
                    print(f"  worker {w['pid']} on {w['device']}: written frame {1e3 * c['written']:.1f} ms, warm-up frame "
                          f"{1e3 * c['warmup']:.1f} ms, one writer thread's PNG {1e3 * c['encode']:.1f} ms "
                          f"-> warm-up cost {c['ratio']:.3f}", flush=True)
            for r in sorted(stats.chunks, key=lambda r: r["chunk"]):
                a, b = r["chunk"]
                print(f"  chunk {a}..{b - 1} (pid {r['pid']}): {r['warmup']} warm-up frames in {r['warmup_seconds']:.2f} s, "
                      f"{len(r['written'])} written, loop {r['render_seconds']:.2f} s, writers' wait at the end "
                      f"{r['write_wait_seconds']:.2f} s, writer threads {r['write_seconds']:.1f} s", flush=True)
        base_fps = len(codes) / rows[0][2].render_seconds
        base_wall = rows[0][3]
        head = ("workers", "devices", "set-up s", "frames s", "frames/s", "speed-up", "efficiency", "wall s",
                "wall speed-up", "warm-up", "PNG thread-s", "writer wait s", "video s", "max diff", "px differ")
        lines = []
        for n, out, stats, wall in rows:
            fps = len(codes) / stats.render_seconds
            devices = "; ".join(sorted({f"{w['device']} [CUDA_VISIBLE_DEVICES={w['cuda_visible_devices']}]"
                                        if w["cuda_visible_devices"] is not None else w["device"]
                                        for w in stats.workers}))
            wait = max((r["write_wait_seconds"] for r in stats.chunks), default=0.0)
            if args.no_compare or n == rows[0][0]:
                diff, frac = "-", "-"
            else:
                d, f = compare(rows[0][1], out, codes)
                diff, frac = str(d), f"{100 * f:.3f}%"
            speed = fps / base_fps
            scale = speed * rows[0][0] / n
            lines.append((str(n), devices, f"{stats.setup_seconds:.1f}", f"{stats.render_seconds:.2f}", f"{fps:.2f}",
                          f"{speed:.2f}x", f"{100 * scale:.0f}%", f"{wall:.1f}", f"{base_wall / wall:.2f}x",
                          str(stats.warmup), f"{stats.write_seconds:.1f}", f"{wait:.2f}",
                          f"{stats.video_seconds:.1f}" if stats.video else "-", diff, frac))
        head = head + ("warm-up cost",)
        lines = [line + (f"{stats.warmup_cost:.3f}",) for line, (_, _, stats, _) in zip(lines, rows)]
        widths = [max(len(h), *(len(line[i]) for line in lines)) for i, h in enumerate(head)]
        print()
        print(" | ".join(h.ljust(w) for h, w in zip(head, widths)))
        print("-|-".join("-" * w for w in widths))
        for line in lines:
            print(" | ".join(v.ljust(w) for v, w in zip(line, widths)))
        starts = sorted(r["chunk"][0] for r in rows[-1][2].chunks if r["chunk"][0] > codes.start)
        costs = predict(args, settings, codes, threads) if args.costs else None
        if args.seam and not starts and costs:  # one worker ran: the seam where the plan puts a second chunk
            starts = [costs["plans"][2]["chunks"][1][0]]
        seam = seam_check(args, settings, codes, starts[0], rows[-1][2]) if args.seam and starts else None
        if args.keep:
            os.makedirs(args.keep, exist_ok=True)
            from cisp_warp.distributed import frame_name

            for n, out, _, _ in rows:
                for c in sorted({c for s in starts for c in (s - 1, s)}):
                    shutil.copy(os.path.join(out, frame_name(c)), os.path.join(args.keep, f"workers{n}_{frame_name(c)}"))
        if args.json:
            import json

            data = {"scene": args.scene, "frames": [codes.start, codes.stop], "settings": repr(settings),
                    "host_cores": os.cpu_count(), "writer_threads": threads, "seam": seam, "costs": costs,
                    "runs": [{"workers": n, "wall_seconds": wall, "table": dict(zip(head, line)),
                              "stats": {k: v for k, v in vars(stats).items()}}
                             for (n, _, stats, wall), line in zip(rows, lines)]}
            with open(args.json, "w") as f:
                json.dump(data, f, indent=1, default=str)
    finally:
        if args.out is None:
            shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
