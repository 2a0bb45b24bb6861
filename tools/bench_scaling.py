#!/usr/bin/env python3
"""Cost against work, for an animated frame of the pool: trace ms against photons, and against the water's size.

Every frame is animated as ``cisp-render`` animates it (:class:`cisp_warp.animation.Animation`): the water is
simulated on the device, the BVHs the photon pass uses are refit (``sspm``'s price for tracing in world space;
``cisp`` builds none) and every view is rasterized again (``cisp``'s price: it traces in the rasters, and ``sspm``
emits from the RSM and stores by the camera's depth, so it pays the raster too). Stage times are CUDA events
(synchronised wall clock on the CPU), medians over ``--frames`` frames after ``--warmup``:

* ``water``: the simulation (FFT, displacement, normals into the scene's points) and the frame's bookkeeping;
* ``refit``: the BVH refit (zero where no BVH exists);
* ``raster``, ``direct``, ``sky``, ``trace+store``, ``denoise``, ``shade``: ``Renderer.render_frame``'s stages.

Two sweeps, each for every method:

1. photons per light (default 0.5M .. 16M) on the shipped pool: trace+store ms, ns per traced photon, and the
   ratio of the per-photon cost at the largest count to that at 1M (the issue asks for <= 1.2);
2. water triangles (default about 16k, 1M, 4M): the pool generated with finer water grids
   (``cisp_warp.pool_scene``, ``--water-spacing``), at ``--scene-photons`` photons per light.

Prints both tables with the device; writes ``OUT/scaling.json`` (every figure) and ``OUT/scaling.png`` (the chart,
when matplotlib is installed).

    python tools/bench_scaling.py --out results/scaling            # the full set (H100: about 3 minutes)
    python tools/bench_scaling.py --photons 1M,4M --water 16k,1M   # fewer points
    python tools/bench_scaling.py --smoke --device cpu --out /tmp/s  # seconds
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import shutil
import sys
import tempfile
from contextlib import nullcontext
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

POOL = ROOT / "scenes_usd" / "pool.usda"
STAGES = ("water", "refit", "raster", "direct", "sky", "trace+store", "denoise", "shade")


def spacing_for(triangles: int) -> float:
    """Water grid spacing [m] that gives the 8 m x 4 m pool about ``triangles`` water triangles (2 per quad)."""
    from cisp_warp.pool_scene import POOL_HALF

    area = 4.0 * POOL_HALF[0] * POOL_HALF[1]
    return math.sqrt(2.0 * area / triangles)


def pool_with_water(out_dir: Path, spacing: float) -> tuple[Path, int]:
    """Write the pool with water grid ``spacing`` [m] into ``out_dir``; (stage path, water triangles).

    Only the water grid differs from the shipped pool, so its sky image is the shipped one (copied beside the
    stage), which spares the benchmark OpenEXR's writer."""
    from cisp_warp import pool_scene

    opts = pool_scene.PoolOptions(water_spacing=spacing)
    nx, nz = opts.water_counts()
    out_dir.mkdir(parents=True, exist_ok=True)
    shutil.copy(ROOT / "scenes_usd" / pool_scene.SKY_IMAGE, out_dir / pool_scene.SKY_IMAGE)
    path = out_dir / f"pool_{nx}x{nz}.usdc"
    write_exr = pool_scene.write_exr
    pool_scene.write_exr = lambda *_: None  # the sky image is in place already
    try:
        pool_scene.build(path, opts)
    finally:
        pool_scene.write_exr = write_exr
    return path, 2 * (nx - 1) * (nz - 1)


class _RefitTimer:
    """Times ``DeviceScene.refit`` as its own stage inside ``Animation.set_time_code``."""

    def __init__(self, gpu, timer_ref: list):
        self._refit = gpu.refit
        self._timer_ref = timer_ref

    def __call__(self):
        timer = self._timer_ref[0]
        if timer is None:
            return self._refit()
        with timer.stage("refit"):
            self._refit()


