#!/usr/bin/env python3
"""Where `cisp`'s trace kernel spends a warp's time, counted on the CPU (docs/perf_notes.md section 34).

Renders one frame of each scene with `cisp` on the CPU with the GPU's photon order (texel Morton order, then grouped
by march: ``PhotonPass.photon_order``), and in place of each view's ``trace_photons`` launches the ``counted`` trace
(``kernels_cisp.counted_trace``: the same kernel on marches that count their work, ``wp.static``) over a sample of
whole warps (32 consecutive threads of the launch, spread evenly over it, in their real order). Per photon it has
the dependent iterations of each phase:

* emit: 1, plus the triangle walk of ``surface_at_sample`` (replayed here for the traced photons);
* light march: the light-view march's cell tests (coarse, fine) and pixel steps;
* reproject: 1 (traced photons);
* cascade, rescue: the two camera marches' cell tests and pixel steps; they share one call site (one inlined
  march in a loop of two passes), so a warp pays them as "camera (one site)": the max over its lanes of their sum;
* refine, store: 1 each where they ran (``refine_landing``; ``deposit`` and ``store_hidden``).

Per warp it takes each phase's most expensive lane (what the warp pays: SIMT runs a phase as long as its longest
lane) against the lanes' mean (what a perfectly coherent warp would pay). Prints per phase: mean, p99 and max over
the sampled photons, sum over warps of the max lane / of the mean (the divergence ratio), and the phase's share of
the warp-time (sum over phases of the warps' max lanes: phases run one after the other). Iterations are not
cycles: a cell test, a pixel step and a constant phase each cost differently (see the perf notes); the table says
where the lanes wait on each other, not milliseconds. The last row, "whole trace as one phase", is Σ over warps of
the longest lane's total: what the warps would pay if lanes never waited for each other between phases.

    PYTHONPATH=. python3 tools/trace_steps.py --scenes cornell,pool            # 1920x1080, RSM 2048², 2M, 2048 warps
    PYTHONPATH=. python3 tools/trace_steps.py --scenes pool --warps 4096 --json out.json
    PYTHONPATH=. python3 tools/trace_steps.py --smoke     # tiny; also checks the counted trace's output is the trace's
"""


import argparse
import json
import os
import sys

import numpy as np
import warp as wp

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tools"))

WARP = 32
#: the rows of the table: (name, per-lane iterations from the phase arrays)
PHASES = ("emit", "light march", "  light: cell tests", "  light: pixel steps", "reproject", "cascade (pass 0)",
          "rescue (pass 1)", "camera (one site)", "  camera: cell tests", "  camera: pixel steps", "refine", "store")
#: the phases the warp runs one after the other (their warp maxima add up to the warp-time)
SEQUENTIAL = ("emit", "light march", "reproject", "camera (one site)", "refine", "store")


def make_walk_kernel():
    """A kernel that counts ``surface_at_sample``'s triangle walk for given photons (``walk_to_sample``'s steps)."""
    from cisp_warp.photons.common import r2_point, walk_to_sample
    from cisp_warp.raster.views import ViewParams, pixel_ray_world
    from cisp_warp.scene.device import SurfaceGeometry

    @wp.kernel(module="unique")
    def walk_steps(views: wp.array(dtype=ViewParams), view_index: int, scramble: wp.vec2i, ks: wp.array(dtype=wp.int32),
                   rsm_tri: wp.array(dtype=wp.int32), geometry: SurfaceGeometry, out: wp.array(dtype=wp.int32)):
        """Per photon ``ks[r]`` (a traced one): the triangles ``surface_at_sample`` visits after its texel's."""
        r = wp.tid()
        light = views[view_index]
        u = r2_point(ks[r], scramble)
        sx = u[0] * float(light.width)
        sy = u[1] * float(light.height)
        texel = wp.min(int(sy), light.height - 1) * light.width + wp.min(int(sx), light.width - 1)
        lo, ld = pixel_ray_world(light, sx, sy)
        ok, cur, b0, b1, b2, t, step, ind = walk_to_sample(lo, ld, rsm_tri[texel], geometry)
        out[r] = step

    return walk_steps


