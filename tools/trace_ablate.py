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

import os
import sys
import time

import numpy as np
import warp as wp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _scene_bench import SCENES, scene_bench_main  # noqa: E402


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
        if kernel in K.trace_kernels():  # every view's order is written into one array: keep a copy of this view's
            inputs = list(inputs)
            inputs[at_order] = wp.clone(inputs[at_order])
            kept.append((n, inputs, kernel))  # the kernel the frame launched (compiled for the view's projection)

    r.photons.launch_photons = keep
    r.render_frame()
    r.photons.launch_photons = launch
    wp.synchronize_device(device)
    table = {}
    for vname in variants(K.trace_photons, kept[0][1], device):
        per = [(n, variants(K.trace_photons, inputs, device)[vname], kernel) for n, inputs, kernel in kept]
        times = []
        for rep in range(args.reps + 1):
            if device.is_cuda:
                e0, e1 = wp.Event(device, enable_timing=True), wp.Event(device, enable_timing=True)
                wp.record_event(e0)
                for n, inputs, kernel in per:
                    launch(kernel, n, inputs)
                wp.record_event(e1)
                wp.synchronize_event(e1)
                ms = wp.get_event_elapsed_time(e0, e1)
            else:
                t0 = time.perf_counter()
                for n, inputs, kernel in per:
                    launch(kernel, n, inputs)
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
    return scene_bench_main("trace_ablate", __doc__, run_scene, 10, argv)


if __name__ == "__main__":
    sys.exit(main())
