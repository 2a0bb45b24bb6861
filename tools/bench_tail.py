#!/usr/bin/env python3
"""The concurrent program's tail, after the frame's join (docs/perf_notes.md section 76): with the hidden hits' shading
folded into the composite's gather (``HiddenSurfaces.GATHERED``, the default) and apart (``shade.composite_gather``,
then ``hidden_direct_strided`` per shadow map and ``hidden_caustic_strided`` per light).

Per setting: the concurrent frame replayed as a CUDA graph (ms per frame, best of 3 alternating rounds, as
``bench_frame --graph --lanes both``), and the per-kernel table of the concurrent program launched from Python (Warp's
CUDA activity timing). The kernels before the join share the GPU with the traces, so their own times say little; the
tail's (``reproject`` ... ``unpack_level``, the gather, the hidden hits' kernels) run alone and are theirs.

    python tools/bench_tail.py --scenes pool,cornell --photons 2M --frames 10
    python tools/bench_tail.py --device cpu --width 64 --height 36 --rsm-size 64 --photons 20k --frames 1   # smoke
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import warp as wp

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tools"))

#: kernels of the concurrent program's tail (run alone, after the join), by name prefix
TAIL = ("reproject", "filter_moments", "store_history", "atrous", "unpack_level", "flip_parity", "composite_gather",
        "hidden_direct", "hidden_caustic")


def main(argv=None) -> int:
    from bench_frame import SCENES, frame, kernel_table, wall_ms
    from cisp_warp.cli import parse_count
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.shade_hidden import HiddenSurfaces
    from cisp_warp.usd import load_usd

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", default="pool,cornell")
    p.add_argument("--device", default=None)
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--rsm-size", type=int, default=2048)
    p.add_argument("--photons", default="2M")
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    device = wp.get_device(args.device)
    out = {"device": device.name if device.is_cuda else "cpu", "runs": []}
    for name in args.scenes.split(","):
        scene = load_usd(SCENES.get(name, name), width=args.width, height=args.height, device=device)
        settings = RenderSettings(rsm_size=args.rsm_size, method="cisp", denoiser="svgf",
                                  photons=PhotonSettings(photons=parse_count(args.photons)))
        r = Renderer(scene, settings, device=device)
        r.set_concurrent(True)
        for _ in range(3):
            frame(r, graph=False)
        row = {"scene": name, "graph_ms": {}, "kernels": {}}
        kept = HiddenSurfaces.GATHERED
        try:
            if device.is_cuda and r.graph_capable:
                best = {False: float("inf"), True: float("inf")}
                for _ in range(3):
                    for gathered in (False, True):
                        HiddenSurfaces.GATHERED = gathered
                        r._graph = None  # captured again with this setting
                        frame(r, graph=True)
                        best[gathered] = min(best[gathered], wall_ms(r, args.frames, device, graph=True))
                row["graph_ms"] = {("folded" if k else "apart"): v for k, v in best.items()}
            for gathered in (False, True):
                HiddenSurfaces.GATHERED = gathered
                frame(r, graph=False)
                wp.timing_begin(cuda_filter=wp.TIMING_ALL)
                for _ in range(args.frames):
                    frame(r, graph=False)
                table = kernel_table(wp.timing_end(), args.frames)
                row["kernels"]["folded" if gathered else "apart"] = table
        finally:
            HiddenSurfaces.GATHERED = kept
        out["runs"].append(row)
        print(f"{name}: concurrent graph ms per frame {row['graph_ms']}")
        for setting, table in row["kernels"].items():
            tail = {k: v for k, v in table.items() if k.startswith(TAIL)}
            total = sum(v[0] for v in tail.values())
            launches = sum(v[1] for v in tail.values())
            print(f"  tail, {setting}: {total:.4f} ms in {launches:g} launches")
            for k, (ms, n) in tail.items():
                print(f"    {k:<36} {ms:8.4f} ms  {n:g}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