def lane_phases(rec: np.ndarray, walk: np.ndarray, emitted: np.ndarray) -> dict[str, np.ndarray]:
    """Per lane, the iterations of each phase from its count records ``rec`` ((n, 8): ``kernels_cisp.write_counts``)
    and its walk steps."""
    from cisp_warp.photons import kernels_cisp as K

    phases = rec[:, 6].astype(np.int64)
    traced = (phases & int(K.COUNT_TRACED)) != 0
    lt, ls, c0t, c0s, c1t, c1s = (rec[:, i].astype(np.int64) for i in range(6))
    one = lambda bit: ((phases & int(bit)) != 0).astype(np.int64)  # noqa: E731
    return {
        "emit": emitted.astype(np.int64) * (1 + walk),
        "light march": lt + ls,
        "  light: cell tests": lt,
        "  light: pixel steps": ls,
        "reproject": traced.astype(np.int64),
        "cascade (pass 0)": c0t + c0s,
        "rescue (pass 1)": c1t + c1s,
        "camera (one site)": c0t + c0s + c1t + c1s,
        "  camera: cell tests": c0t + c1t,
        "  camera: pixel steps": c0s + c1s,
        "refine": one(K.COUNT_REFINE),
        "store": one(K.COUNT_DEPOSIT) + one(K.COUNT_HIDDEN),
    }


def table(lanes: dict[str, np.ndarray]) -> list[dict]:
    """Per phase: mean, p99, max per lane; Σ over warps of the max lane and of the mean; their ratio; the share of
    the warp-time (Σ over the sequential phases of the warps' max lanes)."""
    n = len(next(iter(lanes.values())))
    assert n % WARP == 0
    rows = []
    warp_time = sum(lanes[p].reshape(-1, WARP).max(1).sum() for p in SEQUENTIAL)
    total = sum(lanes[p] for p in SEQUENTIAL)
    for name, x in list(lanes.items()) + [("whole trace as one phase", total)]:
        w = x.reshape(-1, WARP)
        wmax, wmean = float(w.max(1).sum()), float(w.mean(1).sum())
        rows.append({"phase": name, "mean": float(x.mean()), "p99": float(np.percentile(x, 99)), "max": int(x.max()),
                     "warp_max": wmax, "warp_mean": wmean, "ratio": wmax / wmean if wmean > 0 else float("nan"),
                     "share": wmax / warp_time if (name in SEQUENTIAL and warp_time > 0) else None})
    return rows


def print_table(title: str, rows: list[dict], warps: int) -> None:
    print(title)
    print(f"  {'phase':26s} {'mean':>8s} {'p99':>7s} {'max':>6s}   {'Σwarp max':>11s} {'Σwarp mean':>11s} "
          f"{'ratio':>6s} {'share':>6s}   (iterations; {warps:,} warps)")
    for r in rows:
        share = f"{100 * r['share']:5.1f}%" if r["share"] is not None else "     -"
        print(f"  {r['phase']:26s} {r['mean']:8.2f} {r['p99']:7.0f} {r['max']:6d}   {r['warp_max']:11.0f} "
              f"{r['warp_mean']:11.0f} {r['ratio']:6.2f} {share}")


def arg_index(kernel, name: str) -> int:
    return [a.label for a in kernel.adj.args].index(name)


