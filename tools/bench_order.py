#!/usr/bin/env python3
"""The photon order's kernels and the ledger's outcome pass, each replayed alone with variants, timed on the GPU
(docs/perf_notes.md section 40): which part of a change moved a kernel, which Warp's per-kernel table of a whole
frame (``tools/bench_frame.py --kernels``) cannot separate.

Renders a few frames of each scene with `cisp`, keeps one frame's launches of ``photon_group_keys``,
``photon_group_scatter`` and ``ledger_add_outcomes`` (their inputs as the frame passed them), then replays each
view's launches ``--reps`` times per variant and reports the median ms per frame (the frame's views summed) from
Warp's CUDA activity timing (kernel execution only; L2 flushed before each launch), per view too:

* ``photon_group_keys``: as in the frame (fixed texel order, the texel's values read in one round trip, no
  position, a few blocks over many tiles); ``per-frame order`` (the frame's rotated points sorted, as main did, instead of the fixed order);
  ``chained reads`` (main's prediction: each read after the test before it, the incident direction from the
  texel's position for point and spot lights, one block a tile; a copy of main's kernel here, with the fixed
  order); the same
  without the position (the light ray's direction, as in the frame); and main's reads with the per-frame order;
* ``photon_group_scatter``: as in the frame; ``per-frame order`` (the keys and order of the per-frame variant);
* ``ledger_add_outcomes``: as in the frame (four records a step, two block sums of five entries each); ``one
  record a step`` (main's kernel, a copy here: one block sum per entry); ``no block sums`` (the loop only);
  ``fast`` and ``tile sums``: ``PhotonPass.FAST_OUTCOMES`` on and off (section 77);
* on CUDA, ``[graph]`` rows: each view's order chain captured and replayed as a CUDA graph (warm L2, no flush), so
  that ``wp.utils.array_scan`` (CUB's kernels and temporary allocation, which Warp's timing does not see) is
  counted: keys + scan + scatter; the outcome pass fast and not.

The variants are timings only: the replays rewrite the frame's scratch (keys, counts, grouped order) and add into the
frame's ledger stripes, which nothing reads afterwards.

    PYTHONPATH=. python3 tools/bench_order.py --scenes cornell,pool       # 1920x1080, RSM 2048², 2M per light
    PYTHONPATH=. python3 tools/bench_order.py --smoke --device cpu         # tiny, wall clock on the CPU
"""

import os
import sys
import time

import numpy as np
import warp as wp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _scene_bench import SCENES, scene_bench_main  # noqa: E402

from cisp_warp.denoise.kernels_svgf import luminance  # noqa: E402
from cisp_warp.optics import fresnel_dielectric  # noqa: E402
from cisp_warp.photons import common as C  # noqa: E402
from cisp_warp.raster.light_maps import CascadeState, cascade_photons  # noqa: E402
from cisp_warp.raster.views import ViewParams, pixel_ray_world  # noqa: E402


