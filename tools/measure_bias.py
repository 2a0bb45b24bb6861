#!/usr/bin/env python3
"""A method's own bias: the mean of many raw frames (denoiser ``none``) against the converged reference.

    python tools/measure_bias.py                                   # cisp, Cornell box 192x108, RSM 256², CPU
    python tools/measure_bias.py --scene pool --method sspm --frames 32 --photons 400k
    python tools/measure_bias.py --device cuda:0 --width 1920 --height 1080 --rsm 2048 --photons 2M --frames 256

Every frame draws new random numbers (the frame number seeds them), so the mean of N raw photon maps (the
``photon_map`` AOV, no denoiser) converges to the method's expectation; what is left against the reference
is its bias. The maps are summed on the device (one small kernel a frame: Σ E and Σ Y² per pixel, float64); the
host reads the sums once at the end.

Figures, over the reference's caustic mask (``metrics.caustic_mask``, as ``tools/evaluate.py``):

* ``rel_rmse``: relative RMSE of the mean map against the reference (``metrics.relative_rmse``);
* ``noise``: what of it is still the method's noise: sqrt(mean_M s²/N) / mean_M Y_ref, s² the per-pixel sample
  variance of the frames' luminance; ``bias`` = sqrt(rel_rmse² − noise² − reference noise²) (the part that more
  frames would not remove);
* ``energy``: Σ Y·A over the mask, mean / reference; ``energy_all`` over every pixel;
* ``by_region``: the share of the squared error over the mask of pixels next to a geometric edge (a 4-neighbour
  of ``metrics.geometric_edges``), of pixels where the mean is above and below the reference.

Writes into ``--out``: ``bias_<scene>_<method>_<W>x<H>_rsm<R>.png`` (the mean, the reference, both tone mapped
with the reference's exposure, and the signed relative error (mean − ref) / mean_M Y_ref in red (too bright) and
blue (too dark), full scale at ±``--scale``, the mask's outside dimmed), ``....npz`` (mean, reference, mask,
per-pixel noise) and ``....json`` (the figures). References are accumulated and cached as ``evaluation.py``
does (``--refdir``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tools"))

import warp as wp  # noqa: E402

from cisp_warp.denoise.kernels_svgf import luminance  # noqa: E402


@wp.kernel
def accumulate(photon_map: wp.array(dtype=wp.vec3), sum_e: wp.array(dtype=wp.vec3d),
               sum_y2: wp.array(dtype=wp.float64)):
    """Σ E and Σ Y² per pixel over the frames (float64, one thread a pixel: no atomics)."""
    p = wp.tid()
    e = photon_map[p]
    sum_e[p] = sum_e[p] + wp.vec3d(wp.float64(e[0]), wp.float64(e[1]), wp.float64(e[2]))
    y = wp.float64(luminance(e))
    sum_y2[p] = sum_y2[p] + y * y


def error_image(mean: np.ndarray, ref: np.ndarray, mask: np.ndarray, scale: float, exposure: float) -> np.ndarray:
    """(H, 3W, 3) uint8: the mean and the reference tone mapped, and the signed relative error."""
    from cisp_warp import metrics as M
    from cisp_warp.image_io import tonemap

    y, yr = M.irradiance_y(mean), M.irradiance_y(ref)
    norm = yr[mask].mean() if mask.any() else max(yr.max(), 1e-30)
    rel = np.clip((y - yr) / norm / scale, -1.0, 1.0)
    err = np.ones(y.shape + (3,))
    err[..., 1] -= np.abs(rel)  # white at 0, red when too bright, blue when too dark
    err[..., 0] -= np.where(rel < 0, -rel, 0.0)
    err[..., 2] -= np.where(rel > 0, rel, 0.0)
    err = np.where(mask[..., None], err, 0.35 + 0.3 * err)  # outside the mask: dimmed
    return np.concatenate([tonemap(mean, exposure), tonemap(ref, exposure),
                           (np.clip(err, 0, 1) * 255 + 0.5).astype(np.uint8)], axis=1)


def near_edges(ref: dict) -> np.ndarray:
    from cisp_warp import metrics as M

    e = M.geometric_edges(ref)
    out = e.copy()
    out[1:] |= e[:-1]
    out[:-1] |= e[1:]
    out[:, 1:] |= e[:, :-1]
    out[:, :-1] |= e[:, 1:]
    return out


def figures(mean: np.ndarray, noise_px: np.ndarray, ref: dict, mask: np.ndarray, footprint: np.ndarray) -> dict:
    """The module's figures of a mean map (H, W, 3) with its per-pixel standard error (H, W) against ``ref``."""
    from cisp_warp import metrics as M

    yr = M.irradiance_y(ref["photon_map"])
    y = M.irradiance_y(mean)
    norm = yr[mask].mean()
    rmse = M.relative_rmse(mean, ref["photon_map"], mask)
    noise = float(np.sqrt(np.mean(noise_px[mask] ** 2)) / norm)
    ref_noise = M.reference_noise(ref, mask)
    sq = (y - yr) ** 2
    total = sq[mask].sum()
    edge = near_edges(ref)
    return {
        "rel_rmse": rmse, "noise": noise, "reference_noise": ref_noise,
        "bias": float(math.sqrt(max(rmse ** 2 - noise ** 2 - ref_noise ** 2, 0.0))),
        "energy": M.energy_ratio(mean, ref["photon_map"], footprint, mask),
        "energy_all": M.energy_ratio(mean, ref["photon_map"], footprint),
        "mask_pixels": int(mask.sum()),
        "by_region": {
            "near_edge": float(sq[mask & edge].sum() / total), "near_edge_pixels": float((mask & edge).mean() / mask.mean()),
            "too_bright": float(sq[mask & (y > yr)].sum() / total), "too_dark": float(sq[mask & (y < yr)].sum() / total),
        },
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default="cornell", help="cornell, pool or sinusoid (default cornell)")
    p.add_argument("--method", default="cisp", help="cisp, sspm or caustics_map (default cisp)")
    p.add_argument("--splat", default="point", help="cisp, sspm: point or wavefront (default point)")
    p.add_argument("--width", type=int, default=192, help="image width [pixels] (default 192)")
    p.add_argument("--height", type=int, default=108, help="image height [pixels] (default 108)")
    p.add_argument("--rsm", type=int, default=256, help="RSM edge [texels] (default 256)")
    p.add_argument("--photons", default="200k", help="photons per light and frame (default 200k)")
    p.add_argument("--frames", type=int, default=16, help="frames averaged (default 16)")
    p.add_argument("--seed", type=int, default=0, help="the renderer's seed (default 0)")
    p.add_argument("--thickness", type=float, default=None,
                   help="the depth buffers' absolute surface thickness [m] (default: PhotonSettings')")
    p.add_argument("--no-cascade", action="store_true",
                   help="cisp: the light view only, no camera march (PhotonSettings.cascade off), for comparison")
    p.add_argument("--thickness-rel", type=float, default=None,
                   help="their relative thickness (x depth) (default: PhotonSettings')")
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--out", default="bias", help="output folder (default ./bias)")
    p.add_argument("--refdir", default=None, help="reference cache folder (default OUT/references)")
    p.add_argument("--reference-photons", default="8M", help="photons per light and reference chunk (default 8M)")
    p.add_argument("--reference-pass", default="1M", help="reference photons per pass (default 1M)")
    p.add_argument("--reference-rsm", type=int, default=256,
                   help="the RSM edge the reference is rendered (and cached) with (default 256)")
    p.add_argument("--reference-noise", type=float, default=0.015,
                   help="accumulate the reference until its own relative noise over its mask is at most this")
    p.add_argument("--reference-seconds", type=float, default=600.0,
                   help="rendering time for the reference per call [s] (0: the cache as it is)")
    p.add_argument("--analytic-sinusoid", action="store_true",
                   help="the sinusoid against its analytic ray map (exact) instead of the photon reference")
    p.add_argument("--scale", type=float, default=1.0,
                   help="the error map's full scale, as a fraction of the mask's mean reference (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    args = p.parse_args(argv)

    from cisp_warp.cli import parse_count

    try:
        photons = parse_count(args.photons)
        ref_photons = parse_count(args.reference_photons)
        ref_pass = parse_count(args.reference_pass)
    except Exception as e:  # noqa: BLE001 - one sentence for bad input
        raise SystemExit(f"measure_bias: {e}")
    if args.method not in ("cisp", "sspm", "caustics_map"):
        raise SystemExit(f"measure_bias: unknown method {args.method!r}: cisp, sspm, caustics_map")
    if args.frames < 1 or args.width < 8 or args.height < 8 or args.rsm < 8:
        raise SystemExit("measure_bias: --frames must be at least 1, --width, --height and --rsm at least 8")

    wp.config.log_level = wp.LOG_WARNING
    wp.config.quiet = True
    wp.init()
    import evaluate as EV
    from PIL import Image

    from cisp_warp import evaluation as E
    from cisp_warp import metrics as M
    from cisp_warp.image_io import auto_exposure
    from cisp_warp.render import Renderer

    def say(msg):
        if not args.quiet:
            print(msg, flush=True)

    device = wp.get_device(args.device)
    specs = EV.scene_specs([args.scene])
    if not specs:
        raise SystemExit(f"measure_bias: scene {args.scene!r} is not available")
    spec = specs[0]
    w, h = args.width, args.height
    os.makedirs(args.out, exist_ok=True)
    refdir = args.refdir or os.path.join(args.out, "references")

    t0 = time.perf_counter()

    def progress(k, n):
        if not args.quiet and (k == n or k % max(n // 4, 1) == 0):
            print(f"  reference {k:,}/{n:,}", flush=True)

    rs = E.reference_settings(args.reference_rsm, ref_pass, ref_photons)
    ref, rmeta = E.accumulated_reference(refdir, f"{spec.name}_{w}x{h}", spec.make(w, h), rs, device,
                                         noise=args.reference_noise, seconds=args.reference_seconds,
                                         prepare=spec.prepare, key_extra=spec.key, progress=progress)
    if args.analytic_sinusoid and spec.name == "sinusoid":
        ref = EV.analytic_sinusoid_reference(ref, w, h)
    mask = M.caustic_mask(ref)
    if not mask.any():
        raise SystemExit(f"measure_bias: the reference of {spec.name} at {w}x{h} has no caustic pixels")
    say(f"reference: {rmeta['photons']:,} photons per light ({'cached' if rmeta['cached'] else 'rendered'}), "
        f"mask {int(mask.sum())} pixels, own noise {M.reference_noise(ref, mask):.4f}")

    cfg = E.Config(args.method, photons, "none", args.splat)
    from dataclasses import replace

    settings = E.render_settings(cfg, args.rsm)
    ps = replace(settings.photons, seed=args.seed)
    if args.thickness is not None:
        ps = replace(ps, thickness=args.thickness)
    if args.thickness_rel is not None:
        ps = replace(ps, thickness_rel=args.thickness_rel)
    if args.no_cascade:
        ps = replace(ps, cascade=False)
    settings = replace(settings, photons=ps)
    r = Renderer(spec.make(w, h), settings, device=device)
    if spec.prepare is not None:
        spec.prepare(r)
    n = w * h
    sum_e = wp.zeros(n, dtype=wp.vec3d, device=device)
    sum_y2 = wp.zeros(n, dtype=wp.float64, device=device)
    t1 = time.perf_counter()
    for f in range(args.frames):
        r.render_frame()
        wp.launch(accumulate, dim=n, inputs=[r.photons.photon_map, sum_e, sum_y2], device=device)
        if not args.quiet and (f + 1 == args.frames or (f + 1) & f == 0):  # 1, 2, 4, ... and the last
            wp.synchronize_device(device)
            say(f"  frame {f + 1}/{args.frames} ({time.perf_counter() - t1:.1f} s)")
    k = float(args.frames)
    mean = (sum_e.numpy() / k).reshape(h, w, 3)
    m2 = (sum_y2.numpy() / k).reshape(h, w)
    y = M.irradiance_y(mean)
    var = np.maximum(m2 - y ** 2, 0.0) * (k / max(k - 1.0, 1.0))
    noise_px = np.sqrt(var / k)
    footprint = M.pixel_footprint(ref, r.view)
    fig = figures(mean, noise_px, ref, mask, footprint)
    ledger = r.photons.read_ledger()
    meta = {"scene": spec.name, "method": args.method, "splat": args.splat, "width": w, "height": h, "rsm": args.rsm,
            "photons": photons, "frames": args.frames, "seed": args.seed, "thickness": ps.thickness,
            "thickness_rel": ps.thickness_rel, "cascade": ps.cascade, "device": E.device_name(device),
            "reference_photons": rmeta["photons"], "ledger_closure": float(ledger.closure()),
            "seconds": time.perf_counter() - t0, "source": E.source_version(), **fig}
    stem = os.path.join(args.out, f"bias_{spec.name}_{args.method}_{w}x{h}_rsm{args.rsm}")
    exposure = auto_exposure(ref["photon_map"])
    Image.fromarray(error_image(mean, ref["photon_map"], mask, args.scale, exposure)).save(stem + ".png")
    np.savez_compressed(stem + ".npz", mean=mean.astype(np.float32), reference=ref["photon_map"], mask=mask,
                        noise=noise_px.astype(np.float32), depth=ref["depth"], position=ref["position"],
                        normal=ref["normal"])
    with open(stem + ".json", "w") as fh:
        json.dump(meta, fh, indent=1)
    b = fig["by_region"]
    print(f"{spec.name} {args.method} {w}x{h} RSM {args.rsm}² {photons:,} photons x {args.frames} frames: "
          f"rel RMSE {fig['rel_rmse']:.4f} (noise {fig['noise']:.4f}, reference {fig['reference_noise']:.4f}, "
          f"bias {fig['bias']:.4f}); energy over mask {fig['energy']:.3f}, all {fig['energy_all']:.3f}; "
          f"squared error near edges {b['near_edge']:.2f} ({b['near_edge_pixels']:.2f} of the pixels), "
          f"too bright {b['too_bright']:.2f}, too dark {b['too_dark']:.2f}")
    print(f"wrote {stem}.png, .npz, .json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