def run(scene, path: Path, method: str, photons: int, args, device) -> dict:
    """Median stage ms of an animated frame: ``--warmup`` frames, then ``--frames`` timed ones."""
    import warp as wp

    from cisp_warp.animation import Animation
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.timing import StageTimer

    settings = RenderSettings(rsm_size=args.rsm_size, method=method, denoiser=args.denoiser,
                              photons=PhotonSettings(photons=photons), sky_maps=args.sky_maps)
    r = Renderer(scene, settings, device=device)
    anim = Animation(r, str(path))
    timer_ref = [None]
    r.gpu.refit = _RefitTimer(r.gpu, timer_ref)
    timer = None
    for k in range(args.warmup + args.frames):
        if k == args.warmup:
            timer = timer_ref[0] = StageTimer(device)
        with timer.stage("water") if timer is not None else nullcontext():
            anim.set_time_code(args.start + k)
        r.render_frame(timer)
    stages = timer_ref[0].medians()
    # the refit ran inside the "water" stage's events: take it out
    stages["water"] = max(0.0, stages.get("water", 0.0) - stages.get("refit", 0.0))
    stages.setdefault("refit", 0.0)
    stages = {s: stages[s] for s in STAGES if s in stages}
    traced = photons * len(scene.lights)
    row = {"method": method, "photons": photons, "traced": traced, "triangles": int(scene.triangle_count),
           "stages": stages, "frame_ms": sum(stages.values()),
           "scene_and_trace_ms": stages["refit"] + stages["raster"] + stages["trace+store"],
           "ns_per_photon": 1e6 * stages["trace+store"] / traced}
    del anim, r
    gc.collect()  # the next configuration's buffers where this one's were
    wp.synchronize_device(device)
    return row


