#!/usr/bin/env python3
"""Animated-frame benchmark: seconds per frame and memory across a sequence of the pool (or any stage).

Prints two tables:

* camera per frame: reading the camera of a time code from the open stage (``StageClock.camera``, what
  ``Animation`` does) against re-importing the whole stage (``load_usd``, the baked-animation path);
* the frame loop: median seconds of ``Animation.set_time_code`` (water, refit, camera), ``render_frame``
  and the output (host copy of ``final``, tone map, PNG), and memory [MiB] after the first and the last
  frame: process RSS (current, from /proc/self/statm), and on CUDA the device memory in use and Warp's
  mempool in use. Flat memory means nothing is allocated per frame.

    python tools/bench_animation.py                                  # pool, 30 frames, CLI defaults
    python tools/bench_animation.py --device cpu --frames 60 --photons 500k
    python tools/bench_animation.py --smoke                          # seconds
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


def _median_ms(fn, repeats: int) -> float:
    times = []
    for k in range(repeats):
        t0 = time.perf_counter()
        fn(k)
        times.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(times)


def main(argv=None) -> int:
    from cisp_warp.cli import parse_count

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default=os.path.join(ROOT, "scenes_usd", "pool.usda"))
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--width", type=int, default=None, help="default: the stage's render settings")
    p.add_argument("--height", type=int, default=None)
    p.add_argument("--rsm-size", type=int, default=1024)
    p.add_argument("--photons", type=parse_count, default=parse_count("1M"))
    p.add_argument("--frames", type=int, default=30, help="frames rendered (time codes start .. start + frames - 1)")
    p.add_argument("--start", type=int, default=0, help="first time code")
    p.add_argument("--smoke", action="store_true", help="tiny sizes, 3 frames")
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.rsm_size, args.photons, args.frames = 64, 36, 64, 2000, 3
    if args.frames < 2:
        p.error("--frames must be at least 2 (memory is compared between the first and the last frame)")

    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    from PIL import Image

    from cisp_warp.animation import Animation, memory_in_use
    from cisp_warp.errors import SceneError
    from cisp_warp.image_io import auto_exposure, tonemap
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.usd import load_usd

    device = wp.get_device(args.device)
    try:
        scene = load_usd(args.scene, time_code=args.start, width=args.width, height=args.height, device=device)
        settings = RenderSettings(rsm_size=args.rsm_size, photons=PhotonSettings(photons=args.photons))
        renderer = Renderer(scene, settings, device=device)
        anim = Animation(renderer, args.scene)
    except SceneError as exc:
        print(f"bench_animation: error: {exc}", file=sys.stderr)
        return 2
    g = renderer.gbuffer
    codes = list(range(args.start, args.start + args.frames))

    reads = min(args.frames, 10)
    cam_ms = _median_ms(lambda k: anim.clock.camera(codes[k], g.width, g.height), reads)
    load_ms = _median_ms(lambda k: load_usd(args.scene, time_code=codes[k], width=g.width, height=g.height,
                                            device=device), reads)
    print(f"scene {os.path.relpath(args.scene)}: {scene.triangle_count} triangles, {len(anim.water or [])} "
          f"simulated water mesh(es); device {device.alias} ({device.name})")
    print(f"{'camera per frame':<34}{'median ms':>12}")
    print(f"{'  StageClock.camera (open stage)':<34}{cam_ms:12.3f}")
    print(f"{'  load_usd (re-import the stage)':<34}{load_ms:12.3f}")

    stages = {"set_time_code": [], "render_frame": [], "output": []}
    memory = []
    exposure = None
    with tempfile.TemporaryDirectory() as tmp:
        for code in codes:
            t0 = time.perf_counter()
            anim.set_time_code(code)
            wp.synchronize_device(device)
            t1 = time.perf_counter()
            renderer.render_frame()
            wp.synchronize_device(device)
            t2 = time.perf_counter()
            final = renderer.final.numpy().reshape(g.height, g.width, 3)
            exposure = auto_exposure(final) if exposure is None else exposure
            Image.fromarray(tonemap(final, exposure)).save(os.path.join(tmp, f"final.{code:04d}.png"))
            t3 = time.perf_counter()
            for name, dt in zip(stages, (t1 - t0, t2 - t1, t3 - t2)):
                stages[name].append(dt)
            memory.append(memory_in_use(device))
    print(f"\n{g.width}x{g.height}, RSM {args.rsm_size}², {args.photons:,} photons per light, "
          f"{len(scene.lights)} light(s); {args.frames} frames")
    print(f"{'stage':<16}{'median s':>12}")
    for name, v in stages.items():
        print(f"{name:<16}{statistics.median(v):12.4f}")
    total = [sum(v) for v in zip(*stages.values())]
    print(f"{'frame':<16}{statistics.median(total):12.4f}")
    print(f"\n{'memory [MiB]':<16}{'frame ' + str(codes[0]):>14}{'frame ' + str(codes[-1]):>14}{'change':>10}")
    for key in memory[0]:
        a, b = memory[0][key], memory[-1][key]
        print(f"{key:<16}{a:14.1f}{b:14.1f}{b - a:10.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
