#!/usr/bin/env python3
"""Stability suite: the cases where screen-space caustics fail (cisp_warp/stability_scenes.py), for every
method, measured against the reference frame by frame.

    python tools/stability.py --preset small --out results/     # CPU, 96x72, every case
    python tools/stability.py --preset full --device cuda:0 --out results_cuda/   # 960x540, the animated cases
    python tools/stability.py --smoke --out /tmp/stability       # seconds: what the tests run

Per case, method and denoiser (``--denoisers``: caustic, the default, svgf, none, and own for caustics_map;
cisp_warp/evaluation.py), over the last frames of a sequence (definitions in cisp_warp/metrics.py):

* energy lost: 1 − power(caustics) / power(reference) over the case's receiver (the wall for the wall cases,
  every pixel otherwise); negative means energy gained;
* error: relative RMSE of the caustics over the reference's caustic mask on that receiver;
* flicker: mean relative frame-to-frame difference of the denoised caustics, the previous frame reprojected
  by the motion vectors, over pixels that are the same surface in both and in the caustic mask; beside it
  the raw photon map's, and the reference's own (its noise, plus the true change in animated cases: a
  method far below the reference's there is lagging, not stable).

Writes OUT/stability.csv, OUT/stability.json (device, Warp version, preset, date) and OUT/stability.md.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import math
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

#: photons per light per frame; reference: per light per reference frame, in passes of ``reference_pass``
#: (0 = the renderer's default, 1e8 on CUDA); frames per sequence, the last ``measured`` of which are measured
#: cases: the preset's default ``--cases`` (None: all)
PRESETS = {
    "smoke": dict(width=48, height=36, rsm_size=64, photons=20_000, reference=400_000, reference_pass=100_000,
                  frames=5, measured=3, cases=None),
    "small": dict(width=96, height=72, rsm_size=256, photons=100_000, reference=2_000_000,
                  reference_pass=250_000, frames=16, measured=4, cases=None),
    "full": dict(width=960, height=540, rsm_size=2048, photons=2_000_000, reference=200_000_000,
                 reference_pass=4_000_000, frames=24, measured=4, cases="fast_water,moving_light,camera_pan"),
}
FIELDS = ["case", "method", "denoiser", "photons", "energy_lost", "error", "static_error", "error_ratio", "flicker",
          "flicker_raw", "reference_flicker", "flicker_ratio", "reference_noise", "stored", "lost_light_view", "lost_camera_view", "occluded", "closure", "finite"]


def fmt(v: float, digits: int = 3) -> str:
    return "–" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def ratio(a: float, b: float) -> float:
    return a / b if b and math.isfinite(b) else math.nan


def markdown(rows: list[dict], methods: list[str], header: str) -> str:
    """A compact table (one row per case and denoiser: lost / error / flicker per method), then every figure."""
    cases = list(dict.fromkeys(r["case"] for r in rows))
    denoisers = list(dict.fromkeys(r["denoiser"] for r in rows))
    by = {(r["case"], r["method"], r["denoiser"]): r for r in rows}
    out = [header, "", "energy lost / relative error / flicker of the denoised caustics (– : no caustic to "
           "compare); animated cases: e/s = error over the same case's held still (static twin, same photons, frames and "
           "denoiser; goal <= 1.25), f/r = flicker over the reference's (goal <= 1.5); last column: the reference's "
           "own flicker (noise + true change)", "",
           "| case | denoiser | " + " | ".join(methods) + " | reference flicker |",
           "|---|---|" + "---|" * (len(methods) + 1)]
    for c in cases:
        ref = next(r for r in rows if r["case"] == c)
        for d in denoisers:
            cells = []
            for m in methods:
                r = by.get((c, m, d))
                cells.append("" if r is None else f"{fmt(r['energy_lost'], 2)} / {fmt(r['error'], 3)} / {fmt(r['flicker'], 3)}"
                             + ("" if not math.isfinite(r.get("error_ratio", math.nan)) else
                                f" (e/s {fmt(r['error_ratio'], 2)}, f/r {fmt(r['flicker_ratio'], 2)})"))
            if any(cells):
                out.append(f"| {c} | {d} | " + " | ".join(cells) + f" | {fmt(ref['reference_flicker'], 3)} |")
    out += ["", "| " + " | ".join(FIELDS) + " |", "|---" * len(FIELDS) + "|"]
    for r in rows:
        out.append("| " + " | ".join(fmt(r[k], 4) if isinstance(r[k], float) else str(r[k]) for k in FIELDS) + " |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", choices=sorted(PRESETS), default="small",
                   help="small: CPU-sized (96x72); full: 1280x720 for a GPU; smoke: seconds")
    p.add_argument("--smoke", action="store_true", help="same as --preset smoke")
    p.add_argument("--out", default="results", help="output folder; references are cached in OUT/references")
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--cases", default=None, help="comma-separated subset of the cases (default: all)")
    p.add_argument("--methods", default="cisp,sspm,caustics_map",
                   help="comma-separated methods; cisp:wavefront, sspm:wavefront for wavefront splatting over the RSM grid, "
                   "cisp:wavefront-mesh, sspm:wavefront-mesh over the water mesh (the preset's photons then count "
                   "grid cells per light)")
    p.add_argument("--denoisers", default="caustic,svgf,own",
                   help="comma-separated denoisers: caustic, svgf, none, own (caustics_map's seed-004 filters), "
                   "caustic-surface (cisp: the caustics denoiser without the caustic flow, its history along the surface's motion only, docs/perf_notes.md section 35), caustic-single (the caustics denoiser "
                   "without the flow, its history forgotten before every frame: what the spatial filter alone makes of one frame)")
    p.add_argument("--photons", type=int, default=None,
                   help="photons per light per frame of the methods (default: the preset's; the reference keeps "
                   "its own)")
    p.add_argument("--size", default=None, help="WxH: the image size instead of the preset's (e.g. 192x144)")
    p.add_argument("--rsm-size", type=int, default=None, help="RSM edge [texels] instead of the preset's")
    p.add_argument("--reference", type=int, default=None,
                   help="reference photons per light per frame instead of the preset's")
    p.add_argument("--no-static", action="store_true",
                   help="skip the static twins of the animated cases (their error held still: half the time)")
    p.add_argument("--merge", action="store_true",
                   help="keep the rows already in OUT/stability.json (same preset and device) that this call does "
                   "not measure again (another case, method or denoiser), so that a long preset can run in parts")
    args = p.parse_args(argv)
    if args.smoke:
        args.preset = "smoke"
    cfg = dict(PRESETS[args.preset])
    if args.photons is not None:
        if args.photons < 1:
            raise SystemExit(f"--photons must be a positive integer, got {args.photons}")
        cfg["photons"] = args.photons
    try:
        if args.size is not None:
            cfg["width"], cfg["height"] = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise SystemExit(f"--size must be WxH in pixels, got {args.size!r}") from None
    for name, key in (("rsm_size", "rsm_size"), ("reference", "reference")):
        v = getattr(args, name)
        if v is not None:
            if v < 1:
                raise SystemExit(f"--{name.replace('_', '-')} must be a positive integer, got {v}")
            cfg[key] = v
    if min(cfg["width"], cfg["height"]) < 1:
        raise SystemExit(f"--size must be positive, got {args.size!r}")

    import warp as wp

    wp.config.log_level = wp.LOG_WARNING  # no init banner or module-load lines
    wp.init()
    from tqdm import tqdm

    from cisp_warp import evaluation as E
    from cisp_warp.stability_scenes import CASES, case, frozen

    device = wp.get_device(args.device)
    dev_name = E.device_name(device)
    names = args.cases or cfg["cases"]
    cases = [case(n) for n in names.split(",")] if names else list(CASES)
    methods = args.methods.split(",")
    denoisers = args.denoisers.split(",")
    for d in denoisers:
        if d not in E.DENOISERS + E.EXTRA_DENOISERS:
            raise SystemExit(f"unknown denoiser {d!r}: {', '.join(E.DENOISERS + E.EXTRA_DENOISERS)}")
    runs = [(m, d) for m in methods for d in denoisers if E.applicable(m.partition(":")[0], d)]
    w, h, frames, measured = cfg["width"], cfg["height"], cfg["frames"], cfg["measured"]
    cache = os.path.join(args.out, "references")
    os.makedirs(args.out, exist_ok=True)
    settings = E.reference_settings(cfg["rsm_size"], cfg["reference_pass"], cfg["reference"])
    t_start = time.perf_counter()
    rows, references = [], {}
    bar = tqdm(total=len(cases) * (len(runs) + 1), unit="run", desc="stability")
    for c in cases:
        bar.set_postfix_str(f"{c.name}: reference")
        reference, meta = E.case_reference(c, w, h, frames, measured, settings, device, cache)
        references[c.name] = meta
        bar.update()
        for m, d in runs:
            bar.set_postfix_str(f"{c.name}: {m} {d}")
            method, _, splat = m.partition(":")
            splat, _, grid = (splat or "point").partition("-")
            f = E.measure_case(c, method, reference, w, h, frames, measured, cfg["rsm_size"], cfg["photons"], device,
                               denoiser=d, splat=splat, wavefront_grid=grid or "rsm")
            static_error = math.nan
            if c.animated and not args.no_static:  # the same caustic held still: the error nothing moving allows
                still = frozen(c, frames - 1)
                static_error = E.measure_case(still, method, [reference[-1]] * 2, w, h, frames, measured, cfg["rsm_size"],
                                              cfg["photons"], device, denoiser=d, splat=splat,
                                              wavefront_grid=grid or "rsm").error
            rows.append({"case": c.name, "method": m, "denoiser": d, "photons": f.photons, "energy_lost": f.energy_lost,
                         "error": f.error, "static_error": static_error, "error_ratio": ratio(f.error, static_error),
                         "flicker": f.flicker, "flicker_raw": f.flicker_raw,
                         "reference_flicker": f.reference_flicker,
                         "flicker_ratio": ratio(f.flicker, f.reference_flicker), "reference_noise": f.reference_noise,
                         **{k: f.ledger[k] for k in ("stored", "lost_light_view", "lost_camera_view", "occluded")},
                         "closure": f.closure, "finite": f.finite})
            bar.update()
    bar.close()
    wall = time.perf_counter() - t_start
    previous = os.path.join(args.out, "stability.json")
    case_info = {c.name: {"summary": c.summary, "animated": c.animated, "expect": c.expect} for c in cases}
    if args.merge and os.path.exists(previous):
        with open(previous) as fh:
            old = json.load(fh)
        if (old["device"], old["preset"]) == (dev_name, args.preset):
            done = {c.name for c in cases}
            measured = {(r["case"], r["method"], r["denoiser"]) for r in rows}
            order = [c.name for c in CASES]
            rows = sorted([r for r in old["rows"] if (r["case"], r["method"], r["denoiser"]) not in measured] + rows,
                          key=lambda r: order.index(r["case"]))
            references = {**{k: v for k, v in old["references"].items() if k not in done}, **references}
            case_info = {**{k: v for k, v in old["cases"].items() if k not in done}, **case_info}
            wall += old.get("wall_seconds", 0.0)
        else:
            print(f"note: {previous} is from another device or preset; not merged", file=sys.stderr)

    header = (f"Stability, preset {args.preset}: {w}x{h}, RSM {cfg['rsm_size']}², {cfg['photons']:,} photons per "
              f"frame, {frames} frames (the last {measured} measured); device {dev_name}, Warp {wp.config.version}")
    with open(os.path.join(args.out, "stability.csv"), "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=FIELDS)
        wr.writeheader()
        wr.writerows(rows)
    with open(os.path.join(args.out, "stability.json"), "w") as fh:
        json.dump({"device": dev_name, "warp": wp.config.version, "source": E.source_version(), "preset": args.preset,
                   "settings": cfg,
                   "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                   "command": " ".join([os.path.relpath(sys.argv[0], ROOT)] + sys.argv[1:]), "wall_seconds": wall,
                   "cases": case_info,
                   "references": references, "rows": rows}, fh, indent=1)
    md = markdown(rows, methods, header)
    with open(os.path.join(args.out, "stability.md"), "w") as fh:
        fh.write(md)
    print(f"{header}; {wall:.0f} s")
    print("error: relative RMSE; static: the same case held still at its last frame (same photons, frames and "
          "denoiser), e/s their ratio (goal <= 1.25); flicker: denoised, raw photon map, reference (noise + true "
          "change), f/r denoised over reference (goal <= 1.5)")
    print(f"{'case':<23}{'method':<16}{'denoiser':<9}{'lost':>8}{'error':>8}{'static':>8}{'e/s':>7}{'flicker':>9}"
          f"{'raw':>8}{'ref':>8}{'f/r':>7}")
    for r in rows:
        print(f"{r['case']:<23}{r['method']:<16}{r['denoiser']:<9}{fmt(r['energy_lost']):>8}{fmt(r['error']):>8}"
              f"{fmt(r['static_error']):>8}{fmt(r['error_ratio'], 2):>7}{fmt(r['flicker']):>9}{fmt(r['flicker_raw']):>8}"
              f"{fmt(r['reference_flicker']):>8}{fmt(r['flicker_ratio'], 2):>7}")
    print(f"wrote {args.out}/stability.csv, stability.json, stability.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
