#!/usr/bin/env python3
"""Raster benchmark: ms per view (camera G-buffer, each RSM view) for a USD scene; prints a table.

    python tools/bench_raster.py                       # flooded Cornell box, 1920x1080, RSM 2048², default device
    python tools/bench_raster.py --device cpu --smoke  # seconds, tiny sizes
    python tools/bench_raster.py --scene scenes_usd/pool.usda --naive   # the tile walk's naive twin (raster_tiles)
    python tools/bench_raster.py --columns             # the opt-in column raster (raster_tile_columns)
"""

from __future__ import annotations

import argparse
import os
import sys

import warp as wp

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default=os.path.join(ROOT, "scenes_usd", "cornell_flooded.usda"))
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--rsm-size", type=int, default=2048)
    p.add_argument("--frames", type=int, default=20, help="timed frames (after 3 warm-up frames)")
    p.add_argument("--smoke", action="store_true", help="tiny sizes and 2 frames: a quick check that it runs")
    p.add_argument("--naive", action="store_true", help="draw with raster_tiles (a thread per tile), the naive twin "
                   "of the default raster_tiles_reject / raster_tile_rows")
    p.add_argument("--columns", action="store_true", help="draw with the opt-in column raster raster_tile_columns")
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.rsm_size, args.frames = 64, 36, 64, 2
    wp.init()
    from cisp_warp.raster import GBuffer, LightMaps, Rasterizer, camera_view
    from cisp_warp.raster.rasterizer import view_array
    from cisp_warp.scene import DeviceScene
    from cisp_warp.timing import StageTimer
    from cisp_warp.usd import load_usd

    device = wp.get_device(args.device)
    scene = load_usd(args.scene, width=args.width, height=args.height, device=device)
    gpu = DeviceScene(scene, device)
    raster = Rasterizer(gpu)
    raster.columns = args.columns
    raster.reject = not args.naive
    view = camera_view(scene.camera)
    cams = view_array([view, view], device)  # the camera, this frame and the last
    gbuf = GBuffer.allocate(view.width, view.height, device)
    lights = [LightMaps(gpu, light, args.rsm_size) for light in scene.lights]
    timer = StageTimer(device)
    for frame in range(3 + args.frames):
        if frame == 3:
            timer = StageTimer(device)
        with timer.stage(f"camera G-buffer {view.width}x{view.height}"):
            gbuf.render(raster, cams)
        for lm in lights:
            with timer.stage(f"RSM {lm.light.safe_name} ({len(lm.rsm)} view(s) of {args.rsm_size}²)"):
                lm.render(raster)
    print(f"device: {device.alias} ({device.name}); scene {os.path.basename(args.scene)}: "
          f"{scene.triangle_count} triangles; median of {args.frames} frames; "
          f"{'raster_tile_columns' if args.columns else 'raster_tiles (naive twin)' if args.naive else 'raster_tiles_reject (raster_tile_rows for views of <= 512² pixels)'}")
    print(f"{'view':<48}{'ms':>10}")
    for name, ms in timer.medians().items():
        print(f"{name:<48}{ms:10.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
