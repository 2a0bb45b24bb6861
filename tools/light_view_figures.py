"""Figures for light views fitted to the camera and exact per-photon geometry (issue 13).

``store``: per scene, one frame of ``cisp`` with the lights' whole views (``--light-views scene``) and
with views fitted to the camera: where the sampled power went, and the share of the *traced* power
(the photon budget: sampled minus what the fit skipped) that ends stored in a visible pixel. Photons
of one view carry equal power, so that share is the share of traced photons that land in view.
Writes ``photon_map`` crops (PNG, one exposure per scene) and ``store.md``.

``converged``: the wavy-water close-up (``analytic.wavy_water``) at RSM sizes, whole and fitted views,
against a converged ``reference`` (relative RMSE of the 3×3-blurred raw photon map, and the reference's
own noise from two halves). Writes ``converged.md`` and crops.

    python3 tools/light_view_figures.py store --out fig/ --width 320 --height 180 --photons 1M
    python3 tools/light_view_figures.py converged --out fig/ --size 96 --photons 16M --reference 64M
    python3 tools/light_view_figures.py store --smoke --out /tmp/fig   # seconds, what the tests run
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def parse_count(text: str) -> int:
    t = text.strip().lower()
    scale = {"k": 1_000, "m": 1_000_000}.get(t[-1:], 1)
    return int(float(t[:-1] if scale > 1 else t) * scale)


def save_png(path: str, irradiance: np.ndarray, white: float) -> None:
    from PIL import Image

    v = np.clip(irradiance / max(white, 1e-12), 0.0, 1.0) ** (1.0 / 2.2)
    img = Image.fromarray((v * 255 + 0.5).astype(np.uint8))
    scale = max(1, 256 // max(img.size))
    img.resize((img.size[0] * scale, img.size[1] * scale), Image.NEAREST).save(path)


def scenes(width: int, height: int):
    """(name, scene, water time [s] or None) of the shipped scenes and the close-ups."""
    from cisp_warp import analytic
    from cisp_warp.scene import Camera
    from cisp_warp.usd import load_usd

    cornell = load_usd(os.path.join(ROOT, "scenes_usd", "cornell_flooded.usda"), width=width, height=height)
    pool = load_usd(os.path.join(ROOT, "scenes_usd", "pool.usda"), width=width, height=height)
    closeup = load_usd(os.path.join(ROOT, "scenes_usd", "pool.usda"), width=width, height=height)
    closeup.camera = Camera.look_at((1.5, 0.4, 0.9), (1.5, -1.2, 0.4), fov_y=math.radians(35.0), width=width,
                                    height=height, near=0.05, far=40.0)
    wavy = analytic.wavy_water(width=height, height=height)
    return [("cornell_flooded", cornell, 0.0), ("pool", pool, 2.0), ("pool_floor_closeup", closeup, 2.0),
            ("wavy_closeup", wavy, None)]


def renderer(scene, rsm: int, photons: int, fit: str, method: str = "cisp", device="cpu", seed: int = 1,
             reference_photons: int = 0, water_time: float | None = None):
    from cisp_warp.animation import WaterSimulation
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.raster import LightViewSettings
    from cisp_warp.render import Renderer, RenderSettings

    r = Renderer(scene, RenderSettings(rsm_size=rsm, method=method, denoiser="none",
                                       light_views=LightViewSettings(fit=fit),
                                       photons=PhotonSettings(photons=photons, seed=seed,
                                                              reference_photons=reference_photons)), device=device)
    if water_time is not None:
        sim = WaterSimulation(r.gpu)
        if len(sim):
            sim.update(water_time)
            r.gpu.refit()
    return r


def store(args) -> None:
    rows = ["| scene | light views | traced / sampled | outside_fitted_view | stored / sampled | stored / traced | "
            "photons in view × | frame [s] | closure |", "|---|---|---|---|---|---|---|---|---|"]
    for name, scene, t in scenes(args.width, args.height):
        maps, share = {}, {}
        for fit in ("scene", "camera"):
            r = renderer(scene, args.rsm_size, args.photons, fit, device=args.device, water_time=t)
            r.render_frame()  # compiles, and fits the views
            t0 = time.perf_counter()
            r.render_frame()
            seconds = time.perf_counter() - t0
            led = r.photons.read_ledger()
            d = led.as_dict()
            traced = d["sampled"] - d["outside_fitted_view"]
            share[fit] = d["stored"] / traced if traced > 0 else 0.0
            gain = share[fit] / share["scene"] if share.get("scene") else 1.0
            rows.append(f"| {name} | {fit} | {traced / d['sampled']:.4f} | {d['outside_fitted_view'] / d['sampled']:.4f} | "
                        f"{d['stored'] / d['sampled']:.4f} | {share[fit]:.4f} | {gain:.1f} | {seconds:.2f} | {led.closure():.1e} |")
            maps[fit] = r.photons.photon_map.numpy().reshape(r.gbuffer.height, r.gbuffer.width, 3)[..., 0]
            print(rows[-1], flush=True)
        white = float(np.percentile(maps["camera"][maps["camera"] > 0], 99)) if (maps["camera"] > 0).any() else 1.0
        for fit, m in maps.items():
            save_png(os.path.join(args.out, f"{name}_photon_map_{fit}.png"), m, white)
    head = (f"{args.device}, {args.width}x{args.height}, RSM {args.rsm_size}², {args.photons:,} photons per light, "
            f"one frame of cisp (after one to fit), raw photon map\n\n")
    with open(os.path.join(args.out, "store.md"), "w") as f:
        f.write(head + "\n".join(rows) + "\n")
    print(head + "\n".join(rows))


def rel_rmse(a: np.ndarray, b: np.ndarray) -> float:
    from scipy.ndimage import uniform_filter

    a, b = uniform_filter(a.astype(np.float64), 3), uniform_filter(b.astype(np.float64), 3)
    return float(np.sqrt(((a - b) ** 2).mean()) / b.mean())


def converged(args) -> None:
    from cisp_warp import analytic

    def scene():
        return analytic.wavy_water(width=args.size, height=args.size)

    refs = []
    for seed in (11, 12):  # two independent halves: their difference measures the reference's own noise
        r = renderer(scene(), 256, min(args.reference // 2, 1 << 22), "scene", method="reference", device=args.device,
                     seed=seed, reference_photons=args.reference // 2)
        r.render_frame()
        refs.append(r.photons.photon_map.numpy().reshape(args.size, args.size, 3)[..., 0].astype(np.float64))
    ref = 0.5 * (refs[0] + refs[1])
    ref_noise = 0.5 * rel_rmse(refs[0], refs[1])  # of the mean of the halves: half the halves' difference
    rows = [f"reference: {args.reference:,} photons, its own relative noise (3×3 blur) {ref_noise:.4f}\n",
            "| method | light views | RSM | relative RMSE (3×3 blur) | energy ratio | frame [s] |", "|---|---|---|---|---|---|"]
    white = float(np.percentile(ref, 99))
    save_png(os.path.join(args.out, "wavy_reference.png"), ref, white)
    for method in args.methods.split(","):
        for fit in ("scene", "camera"):
            for rsm in (int(v) for v in args.rsm_sizes.split(",")):
                r = renderer(scene(), rsm, args.photons, fit, method=method, device=args.device, seed=3)
                t0 = time.perf_counter()
                r.render_frame()
                seconds = time.perf_counter() - t0
                m = r.photons.photon_map.numpy().reshape(args.size, args.size, 3)[..., 0]
                rows.append(f"| {method} | {fit} | {rsm}² | {rel_rmse(m, ref):.4f} | {m.mean() / ref.mean():.4f} | {seconds:.1f} |")
                print(rows[-1], flush=True)
                save_png(os.path.join(args.out, f"wavy_{method}_{fit}_{rsm}.png"), m, white)
    head = f"{args.device}, wavy_water close-up {args.size}x{args.size}, {args.photons:,} photons in one frame, raw photon map\n\n"
    with open(os.path.join(args.out, "converged.md"), "w") as f:
        f.write(head + "\n".join(rows) + "\n")
    print(head + "\n".join(rows))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("part", choices=["store", "converged"])
    p.add_argument("--out", default="light_view_figures")
    p.add_argument("--device", default="cpu")
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--height", type=int, default=180)
    p.add_argument("--rsm-size", type=int, default=1024)
    p.add_argument("--photons", type=parse_count, default=parse_count("1M"))
    p.add_argument("--size", type=int, default=96, help="converged: image edge [pixels]")
    p.add_argument("--rsm-sizes", default="1024,4096", help="converged: RSM edges to compare")
    p.add_argument("--methods", default="cisp,sspm", help="converged: methods to compare")
    p.add_argument("--reference", type=parse_count, default=parse_count("64M"), help="converged: reference photons")
    p.add_argument("--smoke", action="store_true", help="tiny sizes: seconds, for the test suite")
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.rsm_size, args.photons = 48, 27, 64, 20_000
        args.size, args.rsm_sizes, args.reference, args.methods = 24, "32,64", 200_000, "cisp"
    os.makedirs(args.out, exist_ok=True)
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.config.quiet = True
    (store if args.part == "store" else converged)(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