@wp.kernel(module="unique")
def group_keys_chained(
    views: wp.array(dtype=ViewParams), states: wp.array(dtype=CascadeState), view_index: int, light_photons: int,
    light_kind: int, light_pos: wp.vec3, randoms: wp.array(dtype=wp.vec3i), stream: int,
    rsm_position: wp.array(dtype=wp.vec3), rsm_normal: wp.array(dtype=wp.vec3), rsm_flux: wp.array(dtype=wp.vec3),
    rsm_roughness: wp.array(dtype=wp.float32), rsm_ior: wp.array(dtype=wp.float32), rsm_tri: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32), mat_opacity: wp.array(dtype=wp.float32),
    max_lum: wp.array(dtype=wp.float32), roughness_cutoff: float, luminance_cutoff: float,
    order: wp.array(dtype=wp.int32), order_stride: int, orders: int, n_slots: int, keys: wp.array(dtype=wp.int32),
    block_counts: wp.array(dtype=wp.int32),
):
    """Main's photon_group_keys (7704868): reads chained behind their tests, position for point/spot lights; the
    order from common.order_base (the fixed orders' table)."""
    block, lane = wp.tid()
    bd = wp.block_dim()
    t = block * bd + lane
    group = int(-1)
    if t < n_slots:
        cascade = states[view_index]
        n_photons = cascade_photons(cascade, light_photons)
        group = C.SORT_GROUP_LAST
        if t < n_photons:
            k = order[C.order_base(cascade, order_stride, orders) + t]
            if k >= 0:
                light = views[view_index]
                rnd = randoms[stream]
                skip_window = cascade.skip_window
                u = C.r2_point(k, wp.vec2i(rnd[0], rnd[1]))
                sx = u[0] * float(light.width)
                sy = u[1] * float(light.height)
                i = wp.min(int(sx), light.width - 1)
                j = wp.min(int(sy), light.height - 1)
                texel = j * light.width + i
                group = C.SORT_NOT_TRACED
                tri = rsm_tri[texel]
                in_window = sx >= skip_window[0] and sx < skip_window[2] and sy >= skip_window[1] and sy < skip_window[3]
                if tri >= 0 and not in_window and rsm_roughness[texel] <= roughness_cutoff:
                    if luminance(rsm_flux[texel]) >= luminance_cutoff * cascade.texel_scale * max_lum[0]:
                        group = C.SORT_REFLECTED
                        m = triangle_material[tri]
                        if mat_opacity[m] < 1.0:
                            lo, ld = pixel_ray_world(light, sx, sy)
                            d_in = wp.normalize(ld)
                            if light_kind != 0:
                                d_in = wp.normalize(rsm_position[texel] - light_pos)
                            n = rsm_normal[texel]
                            eta = rsm_ior[texel]
                            if wp.dot(d_in, n) > 0.0:
                                n = -n
                                eta = 1.0 / eta
                            state = wp.rand_init(rnd[2], k)
                            if wp.randf(state) >= fresnel_dielectric(-wp.dot(d_in, n), eta):
                                group = C.SORT_REFRACTED
            keys[t] = group
    packed = wp.tile_sum(wp.tile(C._group_count_bit(group)))
    if lane == 0:
        blocks = block_counts.shape[0] / C.SORT_GROUPS
        c = packed[0]
        mask = (1 << C.SORT_COUNT_BITS) - 1
        rest = wp.min(n_slots - block * bd, bd)
        for g in range(C.SORT_GROUPS - 1):
            n_g = (c >> (C.SORT_COUNT_BITS * g)) & mask
            block_counts[g * blocks + block] = n_g
            rest -= n_g
        block_counts[(C.SORT_GROUPS - 1) * blocks + block] = rest


#: main's per-thread sums: every ledger entry (15 × 3 float64)
AllSums = wp.types.matrix(shape=(C.LEDGER_ENTRIES, 3), dtype=wp.float64)


@wp.kernel(module="unique")
def outcomes_one_a_step(
    outcome: wp.array(dtype=wp.vec4), count: int, threads: int, entries: int, ledger: wp.array(dtype=wp.vec3d),
    states: wp.array(dtype=CascadeState), view_index: int, light_photons: int, run: int,
):
    """Main's ledger_add_outcomes (7704868): one record a loop step, over every slot, one block sum per entry."""
    block, lane = wp.tid()
    n_photons = cascade_photons(states[view_index], light_photons)
    t = block * wp.block_dim() + lane
    sums = AllSums()
    r = t
    while r < count:
        if r % run >= n_photons:
            r += threads
            continue
        o = outcome[r]
        code = int(o[3])
        p = wp.vec3d(wp.float64(o[0]), wp.float64(o[1]), wp.float64(o[2]))
        for e in range(C.LEDGER_ENTRIES):
            if ((C.FINAL_ENTRIES >> e) & 1) != 0 and code == e:
                sums[e] = sums[e] + p
        r += threads
    for e in range(C.LEDGER_ENTRIES):
        if ((C.FINAL_ENTRIES >> e) & 1) != 0 and ((entries >> e) & 1) != 0:
            wp.tile_atomic_add(ledger, wp.tile_sum(wp.tile(sums[e], preserve_type=True)),
                               offset=C.ledger_slot(ledger, block, e))


