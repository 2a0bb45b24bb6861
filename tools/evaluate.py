#!/usr/bin/env python3
"""Speed against accuracy: every method × photon count × denoiser on every scene, measured against the
converged reference, charted as a Pareto plot.

    python tools/evaluate.py --preset small --out results/          # CPU, 160x90
    python tools/evaluate.py --preset small --out results/ --all    # and the stability suite (tools/stability.py)
    python tools/evaluate.py --preset full --device cuda:0 --out results_cuda/ --references-only  # references
    python tools/evaluate.py --preset full --device cuda:0 --out results_cuda/ --reference-seconds 0
    python tools/evaluate.py --smoke --out /tmp/eval                # seconds: what the tests run
    python tools/evaluate.py --scenes sinusoid,pool --methods cisp --splats point,wavefront --denoisers none
                                                                    # point photons against wavefront splatting

Denoisers (``--denoisers``): ``caustic`` (the renderer's default), ``svgf`` (the paper's), ``none`` (raw), and
for caustics_map ``own`` (seed 004's filters); cisp_warp/evaluation.py says what each means per method. The
scenes are still: the figures are of the last frames after 16 (the denoisers' steady state).

References accumulate independent reference frames until their own relative noise over their caustic mask is
at most ``--reference-noise`` (2% by default), within ``--reference-seconds`` of rendering per scene and call;
the sums are cached in OUT/references, so a first call can build them (``--references-only``) and a second
use them as they are (``--reference-seconds 0``).

Per run (scene, method, photons, denoiser): median stage times [ms] over the timed frames after warm-up
(CUDA events on a GPU, synchronised wall clock on the CPU; cisp_warp.timing.StageTimer), and, averaged over
the last frames, against the reference's photon map: the relative RMSE of the caustic irradiance over the
pixels where the reference shows caustics (``caustics``, and the raw ``photon_map``), the energy ratio, and
LDR-FLIP of the tone-mapped final image (of the last frame, at the preset's ``flip_photons`` counts). The
definitions are in cisp_warp/metrics.py. References are rendered once per scene and cached under --out.

Writes OUT/results.csv, OUT/results.json (device, Warp version, preset, date, definitions) and
OUT/pareto.png (relative RMSE and FLIP against frame time, log axes, one colour per method, one line style
per denoiser, one column per scene). FLIP needs ``flip-evaluator`` and the chart ``matplotlib``:
``pip install -e .[eval]``; without them those columns are NaN and the chart is skipped, with a note.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import hashlib
import json
import math
import os
import sys
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

CORNELL = os.path.join(ROOT, "scenes_usd", "cornell_flooded.usda")
POOL = os.path.join(ROOT, "scenes_usd", "pool.usda")
POOL_TIME_CODE = 48.0  #: 2 s into the pool's animation: simulated waves, the camera mid-dolly

#: photons: per light per frame; reference: photons per light and chunk (0 = the renderer's default: 1e8 on
#: CUDA), in passes of ``reference_pass``, chunks accumulated to ``reference_noise`` within ``reference_seconds``
#: per scene; frames: warm-up (untimed), timed, and the last ``measured`` of the timed ones compared with the
#: reference (static scenes: warmup + timed = 16, the denoisers' steady state); FLIP at ``flip_photons`` only
#: (None: every count), on the last frame
PRESETS = {
    "smoke": dict(width=64, height=36, rsm_size=64, photons=[4_000, 16_000], warmup=2, timed=2, measured=1,
                  reference=200_000, reference_pass=100_000, reference_noise=0.05, reference_seconds=60.0,
                  flip_photons=None, scenes=["sinusoid"]),
    "small": dict(width=160, height=90, rsm_size=256, photons=[31_250, 62_500, 125_000, 250_000, 500_000],
                  warmup=12, timed=4, measured=2, reference=8_000_000, reference_pass=1_000_000,
                  reference_noise=0.02, reference_seconds=600.0, flip_photons=None,
                  scenes=["cornell", "pool", "sinusoid"]),
    "full": dict(width=1920, height=1080, rsm_size=2048, photons=[250_000, 1_000_000, 2_000_000, 8_000_000],
                 warmup=12, timed=4, measured=2, reference=0, reference_pass=4_000_000, reference_noise=0.02,
                 reference_seconds=120.0, flip_photons=[2_000_000], scenes=["cornell", "pool", "sinusoid"]),
}
DENOISER_STYLES = {"caustic": "-", "svgf": "--", "none": ":", "own": "-."}


@dataclass
class SceneSpec:
    """How to build one evaluation scene at a resolution, and what to do to a renderer before its frames."""

    name: str
    make: Callable[[int, int], object]
    prepare: Callable[[object], None] | None = None
    key: str = ""  #: what the scene digest does not see (a file's simulation parameters, a time code)


def file_digest(path: str) -> str:
    with open(path, "rb") as f:
        return hashlib.blake2b(f.read(), digest_size=8).hexdigest()


def run_key(r: dict) -> tuple:
    """What a row of results.json measures: scene, method, splat, grid, photons, denoiser (--merge replaces by it)."""
    return (r["scene"], r["method"], r.get("splat", "point"), r.get("wavefront_grid"), r["photons"], r["denoiser"])


def scene_specs(names: list[str]) -> list[SceneSpec]:
    from cisp_warp import analytic
    from cisp_warp.usd import load_usd

    specs = []
    for name in names:
        if name == "cornell":
            specs.append(SceneSpec("cornell", lambda w, h: load_usd(CORNELL, width=w, height=h)))
        elif name == "pool":
            if not os.path.exists(POOL):
                print(f"note: {os.path.relpath(POOL, ROOT)} not found; the pool is left out", file=sys.stderr)
                continue
            from cisp_warp.animation import Animation

            specs.append(SceneSpec("pool", lambda w, h: load_usd(POOL, width=w, height=h),
                                   lambda r: Animation(r, POOL).set_time_code(POOL_TIME_CODE),
                                   f"{file_digest(POOL)}@{POOL_TIME_CODE}"))
        elif name == "sinusoid":
            specs.append(SceneSpec("sinusoid", lambda w, h: analytic.sinusoidal_water(w, h)))
        else:
            raise SystemExit(f"unknown scene {name!r}: cornell, pool, sinusoid")
    return specs


def analytic_sinusoid_reference(ref: dict, width: int, height: int) -> dict:
    """The sinusoid's exact floor irradiance (the analytic refraction ray map, binned per pixel column) in place
    of the photon reference's map, its standard error zero: errors are then measured against the truth, not
    against a reference whose own noise (19% at 1920x1080 from 1e8 photons) would hide them."""
    from cisp_warp import analytic

    profile = analytic.sinusoidal_answer(width, height, samples=max(2_000_001, 4000 * width + 1))
    e = np.where(ref["depth"][..., None] > 0, profile[None, :, None], 0.0).astype(np.float32)
    return {**ref, "photon_map": np.broadcast_to(e, ref["photon_map"].shape).copy(),
            "caustics_stderr": np.zeros_like(ref["caustics_stderr"])}


def measure(shots: list[dict], ref: dict, mask: np.ndarray, footprint: np.ndarray, flip: bool) -> dict:
    """Figures of the measured frames against the reference, each the mean over the frames; FLIP (when
    ``flip``) of the last frame."""
    from cisp_warp import metrics as M

    rows = []
    for a in shots:
        rows.append({
            "rel_rmse": M.relative_rmse(a["caustics"], ref["photon_map"], mask),
            "rel_rmse_raw": M.relative_rmse(a["photon_map"], ref["photon_map"], mask),
            "energy_ratio": M.energy_ratio(a["caustics"], ref["photon_map"], footprint),
            "energy_ratio_raw": M.energy_ratio(a["photon_map"], ref["photon_map"], footprint),
            "finite": bool(all(np.isfinite(v).all() for v in a.values() if v.dtype.kind == "f")),
        })
    out = {k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k != "finite"}
    out["flip"] = M.flip_ldr(shots[-1]["final"], ref["final"]) if flip else math.nan
    out["finite"] = all(r["finite"] for r in rows)
    return out


def pareto_chart(rows: list[dict], path: str, title: str) -> None:
    """Relative RMSE (top) and FLIP (bottom) against frame time, log axes, one column per scene."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    methods = list(dict.fromkeys(curve_name(r) for r in rows))
    denoisers = list(dict.fromkeys(r["denoiser"] for r in rows))
    colours = {m: c for m, c in zip(methods, ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple",
                                              "tab:brown", "tab:pink"))}
    have_flip = any(np.isfinite(r["flip"]) for r in rows)
    metrics = [("rel_rmse", "relative RMSE of caustic irradiance")] + ([("flip", "LDR-FLIP of final image")]
                                                                          if have_flip else [])
    fig, axes = plt.subplots(len(metrics), len(scenes), figsize=(4.2 * len(scenes), 3.4 * len(metrics)),
                             squeeze=False)
    for j, scene in enumerate(scenes):
        for i, (key, label) in enumerate(metrics):
            ax = axes[i][j]
            for m in methods:
                for den in denoisers:
                    pts = sorted((r["photons"], r["frame_ms"], r[key]) for r in rows if r["scene"] == scene
                                 and curve_name(r) == m and r["denoiser"] == den and np.isfinite(r[key]))
                    if not pts:
                        continue
                    _, x, y = zip(*pts)  # joined in photon order
                    ax.plot(x, y, DENOISER_STYLES.get(den, "-"), marker="o", ms=3.5, color=colours[m],
                            label=f"{m} {den}")
            floor_key = {"rel_rmse": "reference_noise", "flip": "reference_flip"}[key]
            floor = [r[floor_key] for r in rows if r["scene"] == scene]
            if floor and np.isfinite(floor[0]) and floor[0] > 0:
                ax.axhline(floor[0], color="grey", lw=0.8, ls=":", label="reference's own noise")
            ax.set_xscale("log")
            ax.set_yscale("log")
            for axis in (ax.xaxis, ax.yaxis):  # 1-2-5 ticks labelled in plain numbers
                axis.set_major_locator(matplotlib.ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
                axis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
                axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            ax.grid(True, which="both", lw=0.3, alpha=0.5)
            ax.set_xlabel("frame time [ms]")
            if j == 0:
                ax.set_ylabel(label)
            if i == 0:
                ax.set_title(scene)
    axes[0][-1].legend(fontsize=7, loc="best")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def curve_name(row: dict) -> str:
    """A run's curve: its method, and its splat when not points (rows from before splats count as points)."""
    splat = row.get("splat", "point")
    if splat == "point":
        return row["method"]
    return f"{row['method']} {splat}" + (" mesh" if row.get("wavefront_grid", "rsm") == "mesh" else "")


def chart_title(meta: dict) -> str:
    counts = sorted({r["photons"] for r in meta["runs"]})
    c = meta["settings"]
    return (f"{meta['device']} · Warp {meta['warp']} · {c['width']}x{c['height']}, RSM {c['rsm_size']}² · preset "
            f"{meta['preset']} · {counts[0]:,} to {counts[-1]:,} photons per frame along each curve")


FIELDS = ["scene", "method", "splat", "wavefront_grid", "photons", "denoiser", "width", "height", "frame_ms", "raster_ms", "direct_ms",
          "trace_ms", "denoise_ms", "shade_ms", "rel_rmse", "rel_rmse_raw", "energy_ratio", "energy_ratio_raw",
          "flip", "reference_noise", "reference_flip", "mask_pixels", "stored_share", "ledger_closure", "finite"]


def print_table(rows: list[dict]) -> None:
    print(f"{'scene':<9}{'method':<18}{'photons':>10} {'denoiser':<9}{'ms':>9}{'relRMSE':>9}{'raw':>8}"
          f"{'energy':>8}{'FLIP':>8}")
    for r in rows:
        print(f"{r['scene']:<9}{curve_name(r):<18}{r['photons']:>10,} {r['denoiser']:<9}"
              f"{r['frame_ms']:9.1f}{r['rel_rmse']:9.3f}{r['rel_rmse_raw']:8.3f}{r['energy_ratio']:8.3f}"
              f"{r['flip']:8.3f}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", choices=sorted(PRESETS), default="small",
                   help="small: CPU-sized (160x90); full: 1920x1080 for a GPU; smoke: seconds")
    p.add_argument("--smoke", action="store_true", help="same as --preset smoke")
    p.add_argument("--out", default="results", help="output folder; references are cached in OUT/references")
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--scenes", default=None, help="comma-separated subset of cornell,pool,sinusoid")
    p.add_argument("--methods", default="cisp,sspm,caustics_map", help="comma-separated methods")
    p.add_argument("--splats", default="point",
                   help="comma-separated photon stores for cisp and sspm: point, wavefront (photons on an RSM grid, "
                   "--photons then counts grid cells per light); one curve per method and splat")
    p.add_argument("--wavefront-grids", default="rsm",
                   help="comma-separated grids of the wavefront splat: rsm (cells over the RSM's texels), mesh (over "
                   "the water mesh's triangles); one curve each")
    p.add_argument("--denoisers", default="caustic,svgf,none,own",
                   help="comma-separated denoisers: caustic, svgf, none, own (caustics_map's seed-004 filters)")
    p.add_argument("--reference-noise", type=float, default=None,
                   help="accumulate references until their own relative noise over the caustic mask is at most this "
                   "(default: the preset's, 0.02)")
    p.add_argument("--reference-seconds", type=float, default=None,
                   help="rendering time per reference and call [s] (0: use the cached references as they are)")
    p.add_argument("--references-only", action="store_true", help="build or extend the references, then stop")
    p.add_argument("--photons", default=None, help="comma-separated photon counts (500k, 1M, ...) instead of the preset's")
    p.add_argument("--width", type=int, default=None, help="override the preset's image width [pixels]")
    p.add_argument("--height", type=int, default=None, help="override the preset's image height [pixels]")
    p.add_argument("--analytic-sinusoid", action="store_true",
                   help="measure the sinusoid's caustic against its analytic ray map (exact) instead of the photon "
                   "reference (FLIP still compares with the reference's final image)")
    p.add_argument("--no-flip", action="store_true", help="skip FLIP (it is the slowest figure at full size)")
    p.add_argument("--merge", action="store_true",
                   help="keep the rows already in OUT/results.json (same preset, device and size) that this call does "
                   "not measure again (another scene, method, splat or grid), so that a long preset can run in parts")
    p.add_argument("--replot", action="store_true", help="only redraw OUT/pareto.png from OUT/results.json")
    p.add_argument("--all", action="store_true", help="then run tools/stability.py with the same preset, device and out")
    args = p.parse_args(argv)
    if args.smoke:
        args.preset = "smoke"
    cfg = dict(PRESETS[args.preset])
    if args.width:
        cfg["width"] = args.width
    if args.height:
        cfg["height"] = args.height

    if args.replot:
        with open(os.path.join(args.out, "results.json")) as f:
            data = json.load(f)
        pareto_chart(data["runs"], os.path.join(args.out, "pareto.png"), chart_title(data))
        print(f"wrote {args.out}/pareto.png")
        return 0

    import warp as wp

    wp.config.log_level = wp.LOG_WARNING  # no init banner or module-load lines
    wp.init()
    from tqdm import tqdm

    from cisp_warp import evaluation as E
    from cisp_warp import metrics as M
    from cisp_warp.cli import parse_count
    from cisp_warp.render import Renderer

    device = wp.get_device(args.device)
    dev_name = E.device_name(device)
    if args.photons:
        cfg["photons"] = [parse_count(c) for c in args.photons.split(",")]
    methods = args.methods.split(",")
    specs = scene_specs(args.scenes.split(",") if args.scenes else cfg["scenes"])
    flip = not args.no_flip and M.flip_available()
    if not args.no_flip and not flip:
        print("note: flip-evaluator is not installed (pip install -e .[eval]): FLIP is left out", file=sys.stderr)
    os.makedirs(args.out, exist_ok=True)
    cache = os.path.join(args.out, "references")
    w, h, rsm = cfg["width"], cfg["height"], cfg["rsm_size"]
    denoisers = args.denoisers.split(",")
    for d in denoisers:
        if d not in E.DENOISERS:
            raise SystemExit(f"unknown denoiser {d!r}: {', '.join(E.DENOISERS)}")
    splats = args.splats.split(",")
    for sp in splats:
        if sp not in ("point", "wavefront"):
            raise SystemExit(f"unknown splat {sp!r}: point, wavefront")
    grids = args.wavefront_grids.split(",")
    for g in grids:
        if g not in ("rsm", "mesh"):
            raise SystemExit(f"unknown wavefront grid {g!r}: rsm, mesh")
    configs = [E.Config(m, n, d, sp, g) for m in methods for sp in (splats if m in ("cisp", "sspm") else ["point"])
               for g in (grids if sp == "wavefront" else ["rsm"])
               for d in denoisers if E.applicable(m, d) for n in cfg["photons"]]
    noise_target = args.reference_noise if args.reference_noise is not None else cfg["reference_noise"]
    ref_seconds = args.reference_seconds if args.reference_seconds is not None else cfg["reference_seconds"]
    flip_counts = cfg["flip_photons"]
    t_start = time.perf_counter()
    rows, references = [], {}
    for spec in specs:
        bar = tqdm(total=1, desc=f"{spec.name}: reference", unit="pass", leave=False)

        def progress(k, n, bar=bar):
            bar.total = n
            bar.n = k
            bar.refresh()

        settings = E.reference_settings(rsm, cfg["reference_pass"], cfg["reference"])
        ref, meta = E.accumulated_reference(cache, f"{spec.name}_{w}x{h}", spec.make(w, h), settings, device,
                                            noise=noise_target, seconds=ref_seconds, prepare=spec.prepare,
                                            key_extra=spec.key, progress=progress)
        bar.close()
        flip_floor = math.nan
        if flip and "final_halves" in ref:  # FLIP between the even and the odd chunks: what FLIP sees of its noise
            flip_floor = M.flip_ldr(ref["final_halves"][0], ref["final_halves"][1])
        if args.analytic_sinusoid and spec.name == "sinusoid":
            ref = analytic_sinusoid_reference(ref, w, h)
            meta["analytic"] = True
        mask = M.caustic_mask(ref)
        meta.update(mask_pixels=int(mask.sum()), reference_noise=M.reference_noise(ref, mask),
                    reference_flip=flip_floor)
        references[spec.name] = meta
        took = "cached" if meta["cached"] else f"{meta['seconds']:.1f} s"
        tqdm.write(f"{spec.name}: reference {meta['photons']:,} photons per light in {meta['chunks']} chunks ({took}), "
                   f"caustic mask {meta['mask_pixels']} pixels, its own relative noise {meta['reference_noise']:.4f}"
                   f" (target {noise_target})")
        if args.references_only:
            continue
        footprint = None
        for cfg_run in tqdm(configs, desc=spec.name, unit="run"):
            r = Renderer(spec.make(w, h), E.render_settings(cfg_run, rsm), device=device)
            if spec.prepare is not None:
                spec.prepare(r)
            timing, shots = E.run_frames(r, cfg["warmup"], cfg["timed"], cfg["measured"])
            if footprint is None:
                footprint = M.pixel_footprint(ref, r.view)
            fig = measure(shots, ref, mask, footprint, flip and (flip_counts is None or cfg_run.photons in flip_counts))
            ledger = r.photons.read_ledger()
            s = timing.stages
            rows.append({"scene": spec.name, "method": cfg_run.method, "splat": cfg_run.splat,
                         "wavefront_grid": cfg_run.wavefront_grid, "photons": cfg_run.photons,
                         "denoiser": cfg_run.denoiser, "width": w, "height": h, "frame_ms": timing.frame,
                         "raster_ms": s.get("raster", 0.0), "direct_ms": s.get("direct", 0.0),
                         "trace_ms": s.get("trace+store", 0.0), "denoise_ms": s.get("denoise", 0.0),
                         "shade_ms": s.get("shade", 0.0), **fig, "reference_noise": meta["reference_noise"],
                         "reference_flip": meta["reference_flip"],
                         "mask_pixels": meta["mask_pixels"],
                         "stored_share": float(ledger["stored"].sum() / max(ledger["sampled"].sum(), 1e-300)),
                         "ledger_closure": float(ledger.closure())})
    wall = time.perf_counter() - t_start
    if args.references_only:
        print(f"references in {args.out}/references ({wall:.0f} s): " + "; ".join(
            f"{k} {v['photons']:,} photons, noise {v['reference_noise']:.4f}" for k, v in references.items()))
        return 0
    previous = os.path.join(args.out, "results.json")
    if args.merge and os.path.exists(previous):
        with open(previous) as f:
            old = json.load(f)
        if (old["device"], old["preset"]) == (dev_name, args.preset):
            done = {run_key(r) for r in rows}
            kept = [r for r in old["runs"] if run_key(r) not in done and (r["width"], r["height"]) == (w, h)]
            rows = [{"splat": "point", **r} for r in kept] + rows
            references = {**{k: v for k, v in old["references"].items() if k not in done}, **references}
            wall += old.get("wall_seconds", 0.0)
        else:
            print(f"note: {previous} is from another device or preset; not merged", file=sys.stderr)

    with open(os.path.join(args.out, "results.csv"), "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=FIELDS)
        wr.writeheader()
        for r in rows:
            wr.writerow({k: r[k] for k in FIELDS})
    meta = {
        "device": dev_name, "warp": wp.config.version, "source": E.source_version(), "preset": args.preset,
        "settings": cfg,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "command": " ".join([os.path.relpath(sys.argv[0], ROOT)] + sys.argv[1:]), "wall_seconds": wall,
        "definitions": {
            "caustic_mask": f"reference luminance > {M.MASK_FRACTION} x its 99th percentile and > "
                            f"{M.MASK_SIGMAS} x its standard error (caustics_stderr), on a surface",
            "rel_rmse": "sqrt(mean over mask of (Y - Y_ref)^2) / mean over mask of Y_ref; Y = Rec.709 luminance "
                        "of the irradiance [W/m2]; rel_rmse of 'caustics' (after the denoiser), rel_rmse_raw of "
                        "'photon_map'",
            "energy_ratio": "sum over camera pixels of Y * exact pixel footprint [W], method / reference",
            "flip": "mean LDR-FLIP (flip-evaluator, 67 ppd) of final vs the reference's final, both tone mapped "
                    "by cisp_warp.image_io.tonemap with the reference's automatic exposure",
            "frame_ms": "median over timed frames of the sum of the stages raster, direct, trace+store, denoise, "
                        "shade (after warm-up; synchronised)",
            "reference_noise": "the reference's own relative standard error over the mask (0 for the sinusoid with "
                               "--analytic-sinusoid: its reference is then the analytic ray map's irradiance)",
            "reference_flip": "LDR-FLIP between the reference's even and odd chunks (each half of its photons): "
                              "above FLIP's noise floor of the whole reference",
            "denoiser": "caustic (default: reactive accumulation of the raw photon map + variance-sized "
                        "à-trous), svgf, none (raw); own: caustics_map's seed-004 light-space gather and 4-frame mean",
            "reference_noise_target": noise_target,
        },
        "flip": "LDR-FLIP" if flip else None, "references": references, "runs": rows,
    }
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump(meta, f, indent=1)
    print(f"device: {dev_name}; Warp {wp.config.version}; preset {args.preset} ({w}x{h}, RSM {rsm}²); "
          f"{wall:.0f} s")
    print_table(rows)
    try:
        pareto_chart(rows, os.path.join(args.out, "pareto.png"), chart_title(meta))
    except ImportError:
        print("note: matplotlib is not installed (pip install -e .[eval]): no pareto.png", file=sys.stderr)
    print(f"wrote {args.out}/results.csv, results.json" + (", pareto.png" if os.path.exists(
        os.path.join(args.out, "pareto.png")) else ""))
    if args.all:
        import stability

        return stability.main(["--preset", args.preset, "--out", args.out]
                              + (["--device", args.device] if args.device else []))
    return 0


if __name__ == "__main__":
    sys.exit(main())