def chart(report: dict, path: str) -> None:
    """Left: trace+store ms against photons; right: the animated frame's cost against water triangles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    colours = {"cisp": "tab:blue", "sspm": "tab:orange", "caustics_map": "tab:green"}
    for m in report["methods"]:
        rows = [r for r in report["photon_sweep"] if r["method"] == m]
        c = colours.get(m)
        ratio = report.get("per_photon_ratio", {}).get(m)
        lo, hi = report.get("per_photon_ratio_counts", (0, 0))
        note = f" (ns per photon, {hi / 1e6:g}M over {lo / 1e6:g}M: {ratio:.2f})" if ratio else ""
        a.plot([r["traced"] / 1e6 for r in rows], [r["stages"]["trace+store"] for r in rows], "o-", color=c,
               label=f"{m} trace+store{note}")
        rows = [r for r in report["scene_sweep"] if r["method"] == m]
        tri = [r["water_triangles"] for r in rows]
        b.plot(tri, [r["scene_and_trace_ms"] for r in rows], "o-", color=c,
               label=f"{m}: refit + raster + trace+store")
        b.plot(tri, [r["stages"]["trace+store"] for r in rows], "s--", color=c, lw=1, label=f"{m}: trace+store")
        if m == "sspm":
            b.plot(tri, [r["stages"]["refit"] for r in rows], "^:", color=c, lw=1, label="sspm: BVH refit")
    raster = {r["water_triangles"]: r["stages"]["raster"] for r in report["scene_sweep"]}
    b.plot(list(raster), list(raster.values()), "d:", color="tab:gray", lw=1, label="raster (every method)")
    for ax in (a, b):
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):  # 1-2-5 ticks in plain numbers on the log axes
            axis.set_major_locator(matplotlib.ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
            axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.set_ylabel("ms per frame")
        ax.legend(fontsize=7)
    a.set_xlabel("photons traced per frame [million] (all lights)")
    a.set_title("pool, animated: trace against photons")
    b.set_xlabel("water triangles")
    b.set_title(f"against water triangles, {report['scene_photons'] / 1e6:g}M photons per light")
    fig.suptitle(f"{report['device']}, {report['width']}x{report['height']}, RSM {report['rsm_size']}²", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    from cisp_warp.cli import parse_count

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--rsm-size", type=int, default=2048)
    p.add_argument("--methods", default="cisp,sspm", help="comma-separated: cisp, sspm, caustics_map")
    p.add_argument("--photons", default="500k,1M,2M,4M,8M,16M", help="photon sweep: photons per light")
    p.add_argument("--water", default="16k,1M,4M", help="scene sweep: water triangles (about; the grid rounds)")
    p.add_argument("--scene-photons", type=parse_count, default=parse_count("2M"),
                   help="photons per light of the scene sweep")
    p.add_argument("--denoiser", default="caustic", choices=["caustic", "svgf", "gather", "none"])
    p.add_argument("--sky-maps", type=int, default=32, help="occlusion maps of the pool's sky term")
    p.add_argument("--frames", type=int, default=10, help="timed frames per configuration")
    p.add_argument("--warmup", type=int, default=3, help="frames before the timed ones")
    p.add_argument("--start", type=int, default=24, help="first time code (the water is in motion from 0)")
    p.add_argument("--out", default="results/scaling", help="directory for scaling.json and scaling.png")
    p.add_argument("--smoke", action="store_true", help="tiny sizes, 2 frames (seconds on the CPU)")
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.rsm_size, args.sky_maps = 48, 27, 64, 2
        args.photons, args.water, args.scene_photons = "1k,2k", "2k,8k", 1000
        args.frames, args.warmup = 2, 1
    try:
        counts = [parse_count(c) for c in args.photons.split(",")]
        water = [parse_count(c) for c in args.water.split(",")]
    except argparse.ArgumentTypeError as exc:
        p.error(str(exc))
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    for m in methods:
        if m not in ("cisp", "sspm", "caustics_map"):
            p.error(f"--methods: {m!r} is not one of cisp, sspm, caustics_map")

    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    from cisp_warp.usd import load_usd

    device = wp.get_device(args.device)
    dev = f"{device.alias} ({device.name})"
    os.makedirs(args.out, exist_ok=True)
    report = {"device": dev, "warp": wp.config.version, "width": args.width, "height": args.height,
              "rsm_size": args.rsm_size, "denoiser": args.denoiser, "frames": args.frames, "warmup": args.warmup,
              "methods": methods, "scene_photons": args.scene_photons, "photon_sweep": [], "scene_sweep": []}
    print(f"device {dev}, Warp {wp.config.version}; {args.width}x{args.height}, RSM {args.rsm_size}², denoiser "
          f"{args.denoiser}; animated pool (water simulated, BVHs refit every frame); median ms over {args.frames} "
          f"frames after {args.warmup}", flush=True)

    scene = load_usd(POOL, time_code=args.start, width=args.width, height=args.height, device=device)
    for m in methods:
        for n in counts:
            report["photon_sweep"].append(run(scene, POOL, m, n, args, device))
    print(f"\n1. photons per light on the shipped pool ({scene.triangle_count:,} triangles, "
          f"{len(scene.lights)} lights): trace+store ms (ns per traced photon)")
    base_count = 1_000_000 if 1_000_000 in counts else counts[0]
    report["per_photon_ratio_counts"] = [base_count, counts[-1]]
    print(f"{'method':<14}" + "".join(f"{n:>18,}" for n in counts) + f"{'cost ratio':>12}")
    for m in methods:
        rows = [r for r in report["photon_sweep"] if r["method"] == m]
        ns = {r["photons"]: r["ns_per_photon"] for r in rows}
        ratio = ns[counts[-1]] / ns[base_count]
        report.setdefault("per_photon_ratio", {})[m] = ratio
        print(f"{m:<14}" + "".join(f"{r['stages']['trace+store']:10.3f} ({r['ns_per_photon']:5.2f})" for r in rows)
              + f"{ratio:12.2f}")
    print(f"cost ratio: ns per photon at {counts[-1]:,} over that at {base_count:,}")

    with tempfile.TemporaryDirectory() as tmp:
        for target in water:
            path, tris = pool_with_water(Path(tmp) / str(target), spacing_for(target))
            sc = load_usd(path, time_code=args.start, width=args.width, height=args.height, device=device)
            for m in methods:
                row = run(sc, path, m, args.scene_photons, args, device)
                row["water_triangles"] = tris
                report["scene_sweep"].append(row)
            del sc
    print(f"\n2. water triangles at {args.scene_photons:,} photons per light: ms per animated frame")
    head = ("water", "refit", "raster", "trace+store", "r+r+t", "frame")
    print(f"{'method':<8}{'triangles':>12}" + "".join(f"{h:>13}" for h in head))
    for r in report["scene_sweep"]:
        s = r["stages"]
        cells = (s["water"], s["refit"], s["raster"], s["trace+store"], r["scene_and_trace_ms"], r["frame_ms"])
        print(f"{r['method']:<8}{r['water_triangles']:>12,}" + "".join(f"{v:13.3f}" for v in cells))
    print("r+r+t: refit + raster + trace+store, what tracing costs beyond the simulation; frame: every stage")

    with open(os.path.join(args.out, "scaling.json"), "w") as f:
        json.dump(report, f, indent=1)
    try:
        chart(report, os.path.join(args.out, "scaling.png"))
        print(f"wrote {args.out}/scaling.json, scaling.png")
    except ImportError:
        print(f"wrote {args.out}/scaling.json (matplotlib is not installed: no scaling.png)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
