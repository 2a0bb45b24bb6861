#!/usr/bin/env python3
"""Frame benchmark in the layout of seed 000's Table 1: per-stage ms (raster, direct, trace+store,
denoise, shade) for several photon counts and methods; then the photons per second of each method's
trace stage at equal photon counts. Prints tables with the device.

    python tools/bench_frame.py                                # 1920x1080, RSM 2048², 0.5M/1M/2M photons, CISP
    python tools/bench_frame.py --methods cisp,sspm,caustics_map,reference
    python tools/bench_frame.py --device cpu --width 320 --height 180 --rsm-size 256 --photons 50k,100k
    python tools/bench_frame.py --smoke                        # seconds
"""

from __future__ import annotations

import argparse
import os
import sys

import warp as wp

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main(argv=None) -> int:
    from cisp_warp.cli import parse_count

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default=os.path.join(ROOT, "scenes_usd", "cornell_flooded.usda"))
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--rsm-size", type=int, default=2048)
    p.add_argument("--photons", default="500k,1M,2M", help="comma-separated photon counts")
    p.add_argument("--methods", default="cisp", help="comma-separated: cisp, sspm, caustics_map, reference")
    p.add_argument("--denoiser", default="svgf", choices=["svgf", "gather", "none"])
    p.add_argument("--sort", default="auto", choices=["auto", "on", "off"],
                   help="trace RSM photons in texel order (auto: on CUDA only)")
    p.add_argument("--splat", default="point", choices=["point", "wavefront"],
                   help="cisp, sspm: point deposits or wavefront splatting (photons = grid cells per light)")
    p.add_argument("--frames", type=int, default=20, help="timed frames per configuration (after 3 warm-up)")
    p.add_argument("--smoke", action="store_true", help="tiny sizes, 2 frames")
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.rsm_size, args.photons, args.frames = 64, 36, 64, "2k", 2
    wp.config.log_level = wp.LOG_WARNING  # no init banner or module-load lines
    wp.init()
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.timing import StageTimer
    from cisp_warp.usd_import import load_usd

    device = wp.get_device(args.device)
    counts = [parse_count(c) for c in args.photons.split(",")]
    methods = [m.strip() for m in args.methods.split(",")]
    results = {}
    for method in methods:
        rows = []
        for n in counts:
            scene = load_usd(args.scene, width=args.width, height=args.height, device=device)
            # the reference traces two passes of n per frame here: its rate per photon is what is compared
            photons = PhotonSettings(photons=n, reference_photons=2 * n,
                                     sort_photons={"auto": None, "on": True, "off": False}[args.sort],
                                     splat=args.splat if method in ("cisp", "sspm") else "point")
            settings = RenderSettings(rsm_size=args.rsm_size, method=method, photons=photons, denoiser=args.denoiser)
            r = Renderer(scene, settings, device=device)
            timer = None
            for frame in range(3 + args.frames):
                if frame == 3:
                    timer = StageTimer(device)
                r.render_frame(timer)
            traced = n * getattr(r.photons, "passes", 1) * len(scene.lights)
            if getattr(r.photons, "wavefront", None) is not None:
                traced = r.photons.wavefront.photons_traced()  # two sheets through every grid corner
            rows.append((n, timer.medians(), traced))
        results[method] = rows
        stages = list(rows[0][1])
        splat = f", splat {args.splat}" if method in ("cisp", "sspm") else ""
        print(f"{method}: device {device.alias} ({device.name}); {args.width}x{args.height}, RSM {args.rsm_size}², "
              f"denoiser {args.denoiser}{splat}; median ms over {args.frames} frames")
        print(f"{'stage':<14}" + "".join(f"{n:>14,}" for n, _, _ in rows))
        for s in stages:
            print(f"{s:<14}" + "".join(f"{m[s]:14.3f}" for _, m, _ in rows))
        print(f"{'total':<14}" + "".join(f"{sum(m.values()):14.3f}" for _, m, _ in rows))
        print()
    print(f"trace+store rate [million photons per second], device {device.alias} ({device.name})")
    print(f"{'method':<14}" + "".join(f"{n:>14,}" for n in counts))
    for method, rows in results.items():
        print(f"{method:<14}" + "".join(f"{traced / m['trace+store'] / 1e3:14.2f}" for _, m, traced in rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
