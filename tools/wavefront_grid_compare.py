"""Wavefront splatting's two grids against photon count: cells over the RSM's texels (``rsm``) or over the
water mesh's own triangles (``mesh``), one raw frame each (no denoiser, no temporal filter).

The error is the relative RMSE of the raw photon map over the caustic mask (``metrics.relative_rmse``): on the
sinusoid against its analytic ray map; on the pool (or Cornell) against the mean of both grids' maps at
``--reference`` cells, whose own difference is printed (the two grids converge to the same map; the pool's
point-photon reference needs a GPU). Frame and trace times are printed too: CPU timings are no GPU figures.

    python tools/wavefront_grid_compare.py --scene pool --size 480x270 --counts 65k,262k,1M --reference 4M
    python tools/wavefront_grid_compare.py --smoke
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from evaluate import analytic_sinusoid_reference, scene_specs  # noqa: E402  (tools/ sibling; puts ROOT on the path)

GRIDS = ("rsm", "mesh")


def parse_count(text: str) -> int:
    t = text.strip().lower()
    scale = {"k": 1_000, "m": 1_000_000}.get(t[-1:], 1)
    if t[-1:] in ("k", "m"):
        t = t[:-1]
    value = float(t) * scale
    # 65k, 262k, 1m name the powers of two 2^16, 2^18, 2^20 as the README's tables do
    for p in range(10, 29):
        if abs(value - 2 ** p) / 2 ** p < 0.05:
            return 2 ** p
    return int(value)


def render(spec, grid: str, cells: int, width: int, height: int, rsm: int, method: str, fit: str, device):
    """One raw frame of ``spec`` with ``cells`` wavefront cells per light over ``grid``: (aovs, seconds, renderer)."""
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.raster.views import LightViewSettings
    from cisp_warp.render import Renderer, RenderSettings

    settings = RenderSettings(rsm_size=rsm, method=method, denoiser="none", light_views=LightViewSettings(fit=fit),
                              photons=PhotonSettings(photons=cells, splat="wavefront", wavefront_grid=grid))
    r = Renderer(spec.make(width, height), settings, device=device)
    if spec.prepare is not None:
        spec.prepare(r)
    r.render_frame()  # compiles, fits the views
    t0 = time.perf_counter()
    r.render_frame()
    a = r.aovs(include_rsm=False)
    return a, time.perf_counter() - t0, r


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default="pool", choices=["pool", "sinusoid", "cornell"])
    p.add_argument("--size", default="480x270", help="camera WxH")
    p.add_argument("--rsm-size", type=int, default=1024)
    p.add_argument("--method", default="cisp", choices=["cisp", "sspm"])
    p.add_argument("--light-views", default="camera", choices=["camera", "scene"],
                   help="light views fitted to the camera (the renderer's default) or whole")
    p.add_argument("--counts", default="65k,262k,1M", help="comma-separated cells per light")
    p.add_argument("--reference", default="4M", help="cells per light of both grids' reference maps (not sinusoid)")
    p.add_argument("--device", default=None)
    p.add_argument("--json", default=None, help="write the figures to this file")
    p.add_argument("--save", default=None, help="write the maps (references, every run, the mask) to this .npz")
    p.add_argument("--smoke", action="store_true", help="sinusoid, 64x32, seconds")
    args = p.parse_args(argv)
    if args.smoke:
        args.scene, args.size, args.rsm_size, args.counts, args.reference = "sinusoid", "64x32", 128, "16k", "16k"
        args.light_views = "scene"  # whole views: the sinusoid's long strip cells cross a fitted window's edge
    import warp as wp

    from cisp_warp import metrics as M

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    device = wp.get_device(args.device)
    width, height = (int(v) for v in args.size.lower().split("x"))
    counts = [parse_count(c) for c in args.counts.split(",")]
    spec = scene_specs([args.scene])
    if not spec:
        raise SystemExit(f"scene {args.scene} not available")
    spec = spec[0]
    report = {"scene": args.scene, "width": width, "height": height, "rsm_size": args.rsm_size, "method": args.method,
              "light_views": args.light_views,
              "device": f"{device.alias} ({device.name})", "runs": []}
    if args.scene == "sinusoid":
        a, _, _ = render(spec, "rsm", counts[0], width, height, args.rsm_size, args.method, args.light_views, device)
        ref = analytic_sinusoid_reference({**a, "caustics_stderr": np.zeros_like(a["photon_map"])}, width, height)
        report["reference"] = "analytic ray map"
    else:
        n_ref = parse_count(args.reference)
        maps = {}
        saved = {}
        for g in GRIDS:
            a, sec, _ = render(spec, g, n_ref, width, height, args.rsm_size, args.method, args.light_views, device)
            maps[g] = a["photon_map"].astype(np.float64)
            saved[f"ref_{g}"] = a["photon_map"]
            print(f"reference {g} {n_ref:,} cells: {sec:.1f} s", flush=True)
        ref = {**a, "photon_map": 0.5 * (maps["rsm"] + maps["mesh"]), "caustics_stderr": np.zeros_like(a["photon_map"])}
        mask = M.caustic_mask(ref)
        report["reference"] = f"mean of both grids at {n_ref:,} cells"
        report["reference_grids_differ"] = M.relative_rmse(maps["rsm"], maps["mesh"], mask)
        print(f"the two {n_ref:,}-cell maps differ by {100 * report['reference_grids_differ']:.2f}% (relative RMSE)")
    mask = M.caustic_mask(ref)
    if args.scene == "sinusoid":
        saved = {"ref": ref["photon_map"]}
    saved.update(mask=mask, position=ref["position"], normal=ref["normal"], depth=ref["depth"])
    print(f"{args.scene} {width}x{height}, RSM {args.rsm_size}², {args.method}, light views {args.light_views}, "
          f"one raw frame; caustic mask "
          f"{int(mask.sum())} pixels; relative RMSE against the {report['reference']}")
    print(f"{'cells':>10}" + "".join(f"{g:>12}{'s':>7}" for g in GRIDS) + f"{'mesh n':>8}{'refined':>9}"
          f"{'photons rsm':>13}{'mesh':>11}")
    for n in counts:
        row = {"cells": n}
        line = f"{n:>10,}"
        for g in GRIDS:
            a, sec, r = render(spec, g, n, width, height, args.rsm_size, args.method, args.light_views, device)
            err = M.relative_rmse(a["photon_map"], ref["photon_map"], mask)
            ledger = r.photons.read_ledger()
            row[g] = {"rel_rmse": err, "seconds": sec, "ledger_closure": ledger.closure(),
                      "stored_share": float(ledger["stored"].sum() / max(ledger["sampled"].sum(), 1e-300))}
            if g == "mesh":
                row["mesh_n"] = r.photons.wavefront.grid.n
                row["mesh_refined"] = [list(v) for v in r.photons.wavefront.refined]  # (listed, cut) per light
            row[g]["photons_traced"] = r.photons.wavefront.photons_traced()
            line += f"{100 * err:11.2f}%{sec:7.1f}"
            saved[f"{g}_{n}"] = a["photon_map"]
        refined = sum(c for _, c in row["mesh_refined"])
        print(line + f"{row['mesh_n']:>8}{refined:>9,}{row['rsm']['photons_traced']:>13,}"
              f"{row['mesh']['photons_traced']:>11,}", flush=True)
        report["runs"].append(row)
    if args.save:
        np.savez_compressed(args.save, **saved)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