@wp.kernel(module="unique")
def outcomes_no_block_sums(
    outcome: wp.array(dtype=wp.vec4), count: int, threads: int, entries: int, ledger: wp.array(dtype=wp.vec3d),
    states: wp.array(dtype=CascadeState), view_index: int, light_photons: int, run: int,
):
    """ledger_add_outcomes' loop (four records a step) without the block sums: each thread's sums written only
    when ``entries`` is negative (never here), so the loop is not compiled away."""
    block, lane = wp.tid()
    n_photons = cascade_photons(states[view_index], light_photons)
    t = block * wp.block_dim() + lane
    sa = C.OutcomeSums()
    sb = C.OutcomeSums()
    end = wp.min(count, ((count - 1) / run) * run + wp.min(n_photons, run))
    one_run = wp.where(count <= run, 1, 0)
    r = t
    while r < end:
        o0 = C._outcome_at(outcome, r, end, run, n_photons, one_run, 0)
        o1 = C._outcome_at(outcome, r + threads, end, run, n_photons, one_run, 0)
        o2 = C._outcome_at(outcome, r + 2 * threads, end, run, n_photons, one_run, 0)
        o3 = C._outcome_at(outcome, r + 3 * threads, end, run, n_photons, one_run, 0)
        sa, sb = C._outcome_add(sa, sb, o0)
        sa, sb = C._outcome_add(sa, sb, o1)
        sa, sb = C._outcome_add(sa, sb, o2)
        sa, sb = C._outcome_add(sa, sb, o3)
        r += 4 * threads
    if entries < 0:
        for i in range(5):
            ledger[(2 * i) % ledger.shape[0]] = sa[i]
            ledger[(2 * i + 1) % ledger.shape[0]] = sb[i]


def timed(device, calls, reps: int, flush=None) -> float:
    """Median over ``reps`` runs (after a warm-up) of the GPU time of ``calls`` (a list of no-argument functions) run
    in turn: the kernels' own execution times from Warp's CUDA activity timing, summed (host launch gaps left out:
    they would dominate kernels of tens of µs); wall clock on the CPU. ``flush``: an array zeroed before each call
    (a memset, not timed), larger than the L2 cache, so that no call finds the last one's reads there."""
    times = []
    for rep in range(reps + 1):
        if device.is_cuda:
            wp.synchronize_device(device)
            wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
            for c in calls:
                if flush is not None:
                    flush.zero_()
                c()
            wp.synchronize_device(device)
            ms = sum(r.elapsed for r in wp.timing_end())
        else:
            t0 = time.perf_counter()
            for c in calls:
                c()
            ms = 1e3 * (time.perf_counter() - t0)
        if rep > 0:
            times.append(ms)
    return float(np.median(times))


def graph_ms(device, calls, reps: int, replays: int = 20) -> float:
    """Median over ``reps`` of the GPU time of one replay of ``calls`` captured as a CUDA graph (one after another
    on one stream, no host gaps, warm L2; CUDA events around ``replays`` replays): launches Warp does not time (CUB's
    scan kernels, its temporary allocation) are in it."""
    with wp.ScopedCapture(device=device, force_module_load=False) as cap:
        for c in calls:
            c()
    wp.capture_launch(cap.graph)
    times = []
    start, end = wp.Event(device, enable_timing=True), wp.Event(device, enable_timing=True)
    for _ in range(reps):
        wp.record_event(start)
        for _ in range(replays):
            wp.capture_launch(cap.graph)
        wp.record_event(end)
        wp.synchronize_device(device)
        times.append(wp.get_event_elapsed_time(start, end) / replays)
    return float(np.median(times))


