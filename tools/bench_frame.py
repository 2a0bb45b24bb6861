#!/usr/bin/env python3
"""Frame benchmark in the layout of seed 000's Table 1: per-stage ms (raster, direct, trace+store,
denoise, shade) for several photon counts, methods and scenes; then the photons per second of each
method's trace stage at equal photon counts. With ``--kernels``, also the per-kernel table: ms per frame
of every kernel and copy (Warp's CUDA activity timing), and launches per frame. Every configuration also
reports the wall time per frame (frames launched back to back, one synchronisation at the end: what a
real-time loop sees, host launch overhead included); with ``--graph``, the same with the frame replayed
as one CUDA graph (``Renderer.render_frame(graph=True)``: one host->device copy of the frame's inputs, one
graph launch), and with ``--kernels`` the graph's kernels. Prints tables with the device; ``--json``
writes every figure.

    python tools/bench_frame.py                                # 1920x1080, RSM 2048², 0.5M/1M/2M photons, CISP
    python tools/bench_frame.py --scenes cornell,pool --photons 2M --kernels
    python tools/bench_frame.py --scenes cornell,pool --photons 2M --kernels --graph   # + CUDA graph replay
    python tools/bench_frame.py --methods cisp,sspm,caustics_map,reference
    python tools/bench_frame.py --device cpu --width 320 --height 180 --rsm-size 256 --photons 50k,100k
    python tools/bench_frame.py --smoke                        # seconds
    python tools/bench_frame.py --scenes pool --animate ...    # the water simulated anew before every frame

Without ``--animate`` every frame is the same still frame (camera, lights and geometry fixed). With it, before every
frame (warm-up and timed, launched or replayed) ``DeviceScene.begin_frame`` and the ``cisp:water`` meshes simulated
at t = frame / 30 s (``animation.WaterSimulation``, launched from Python outside the graph: its kernels are in the
kernel tables and the wall times).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys

import warp as wp

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = {"cornell": os.path.join(ROOT, "scenes_usd", "cornell_flooded.usda"),
          "pool": os.path.join(ROOT, "scenes_usd", "pool.usda")}


def kernel_table(results, frames: int) -> dict[str, tuple[float, float]]:
    """{activity name: (ms per frame, launches per frame)} from ``wp.timing_end()`` over ``frames`` frames."""
    acc: dict[str, list[float]] = {}
    for r in results:
        name = r.name
        if name.startswith("forward kernel "):
            name = re.sub(r"_[0-9a-f]{8}$", "", name[len("forward kernel "):])  # the module hash Warp appends
        a = acc.setdefault(name, [0.0, 0])
        a[0] += r.elapsed
        a[1] += 1
    return {k: (v[0] / frames, v[1] / frames) for k, v in sorted(acc.items(), key=lambda kv: -kv[1][0])}


def frame(r, timer=None, graph=None) -> None:
    """One frame; with ``--animate`` (``r.bench_water`` set) the water is moved first."""
    sim = getattr(r, "bench_water", None)
    if sim is not None:
        r.gpu.begin_frame()
        sim.update(r.frame / 30.0)
    r.render_frame(timer, graph=graph)


def wall_ms(r, frames: int, device, graph: bool) -> float:
    """Mean wall-clock ms per frame over ``frames`` frames launched back to back (one synchronisation at the end)."""
    import time

    wp.synchronize_device(device)
    t0 = time.perf_counter()
    for _ in range(frames):
        frame(r, graph=graph)
    wp.synchronize_device(device)
    return 1e3 * (time.perf_counter() - t0) / frames


def run_config(scene_path, method, n, args, device):
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.timing import StageTimer
    from cisp_warp.usd import load_usd

    scene = load_usd(scene_path, width=args.width, height=args.height, device=device)
    # the reference traces two passes of n per frame here: its rate per photon is what is compared
    photons = PhotonSettings(photons=n, reference_photons=2 * n,
                             sort_photons={"auto": None, "on": True, "off": False}[args.sort],
                             splat=args.splat if method in ("cisp", "sspm") else "point",
                             wavefront_grid=args.wavefront_grid)
    settings = RenderSettings(rsm_size=args.rsm_size, method=method, photons=photons, denoiser=args.denoiser)
    r = Renderer(scene, settings, device=device)
    r.set_concurrent(args.lanes != "off" and r.graph_capable)
    r.use_graph = False
    r.bench_water = None
    if args.animate:
        from cisp_warp.animation import WaterSimulation

        r.bench_water = WaterSimulation(r.gpu)
        if not len(r.bench_water):
            raise SystemExit(f"--animate: {scene_path} has no cisp:water mesh to simulate")
    timer = None
    for f in range(3 + args.frames):
        if f == 3:
            timer = StageTimer(device)
        frame(r, timer)
    row = {"photons": n, "stages": timer.medians(), "traced": n * getattr(r.photons, "passes", 1) * len(scene.lights)}
    row["wall_ms"] = wall_ms(r, args.frames, device, graph=False)
    if args.graph and r.graph_capable:
        frame(r, graph=True)  # captures
        row["graph_ms"] = wall_ms(r, args.frames, device, graph=True)
        if args.lanes == "both":  # the sequential twin's graph against the concurrent one's, alternating, best of 3
            best = {True: row["graph_ms"], False: float("inf")}
            for rep in range(3):
                for on in (False, True):
                    r.set_concurrent(on)
                    frame(r, graph=True)  # captures again
                    best[on] = min(best[on], wall_ms(r, args.frames, device, graph=True))
            row["graph_ms"], row["graph_ms_sequential"] = best[True], best[False]
        row["lanes"] = r.lanes is not None
        if args.kernels:
            wp.timing_begin(cuda_filter=wp.TIMING_ALL)
            for _ in range(args.frames):
                frame(r, graph=True)
            row["graph_kernels"] = kernel_table(wp.timing_end(), args.frames)
    if getattr(r.photons, "wavefront", None) is not None:
        row["traced"] = r.photons.wavefront.photons_traced()  # two sheets through every grid corner
    if args.kernels and device.is_cuda:
        # per kernel from the sequential program: launched on several streams, kernels share the GPU and each one's
        # own time says little (the concurrent frame's cost is its graph time above)
        r.set_concurrent(False)
        wp.timing_begin(cuda_filter=wp.TIMING_ALL)
        for _ in range(args.frames):
            frame(r)
        row["kernels"] = kernel_table(wp.timing_end(), args.frames)
    return row


def main(argv=None) -> int:
    from cisp_warp.cli import parse_count

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default=None, help="a USD stage (default: --scenes)")
    p.add_argument("--scenes", default="cornell", help="comma-separated: cornell, pool, or stage paths")
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--rsm-size", type=int, default=2048)
    p.add_argument("--photons", default="500k,1M,2M", help="comma-separated photon counts (per light)")
    p.add_argument("--methods", default="cisp", help="comma-separated: cisp, sspm, caustics_map, reference")
    p.add_argument("--denoiser", default="caustic", choices=["caustic", "svgf", "gather", "none"],
                   help="caustic (the renderer's default), svgf (the paper's), gather, none")
    p.add_argument("--sort", default="auto", choices=["auto", "on", "off"],
                   help="trace RSM photons in texel order (auto: on CUDA only)")
    p.add_argument("--splat", default="point", choices=["point", "wavefront"],
                   help="cisp, sspm: point deposits or wavefront splatting (photons = grid cells per light)")
    p.add_argument("--wavefront-grid", default="rsm", choices=["rsm", "mesh"],
                   help="--splat wavefront: cells over the RSM's texels or over the water mesh's triangles")
    p.add_argument("--frames", type=int, default=20, help="timed frames per configuration (after 3 warm-up)")
    p.add_argument("--kernels", action="store_true",
                   help="also time every kernel (CUDA activity timing, separate frames of the one-stream program) and count "
                        "launches")
    p.add_argument("--graph", action="store_true",
                   help="also time the frame replayed as one CUDA graph (CUDA; cisp/sspm with point splats)")
    p.add_argument("--animate", action="store_true",
                   help="simulate the scene's cisp:water meshes anew before every frame (else every frame is still)")
    p.add_argument("--lanes", default="on", choices=["on", "off", "both"],
                   help="the frame's lights, sky and direct light on CUDA streams of their own (on, the default), "
                        "one stream (off), or both graphs timed alternately (with --graph)")
    p.add_argument("--json", default=None, help="write every figure to this file")
    p.add_argument("--smoke", action="store_true", help="tiny sizes, 2 frames")
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.rsm_size, args.photons, args.frames = 64, 36, 64, "2k", 2
    wp.config.log_level = wp.LOG_WARNING  # no init banner or module-load lines
    wp.init()

    device = wp.get_device(args.device)
    counts = [parse_count(c) for c in args.photons.split(",")]
    methods = [m.strip() for m in args.methods.split(",")]
    scenes = [args.scene] if args.scene else [SCENES.get(s.strip(), s.strip()) for s in args.scenes.split(",")]
    dev = f"{device.alias} ({device.name})"
    report = {"device": dev, "warp": wp.config.version, "width": args.width, "height": args.height,
              "rsm_size": args.rsm_size, "denoiser": args.denoiser, "frames": args.frames, "animate": args.animate,
              "runs": []}
    for scene_path in scenes:
        sname = os.path.splitext(os.path.basename(scene_path))[0]
        results = {}
        for method in methods:
            rows = [run_config(scene_path, method, n, args, device) for n in counts]
            results[method] = rows
            for row in rows:
                splat = args.splat if method in ("cisp", "sspm") else "point"
                report["runs"].append({"scene": sname, "method": method, "splat": splat,
                                       "wavefront_grid": args.wavefront_grid, **row})
            stages = list(rows[0]["stages"])
            splat = f", splat {args.splat}" if method in ("cisp", "sspm") else ""
            if splat and args.splat == "wavefront":
                splat += f" over the {args.wavefront_grid} grid"
            print(f"{sname}, {method}: device {dev}; {args.width}x{args.height}, RSM {args.rsm_size}², "
                  f"denoiser {args.denoiser}{splat}; {'water simulated every frame' if args.animate else 'still'}; "
                  f"median ms over {args.frames} frames")
            print(f"{'stage':<14}" + "".join(f"{row['photons']:>14,}" for row in rows))
            for s in stages:
                print(f"{s:<14}" + "".join(f"{row['stages'][s]:14.3f}" for row in rows))
            print(f"{'total':<14}" + "".join(f"{sum(row['stages'].values()):14.3f}" for row in rows))
            print(f"{'wall/frame':<14}" + "".join(f"{row['wall_ms']:14.3f}" for row in rows))
            if "graph_ms" in rows[0]:
                lanes = " (lanes)" if rows[0].get("lanes") else ""
                print(f"{'graph/frame':<14}" + "".join(f"{row.get('graph_ms', float('nan')):14.3f}" for row in rows)
                      + lanes)
            if "graph_ms_sequential" in rows[0]:
                print(f"{'graph/seq':<14}" + "".join(f"{row['graph_ms_sequential']:14.3f}" for row in rows))
            for key, title in (("kernels", "launched from Python"), ("graph_kernels", "replayed as one CUDA graph")):
                if key not in rows[0]:
                    continue
                names = list(dict.fromkeys(k for row in rows for k in row[key]))
                width = max(len(k) for k in names) + 2
                print(f"\nper kernel, ms per frame (launches per frame), mean over {args.frames} frames, {title}")
                print(f"{'kernel':<{width}}" + "".join(f"{row['photons']:>18,}" for row in rows))
                for k in names:
                    cells = []
                    for row in rows:
                        ms, count = row[key].get(k, (0.0, 0))
                        cells.append(f"{ms:10.3f} ({count:4.0f})")
                    print(f"{k:<{width}}" + "".join(f"{c:>18}" for c in cells))
                totals = [(sum(v[0] for v in row[key].values()), sum(v[1] for v in row[key].values()))
                          for row in rows]
                print(f"{'sum':<{width}}" + "".join(f"{f'{ms:10.3f} ({c:4.0f})':>18}" for ms, c in totals))
            print()
        print(f"{sname}: trace+store rate [million photons per second], device {dev}")
        print(f"{'method':<14}" + "".join(f"{n:>14,}" for n in counts))
        for method, rows in results.items():
            rates = [row["traced"] / row["stages"]["trace+store"] / 1e3 for row in rows]
            print(f"{method:<14}" + "".join(f"{r:14.2f}" for r in rates))
        print()
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