def sample_warps(n_photons: int, warps: int) -> np.ndarray:
    """Indices of ``warps`` whole warps spread evenly over the first n_photons threads (all when fewer)."""
    full = n_photons // WARP
    if warps <= 0 or warps >= full:
        return np.arange(full)
    return np.unique((np.arange(warps) * full) // warps)


def run_scene(name: str, args) -> dict:
    import evaluate as EV

    from cisp_warp.photons import PhotonSettings
    from cisp_warp.photons import kernels_cisp as K
    from cisp_warp.render import Renderer, RenderSettings

    specs = EV.scene_specs([name])
    if not specs:
        raise SystemExit(f"trace_steps: scene {name!r} is not available")
    spec = specs[0]
    device = wp.get_device("cpu")
    settings = RenderSettings(rsm_size=args.rsm, method="cisp", denoiser="none",
                              photons=PhotonSettings(photons=args.n_photons, seed=3, sort_photons=True))
    r = Renderer(spec.make(args.width, args.height), settings, device=device)
    if spec.prepare is not None:
        spec.prepare(r)
    photons = r.photons
    photons.record_outcomes = True  # --check compares the outcome records (FOLDED_OUTCOMES writes them only if asked)
    counted = K.counted_trace()
    walk_kernel = make_walk_kernel()
    launch = photons.launch_photons
    i_order, i_use, i_hits, i_slots = (arg_index(K.trace_photons, a) for a in ("order", "use_order", "hits", "n_slots"))
    i_views, i_states, i_vi, i_lphot = (arg_index(K.trace_photons, a)
                                        for a in ("light_views", "states", "view_index", "light_photons"))
    i_rand, i_stream, i_tri, i_geom = (arg_index(K.trace_photons, a)
                                       for a in ("randoms", "stream", "rsm_tri", "geometry"))
    i_map, i_out = arg_index(K.trace_photons, "photon_map"), arg_index(K.trace_photons, "outcome")
    views_lanes: list[dict[str, np.ndarray]] = []
    checks: list[str] = []

    def counted_launch(kernel, n, inputs):
        if kernel not in K.trace_kernels():  # the frame's trace, whichever projection it was compiled for
            return launch(kernel, n, inputs)
        inputs = list(inputs)
        if inputs[i_use] == 0:
            raise SystemExit("trace_steps: the photons are not sorted (sort_photons)")
        vi = inputs[i_vi]
        state = inputs[i_states].numpy()[vi]
        active, active_views = int(state["active"]), int(state["active_views"])
        n_photons = 0 if active == 0 else max(1, inputs[i_lphot] // max(1, active_views))
        order = inputs[i_order].numpy()[:n]
        slots = int(inputs[i_slots])
        hits = wp.zeros(3 * slots, dtype=wp.vec4, device=device)
        inputs[i_hits] = hits
        pm0 = inputs[i_map].numpy().copy()
        if args.check:  # the trace and the counted trace over the whole launch: the same outcome and photon map
            inputs[i_hits] = wp.zeros(slots, dtype=wp.vec4, device=device)
            launch(kernel, n, inputs)
            out1, pm1, hits1 = inputs[i_out].numpy()[:n].copy(), inputs[i_map].numpy().copy(), inputs[i_hits].numpy()
            inputs[i_map].assign(pm0)
            inputs[i_hits] = hits
            launch(counted, n, inputs)
            out2, pm2 = inputs[i_out].numpy()[:n], inputs[i_map].numpy()
            same = (np.array_equal(out1, out2) and np.array_equal(pm1, pm2)
                    and np.array_equal(hits1, hits.numpy()[:slots]))
            checks.append(f"view {vi}: counted trace's outcome, photon map and landings "
                          f"{'equal' if same else 'DIFFER from'} the trace's")
            chosen = sample_warps(n_photons, 0)
        else:  # only the sampled warps, each in its place of the real order (k = order[t])
            chosen = sample_warps(n_photons, args.warps)
            sub = order[(chosen[:, None] * WARP + np.arange(WARP)[None, :]).ravel()]
            inputs[i_order] = wp.array(sub.astype(np.int32), dtype=wp.int32, device=device)
            launch(counted, len(sub), inputs)
            inputs[i_order] = wp.array(order, dtype=wp.int32, device=device)
        ks = order[(chosen[:, None] * WARP + np.arange(WARP)[None, :]).ravel()]
        rec = hits.numpy()[slots:].reshape(slots, 8)[ks]
        if not np.all(rec[:, 7] == 1.0):
            raise SystemExit("trace_steps: a sampled photon wrote no count record")
        traced = (rec[:, 6].astype(np.int64) & int(K.COUNT_TRACED)) != 0
        walk = np.zeros(len(ks), np.int64)
        if traced.any():
            out = wp.zeros(int(traced.sum()), dtype=wp.int32, device=device)
            rnd = inputs[i_rand].numpy()[inputs[i_stream]]
            wp.launch(walk_kernel, dim=out.shape[0], device=device, inputs=[
                inputs[i_views], vi, wp.vec2i(int(rnd[0]), int(rnd[1])),
                wp.array(ks[traced].astype(np.int32), dtype=wp.int32, device=device), inputs[i_tri], inputs[i_geom],
                out])
            walk[traced] = out.numpy()
        emitted = np.ones(len(ks), bool)  # every sampled lane is a photon of the view (t < n_photons)
        lanes = lane_phases(rec, walk, emitted)
        lanes["entry"] = inputs[i_out].numpy()[(chosen[:, None] * WARP + np.arange(WARP)[None, :]).ravel()
                                              if args.check else np.arange(len(ks)), 3].astype(np.int64)
        views_lanes.append(lanes)
        print(f"  {name} view {vi}: {n_photons:,} photons, {len(chosen):,} warps sampled, "
              f"{int(traced.sum()):,} lanes traced", file=sys.stderr)

    photons.launch_photons = counted_launch
    r.render_frame()
    lanes = {p: np.concatenate([v[p] for v in views_lanes]) for p in PHASES}
    if args.dump:
        np.savez(f"{args.dump}_{name}.npz", view=np.concatenate([np.full(len(v["emit"]), i)
                                                                 for i, v in enumerate(views_lanes)]),
                 entry=np.concatenate([v["entry"] for v in views_lanes]),
                 **{p.strip().replace(" ", "_").replace(":", ""): x for p, x in lanes.items()})
    rows = table(lanes)
    n_warps = len(lanes["emit"]) // WARP
    print_table(f"{name} {args.width}x{args.height}, RSM {args.rsm}², {args.n_photons:,} photons per light, "
                f"{len(views_lanes)} trace launch(es), photons sorted and grouped as on the GPU", rows, n_warps)
    for c in checks:
        print("  " + c)
    return {"scene": name, "width": args.width, "height": args.height, "rsm": args.rsm, "photons": args.n_photons,
            "warps": n_warps, "rows": rows, "checks": checks,
            "ok": all("equal" in c for c in checks)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", default="cornell,pool", help="comma-separated: cornell, pool (default both)")
    p.add_argument("--width", type=int, default=1920, help="image width [pixels] (default 1920)")
    p.add_argument("--height", type=int, default=1080, help="image height [pixels] (default 1080)")
    p.add_argument("--rsm", type=int, default=2048, help="RSM edge [texels] (default 2048)")
    p.add_argument("--photons", default="2M", help="photons per light (default 2M)")
    p.add_argument("--warps", type=int, default=2048, help="warps sampled per trace launch (default 2048; 0: all)")
    p.add_argument("--check", action="store_true",
                   help="trace every warp, with the trace and the counted trace, and check their outputs are equal")
    p.add_argument("--json", default=None, help="write the tables here")
    p.add_argument("--dump", default=None, help="save every sampled lane's phases and final entry (DUMP_scene.npz)")
    p.add_argument("--smoke", action="store_true", help="tiny (96x54, RSM 64, 8k photons, --check), for the tests")
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.rsm, args.photons, args.check = 96, 54, 64, "8k", True
    from cisp_warp.cli import parse_count

    try:
        args.n_photons = parse_count(args.photons)
    except Exception as e:  # noqa: BLE001 - one sentence for bad input
        raise SystemExit(f"trace_steps: {e}")
    if args.width <= 0 or args.height <= 0 or args.rsm <= 0:
        raise SystemExit("trace_steps: width, height and RSM size must be positive")
    wp.config.quiet = True
    wp.init()
    results = [run_scene(s.strip(), args) for s in args.scenes.split(",") if s.strip()]
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)
    return 0 if all(r["ok"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
