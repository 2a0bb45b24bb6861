#!/usr/bin/env python3
"""`cisp`'s trace kernel with parts of its work switched off by its own run-time inputs, timed on the GPU: where
its milliseconds go, which iteration counts (``tools/trace_steps.py``) cannot say (docs/perf_notes.md section 34).

Renders a few frames of each scene with `cisp`, keeps one frame's ``trace_photons`` launches (their inputs as the
frame passed them), then replays each launch ``--reps`` times per variant and reports the median ms per frame (the
frame's launches summed) from CUDA events:

* ``frame``: the inputs as they were;
* ``no photon_m2 / hidden map``: the two accumulations a stored photon adds beside the photon map left out (empty);
* ``no camera marches``: ``use_cascade`` 0 (no cascade, no rescue: a photon ends where the light view leaves it);
* ``max_steps 1``: every march ends after at most one step (emission, set-up, reprojection and store remain);
* ``emit only``: every texel culled by luminance (sampling and booking; no walk, no bounce, no march);
* ``photons unsorted``: ``use_order`` 0 (thread t traces photon t, in R2 order: no Morton sort, no march groups).

Each launch keeps a copy of its view's tracing order (the frame writes every view's order into one array).

The variants change the photons' outcomes (all but the first): they are ablations for timing, nothing else. The
replays add into the frame's photon map and ledger, which nothing reads afterwards.

    PYTHONPATH=. python3 tools/trace_ablate.py --scenes cornell,pool       # 1920x1080, RSM 2048², 2M per light
    PYTHONPATH=. python3 tools/trace_ablate.py --smoke --device cpu         # tiny, wall clock on the CPU
"""

import argparse
import os
import sys
import time

import numpy as np
import warp as wp

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
SCENES = {"cornell": os.path.join(ROOT, "scenes_usd", "cornell_flooded.usda"),
          "pool": os.path.join(ROOT, "scenes_usd", "pool.usda")}


def variants(kernel, inputs: list, device) -> dict[str, list]:
    names = [a.label for a in kernel.adj.args]
    at = {n: i for i, n in enumerate(names)}

    def with_(**kw):
        v = list(inputs)
        for k, x in kw.items():
            v[at[k]] = x
        return v

    empty_f = wp.zeros(0, dtype=wp.float32, device=device)
    empty_v = wp.zeros(0, dtype=wp.vec3, device=device)
    return {
        "frame": list(inputs),
        "no photon_m2 / hidden map": with_(photon_m2=empty_f, hidden_flux=empty_v),
        "no camera marches": with_(use_cascade=0),
        "max_steps 1": with_(max_steps=1),
        "emit only": with_(luminance_cutoff=1.0e30),
        "photons unsorted": with_(use_order=0),
    }


def run_scene(name: str, args, device) -> None:
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.photons import kernels_cisp as K
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.usd import load_usd

    if not os.path.exists(SCENES[name]):
        raise SystemExit(f"trace_ablate: {SCENES[name]} not found")
    scene = load_usd(SCENES[name], width=args.width, height=args.height, device=device)
    settings = RenderSettings(rsm_size=args.rsm, method="cisp", denoiser="none",
                              photons=PhotonSettings(photons=args.n_photons))
    r = Renderer(scene, settings, device=device)
    r.use_graph = False
    for _ in range(3):
        r.render_frame()
    kept = []
    launch = r.photons.launch_photons

    at_order = [a.label for a in K.trace_photons.adj.args].index("order")

    def keep(kernel, n, inputs):
        launch(kernel, n, inputs)
        if kernel is K.trace_photons:  # every view's order is written into one array: keep a copy of this view's
            inputs = list(inputs)
            inputs[at_order] = wp.clone(inputs[at_order])
            kept.append((n, inputs))

    r.photons.launch_photons = keep
    r.render_frame()
    r.photons.launch_photons = launch
    wp.synchronize_device(device)
    table = {}
    for vname in variants(K.trace_photons, kept[0][1], device):
        per = [(n, variants(K.trace_photons, inputs, device)[vname]) for n, inputs in kept]
        times = []
        for rep in range(args.reps + 1):
            if device.is_cuda:
                e0, e1 = wp.Event(device, enable_timing=True), wp.Event(device, enable_timing=True)
                wp.record_event(e0)
                for n, inputs in per:
                    launch(K.trace_photons, n, inputs)
                wp.record_event(e1)
                wp.synchronize_event(e1)
                ms = wp.get_event_elapsed_time(e0, e1)
            else:
                t0 = time.perf_counter()
                for n, inputs in per:
                    launch(K.trace_photons, n, inputs)
                ms = 1e3 * (time.perf_counter() - t0)
            if rep > 0:  # the first is a warm-up
                times.append(ms)
        table[vname] = float(np.median(times))
    print(f"{name} {args.width}x{args.height}, RSM {args.rsm}², {args.n_photons:,} photons per light, "
          f"{len(kept)} trace launch(es), {device}: trace_photons ms per frame (median of {args.reps})")
    base = table["frame"]
    for vname, ms in table.items():
        print(f"  {vname:28s} {ms:8.3f}   {ms - base:+8.3f}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", default="cornell,pool", help="comma-separated: cornell, pool (default both)")
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--rsm", type=int, default=2048)
    p.add_argument("--photons", default="2M", help="photons per light (default 2M)")
    p.add_argument("--reps", type=int, default=10, help="timed replays per variant (default 10)")
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--smoke", action="store_true", help="tiny (96x54, RSM 64, 4k photons, 2 reps)")
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.rsm, args.photons, args.reps = 96, 54, 64, "4k", 2
    from cisp_warp.cli import parse_count

    try:
        args.n_photons = parse_count(args.photons)
    except Exception as e:  # noqa: BLE001 - one sentence for bad input
        raise SystemExit(f"trace_ablate: {e}")
    wp.config.quiet = True
    wp.init()
    device = wp.get_device(args.device)
    for s in args.scenes.split(","):
        if s.strip() not in SCENES:
            raise SystemExit(f"trace_ablate: unknown scene {s!r}: cornell, pool")
        run_scene(s.strip(), args, device)
    return 0


if __name__ == "__main__":
    sys.exit(main())