def run_scene(name: str, args, device) -> None:
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.photons.base import morton_sort_bits
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.usd import load_usd

    if not os.path.exists(SCENES[name]):
        raise SystemExit(f"bench_order: {SCENES[name]} not found")
    scene = load_usd(SCENES[name], width=args.width, height=args.height, device=device)
    settings = RenderSettings(rsm_size=args.rsm, method="cisp", denoiser="none",
                              photons=PhotonSettings(photons=args.n_photons, sort_photons=True))
    r = Renderer(scene, settings, device=device)
    r.use_graph = False
    r.photons.FOLDED_OUTCOMES = False  # the outcome pass launched (and replayed below): the trace writes the records
    r.photons.OUTCOMES6 = False  # the frame's pass is the twin (ledger_add_outcomes); section 88's is a variant below
    for lm in r.lights:  # main's copies below read the RSM's position, normal, flux, roughness and IOR, which the
        lm.keep_surface_maps()  # views no longer keep (perf_notes sections 43 and 58)
        lm.keep_texel_maps()
    for _ in range(3):
        r.render_frame()
    P = r.photons
    kept = []
    launch_tiled = wp.launch_tiled
    scan = wp.utils.array_scan
    order_kernels = (C.photon_group_keys, C.photon_group_scatter, C.ledger_add_outcomes)

    def keep(kernel, dim, block_dim, device, inputs):
        launch_tiled(kernel, dim=dim, block_dim=block_dim, device=device, inputs=inputs)
        if kernel in order_kernels:
            kept.append((kernel, dim, block_dim, list(inputs)))

    def keep_scan(a, b, inclusive=True):
        scan(a, b, inclusive=inclusive)
        kept.append(("scan", a, b, inclusive))

    wp.launch_tiled, wp.utils.array_scan = keep, keep_scan
    try:
        r.render_frame()
    finally:
        wp.launch_tiled, wp.utils.array_scan = launch_tiled, scan
    wp.synchronize_device(device)
    # the group counts' scans: the one after each photon_group_keys (the frame scans other arrays too)
    scans = [kept[i + 1] for i, k in enumerate(kept[:-1]) if k[0] is C.photon_group_keys and kept[i + 1][0] == "scan"]
    kept = [k for k in kept if k[0] != "scan"]

    keys_args = [a.label for a in C.photon_group_keys.adj.args]
    at = {n: i for i, n in enumerate(keys_args)}
    views = []  # per view: (group_keys, scatter, outcome) launches, in the frame's order
    gk = [k for k in kept if k[0] is C.photon_group_keys]
    sc = [k for k in kept if k[0] is C.photon_group_scatter]
    oc = [k for k in kept if k[0] is C.ledger_add_outcomes]
    for g, s, o, sn in zip(gk, sc, oc, scans):
        states, vi, stream, slots = (g[3][at[a]] for a in ("states", "view_index", "stream", "n_slots"))
        lm = next(lm for lm in P.lights if lm.states.ptr == states.ptr)
        rv = lm.rsm[vi]
        # this view's per-frame order (main's): the frame's rotated points by their Morton code's top bits
        mkeys = wp.zeros(2 * slots, dtype=wp.int32, device=device)
        morder = wp.zeros(2 * slots, dtype=wp.int32, device=device)
        wp.launch(C.photon_sort_keys, dim=slots, device=device, inputs=[
            lm.views, lm.states, vi, P.settings.photons, P.inputs.randoms, stream, mkeys, morder])
        begin, end = morton_sort_bits(min(max(rv.width, rv.height), 1 << 14))
        wp.utils.radix_sort_pairs(mkeys, morder, slots, begin_bit=begin, end_bit=end)
        gi = list(g[3])
        chained = [gi[at["views"]], gi[at["states"]], vi, gi[at["light_photons"]], int(lm.light.kind),
                   wp.vec3(*np.asarray(lm.light.position, np.float32)), gi[at["randoms"]], stream,
                   rv.specular.position, rv.specular.normal, rv.flux, rv.specular.roughness,
                   rv.specular.ior, gi[at["rsm_tri"]], gi[at["triangle_material"]], gi[at["mat_opacity"]],
                   gi[at["max_lum"]], gi[at["roughness_cutoff"]], gi[at["luminance_cutoff"]], gi[at["order"]],
                   gi[at["order_stride"]], gi[at["orders"]], slots, gi[at["keys"]], gi[at["block_counts"]]]
        chained_nopos = list(chained)
        chained_nopos[4] = 0  # as a distant light: the direction from the light ray, no position read
        chained_frame = list(chained)
        chained_frame[19:22] = [morder, 0, 1]
        frame_order = list(gi)
        frame_order[at["order"]], frame_order[at["order_stride"]], frame_order[at["orders"]] = morder, 0, 1
        scatter_frame = list(s[3])
        scatter_frame[4:7] = [morder, 0, 1]
        tiles = gi[at["block_counts"]].shape[0] // C.SORT_GROUPS
        slow_outcome = list(o[3])
        slow_outcome[-1] = 0  # FAST_OUTCOMES off: the two tile sums, an inactive view's blocks run
        fast_outcome = list(o[3])
        fast_outcome[-1] = 1  # section 77's, 4-byte loads
        wide_outcome = list(o[3])
        wide_outcome[-1] = 1 | int(C.OUTCOME_WIDE)  # section 88: 16-byte loads
        # section 88's six-entry pass: three blocks an SM where the twin launched two, 16-byte loads
        dim6 = max(1, o[1] * C.OUTCOME6_BLOCKS_PER_SM // C.OUTCOME_BLOCKS_PER_SM)
        six_outcome = list(o[3])
        six_outcome[2] = dim6 * o[2]
        six_outcome[-1] = 1 | int(C.OUTCOME_WIDE)
        tile_keys = list(g[3])
        tile_keys[-1] = 0  # BALLOT_GROUPS off: Warp's tile sum and scan (the twin)
        tile_scatter = list(s[3])
        tile_scatter[-1] = 0
        views.append({"vi": vi, "light": P.lights.index(lm), "tiles": tiles, "g": g, "s": s, "o": o, "frame_order": frame_order,
                      "chained": chained, "chained_nopos": chained_nopos, "chained_frame": chained_frame, "scatter_frame": scatter_frame,
                      "scan": sn, "o_slow": slow_outcome, "o_fast": fast_outcome, "o_wide": wide_outcome,
                      "tile_keys": tile_keys, "tile_scatter": tile_scatter,
                      "o6": (C.ledger_add_outcomes6, dim6, o[2], six_outcome)})

    def L(kernel, dim, bd, inputs):
        return lambda: launch_tiled(kernel, dim=dim, block_dim=bd, device=device, inputs=inputs)

    rows = {}
    flush = wp.zeros(48 << 20, dtype=wp.float32, device=device) if device.is_cuda else None  # 192 MB > L2

    def variant(label, per_view):
        total = timed(device, [c for v in views for c in per_view(v)], args.reps, flush)
        each = [timed(device, per_view(v), args.reps, flush) for v in views]
        rows[label] = (total, each)

    variant("group_keys: frame", lambda v: [L(*v["g"][:3], v["g"][3])])
    variant("group_keys: tile sums (before section 88)", lambda v: [L(*v["g"][:3], v["tile_keys"])])
    variant("group_keys: per-frame order", lambda v: [L(*v["g"][:3], v["frame_order"])])
    # main's kernel: one block a tile (the frame's launch has fewer blocks, each over many tiles)
    variant("group_keys: chained reads", lambda v: [L(group_keys_chained, v["tiles"], v["g"][2], v["chained"])])
    variant("group_keys: chained, no position", lambda v: [L(group_keys_chained, v["tiles"], v["g"][2], v["chained_nopos"])])
    variant("group_keys: chained + per-frame (main)",
            lambda v: [L(group_keys_chained, v["tiles"], v["g"][2], v["chained_frame"])])
    variant("scatter: frame (after its keys)", lambda v: [L(*v["g"][:3], v["g"][3]), L(*v["s"][:3], v["s"][3])])
    variant("scatter: per-frame order (after its keys)",
            lambda v: [L(*v["g"][:3], v["frame_order"]), L(*v["s"][:3], v["scatter_frame"])])
    variant("scatter: tile scan (before section 88, after its keys)",
            lambda v: [L(*v["g"][:3], v["tile_keys"]), L(*v["s"][:3], v["tile_scatter"])])
    variant("outcomes: six entries, 3 blocks an SM, 16-byte loads (section 88)", lambda v: [L(*v["o6"])])
    variant("outcomes: 16-byte loads (section 88)", lambda v: [L(*v["o"][:3], v["o_wide"])])
    variant("outcomes: fast (section 77)", lambda v: [L(*v["o"][:3], v["o_fast"])])
    variant("outcomes: tile sums (section 40/63)", lambda v: [L(*v["o"][:3], v["o_slow"])])
    variant("outcomes: one record a step (main)", lambda v: [L(outcomes_one_a_step, *v["o"][1:3], v["o"][3][:-1])])
    variant("outcomes: no block sums", lambda v: [L(outcomes_no_block_sums, *v["o"][1:3], v["o"][3][:-1])])
    if device.is_cuda:  # the chains as the frame's graph replays them: CUB's scan kernels and allocation included
        for label, per_view in (
                ("chain: keys + array_scan + scatter", lambda v: [L(*v["g"][:3], v["g"][3]),
                                                                        lambda v=v: scan(*v["scan"][1:]),
                                                                        L(*v["s"][:3], v["s"][3])]),
                ("chain: outcomes, tile sums", lambda v: [L(*v["o"][:3], v["o_slow"])]),
                ("chain: outcomes, fast", lambda v: [L(*v["o"][:3], v["o_fast"])])):
            total = graph_ms(device, [c for v in views for c in per_view(v)], args.reps)
            each = [graph_ms(device, per_view(v), args.reps) for v in views]
            rows[label + " [graph]"] = (total, each)
    print(f"{name} {args.width}x{args.height}, RSM {args.rsm}², {args.n_photons:,} photons per light, {device}: "
          f"ms per frame, median of {args.reps} (per view: light/view)")
    head = "  ".join(f"{v['light']}/{v['vi']:<6}" for v in views)
    print(f"  {'variant':44s} {'frame':>8s}   {head}")
    for label, (total, each) in rows.items():
        print(f"  {label:44s} {total:8.4f}   " + "  ".join(f"{x:8.4f}" for x in each))


def main(argv=None) -> int:
    return scene_bench_main("bench_order", __doc__, run_scene, 20, argv)


if __name__ == "__main__":
    sys.exit(main())
