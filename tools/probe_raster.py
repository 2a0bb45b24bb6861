#!/usr/bin/env python3
"""Raster probe: every draw of one frame of a scene, replayed apart and timed per tile-raster kernel; work counts.

    python tools/probe_raster.py --device cuda:0 --scenes pool,cornell --json out.json
    python tools/probe_raster.py --device cpu --smoke          # tiny sizes: a check that it runs

Renders a few frames of ``cisp`` (the one-stream program), records the draws of the next frame (view, size, layers),
then replays each draw's set-up and times the tile-raster variants on it with CUDA events (``--reps`` launches each,
into scratch buffers: ``atomic_min`` does the same work whatever the buffers hold): ``raster_tiles`` (the naive twin),
``raster_tiles_reject`` (tiles, and rows, outside an edge skipped), ``raster_tiles_lockstep``; ablations: a thread per
(item, row), the item walk and search alone, a float32 key. Counts per draw: sub-triangles drawn, (sub-triangle, tile)
items, items with no covered pixel centre, pixel tests and fragments (covered, in depth range). The variants' buffers
are compared with the naive twin's (on CUDA they may differ by FMA contraction: the count of differing keys).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
import warp as wp

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _make_counter():
    from cisp_warp.raster import kernels as K

    @wp.kernel
    def count_items(sub_v: wp.array(dtype=wp.vec3), sub_bbox: wp.array(dtype=wp.vec4i),
                    tile_end: wp.array(dtype=wp.int32), n_sub: int, out: wp.array(dtype=wp.int32)):
        item = wp.tid()
        s, i_lo, i_hi, j_lo, j_hi = K._tile_of_item(tile_end, n_sub, sub_bbox, item)
        a = sub_v[3 * s + 0]
        b = sub_v[3 * s + 1]
        c = sub_v[3 * s + 2]
        cov = int(0)
        for j in range(j_lo, j_hi + 1):
            y = float(j) + 0.5
            for i in range(i_lo, i_hi + 1):
                x = float(i) + 0.5
                if K._shared_edge(b, c, x, y) >= 0.0 and K._shared_edge(c, a, x, y) >= 0.0 and K._shared_edge(a, b, x, y) >= 0.0:
                    cov += 1
        out[2 * item] = (i_hi - i_lo + 1) * (j_hi - j_lo + 1)
        out[2 * item + 1] = cov

    @wp.kernel
    def search_only(views: wp.array(dtype=K.ViewParams), view_index: int, sub_v: wp.array(dtype=wp.vec3),
                    sub_bbox: wp.array(dtype=wp.vec4i), tile_end: wp.array(dtype=wp.int32), n_sub: int, stride: int,
                    layers: wp.array(dtype=wp.int32), mask: int, visibility: wp.array(dtype=wp.uint64), mask_b: int,
                    visibility_b: wp.array(dtype=wp.uint64)):
        """Ablation: raster_tiles' item walk and binary search alone (one write per thread)."""
        item = wp.tid()
        t = item
        total = tile_end[n_sub - 1]
        acc = int(0)
        while item < total:
            s, i_lo, i_hi, j_lo, j_hi = K._tile_of_item(tile_end, n_sub, sub_bbox, item)
            acc += s + i_lo + j_hi
            item += stride
        if acc == -12345:
            visibility[t] = wp.uint64(0)

    @wp.func
    def write_f32(view: K.ViewParams, a: wp.vec3, b: wp.vec3, c: wp.vec3, w0: float, w1: float, w2: float,
                  inv_area: float, tri: wp.uint64, to_a: bool, to_b: bool, p: int,
                  visibility: wp.array(dtype=wp.uint64), visibility_b: wp.array(dtype=wp.uint64)):
        depth = K.fragment_depth(view, a, b, c, w0, w1, w2, inv_area)
        if depth > 0.0 and depth <= view.far:
            key = (wp.uint64(depth * (4294967040.0 / view.far)) << wp.uint64(32)) | tri
            if to_a:
                wp.atomic_min(visibility, p, key)
            if to_b:
                wp.atomic_min(visibility_b, p, key)

    @wp.kernel
    def lockstep_f32key(views: wp.array(dtype=K.ViewParams), view_index: int, sub_v: wp.array(dtype=wp.vec3),
                        sub_bbox: wp.array(dtype=wp.vec4i), tile_end: wp.array(dtype=wp.int32), n_sub: int, stride: int,
                        layers: wp.array(dtype=wp.int32), mask: int, visibility: wp.array(dtype=wp.uint64), mask_b: int,
                        visibility_b: wp.array(dtype=wp.uint64), reject: int):
        """Ablation: raster_tiles_lockstep with a float32 key (not the same keys: what the float64 quotient costs)."""
        view = views[view_index]
        item = wp.tid()
        total = tile_end[n_sub - 1]
        width = view.width
        while item < total:
            s, i_lo, i_hi, j_lo, j_hi = K._tile_of_item(tile_end, n_sub, sub_bbox, item)
            item += stride
            a = sub_v[3 * s + 0]
            b = sub_v[3 * s + 1]
            c = sub_v[3 * s + 2]
            e0 = K._edge_terms(b, c)
            e1 = K._edge_terms(c, a)
            e2 = K._edge_terms(a, b)
            if reject != 0:
                box = wp.vec4i(i_lo, j_lo, i_hi, j_hi)
                if (K._box_outside(e0, K._edge_slack(e0, box), box) or K._box_outside(e1, K._edge_slack(e1, box), box)
                        or K._box_outside(e2, K._edge_slack(e2, box), box)):
                    continue
            inv_area = 1.0 / K._edge(a, b, c[0], c[1])
            tri = wp.uint64(s / 2)
            tri_layers = layers[s / 2]
            to_a = (tri_layers & mask) != 0
            to_b = (tri_layers & mask_b) != 0
            i = i_lo
            j = j_lo
            while j <= j_hi:
                covered = bool(False)
                w0 = float(0.0)
                w1 = float(0.0)
                w2 = float(0.0)
                p = int(0)
                while j <= j_hi and not covered:
                    x = float(i) + 0.5
                    y = float(j) + 0.5
                    w0 = K._edge_at(e0, x, y)
                    w1 = K._edge_at(e1, x, y)
                    w2 = K._edge_at(e2, x, y)
                    covered = w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0
                    p = j * width + i
                    i += 1
                    if i > i_hi:
                        i = i_lo
                        j += 1
                if covered:
                    write_f32(view, a, b, c, w0, w1, w2, inv_area, tri, to_a, to_b, p, visibility, visibility_b)

    @wp.kernel
    def tile_rows(views: wp.array(dtype=K.ViewParams), view_index: int, sub_v: wp.array(dtype=wp.vec3),
                  sub_bbox: wp.array(dtype=wp.vec4i), tile_end: wp.array(dtype=wp.int32), n_sub: int, stride: int,
                  layers: wp.array(dtype=wp.int32), mask: int, visibility: wp.array(dtype=wp.uint64), mask_b: int,
                  visibility_b: wp.array(dtype=wp.uint64)):
        """Ablation: a thread per (item, tile row), its own search, the row skipped when outside an edge."""
        view = views[view_index]
        t = wp.tid()
        total = tile_end[n_sub - 1]
        width = view.width
        while t < 8 * total:
            item = t / 8
            r = t - item * 8
            t += stride
            s, i_lo, i_hi, j_lo, j_hi = K._tile_of_item(tile_end, n_sub, sub_bbox, item)
            j = (j_hi / 8) * 8 + r
            if j < j_lo or j > j_hi:
                continue
            a = sub_v[3 * s + 0]
            b = sub_v[3 * s + 1]
            c = sub_v[3 * s + 2]
            e0 = K._edge_terms(b, c)
            e1 = K._edge_terms(c, a)
            e2 = K._edge_terms(a, b)
            box = wp.vec4i(i_lo, j_lo, i_hi, j_hi)
            slack0 = K._edge_slack(e0, box)
            slack1 = K._edge_slack(e1, box)
            slack2 = K._edge_slack(e2, box)
            x0 = float(i_lo) + 0.5
            x1 = float(i_hi) + 0.5
            y = float(j) + 0.5
            if (K._row_outside(e0, slack0, y, x0, x1) or K._row_outside(e1, slack1, y, x0, x1)
                    or K._row_outside(e2, slack2, y, x0, x1)):
                continue
            inv_area = 1.0 / K._edge(a, b, c[0], c[1])
            tri = wp.uint64(s / 2)
            tri_layers = layers[s / 2]
            to_a = (tri_layers & mask) != 0
            to_b = (tri_layers & mask_b) != 0
            for i in range(i_lo, i_hi + 1):
                x = float(i) + 0.5
                w0 = K._edge_at(e0, x, y)
                w1 = K._edge_at(e1, x, y)
                w2 = K._edge_at(e2, x, y)
                if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
                    K.write_fragment(view, a, b, c, w0, w1, w2, inv_area, tri, to_a, to_b, j * width + i, visibility,
                                     visibility_b)

    return count_items, search_only, lockstep_f32key, tile_rows


def probe_scene(scene_path, args, device):
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.raster import kernels as K
    from cisp_warp.raster.rasterizer import Rasterizer
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.usd import load_usd

    scene = load_usd(scene_path, width=args.width, height=args.height, device=device)
    settings = RenderSettings(rsm_size=args.rsm_size, method="cisp", photons=PhotonSettings(photons=args.photons),
                              denoiser="svgf")
    r = Renderer(scene, settings, device=device)
    r.set_concurrent(False)
    r.use_graph = False
    for _ in range(3):
        r.render_frame()
    calls = []
    orig_draw = Rasterizer.draw

    def rec(self, views, view_index, width, height, layer, visibility, clear=True, layer_b=0, visibility_b=None):
        calls.append((self, views, view_index, width, height, layer, layer_b))
        return orig_draw(self, views, view_index, width, height, layer, visibility, clear, layer_b, visibility_b)

    Rasterizer.draw = rec
    try:
        r.render_frame()
    finally:
        Rasterizer.draw = orig_draw
    wp.synchronize_device(device)
    counter, search_only, f32key, tile_rows = _make_counter()
    rows = []
    for (raster, views, vi, w, h, layer, layer_b) in calls:
        far = float(views.list()[vi].far)
        n_sub = 2 * raster.scene.triangle_count
        raster._setup(views, vi, w, h, layer | layer_b, back_only=False)
        total = int(raster.tile_end.numpy()[-1])
        row = {"size": f"{w}x{h}", "layer": layer, "layer_b": layer_b, "active": far > 0.0, "items": total,
               "subs": int((raster.tile_count.numpy() > 0).sum())}
        if total > 0:
            cnt = wp.zeros(2 * total, dtype=wp.int32, device=device)
            wp.launch(counter, dim=total, device=device, inputs=[raster.sub_v, raster.sub_bbox, raster.tile_end, n_sub, cnt])
            c = cnt.numpy().reshape(-1, 2)
            row.update(pixel_tests=int(c[:, 0].sum()), covered=int(c[:, 1].sum()),
                       empty_items=int((c[:, 1] == 0).sum()))
        bufs = [wp.full(w * h, K.EMPTY_KEY_VALUE, dtype=wp.uint64, device=device) for _ in range(2)]
        s = raster.scene
        variants = {"raster_tiles": (K.raster_tiles, []), "reject": (K.raster_tiles_reject, [0]),
                    "reject_rows": (K.raster_tiles_reject, [1]), "lockstep_reject": (K.raster_tiles_lockstep, [1]),
                    "tile_rows": (tile_rows, []), "search_only": (search_only, []), "f32key_reject": (f32key, [1])}
        ref = None
        for name, (kern, extra) in variants.items():
            for b in bufs:
                b.fill_(K.EMPTY_KEY_VALUE)
            inputs = [views, int(vi), raster.sub_v, raster.sub_bbox, raster.tile_end, n_sub, raster.stride,
                      s.triangle_layers, int(layer), bufs[0], int(layer_b), bufs[1]] + extra
            wp.launch(kern, dim=raster.stride, device=device, inputs=inputs)
            out = [b.numpy().copy() for b in bufs]
            if ref is None:
                ref = out
            else:
                row[f"{name}_diff_keys"] = int(sum((x != y).sum() for x, y in zip(ref, out)))
                low = np.uint64(0xFFFFFFFF)
                row[f"{name}_diff_tri"] = int(sum(((x & low) != (y & low)).sum() for x, y in zip(ref, out)))
            if device.is_cuda:  # a graph of `reps` launches, replayed: no host launch overhead in the time
                wp.capture_begin(device, force_module_load=False)
                try:
                    for _ in range(args.reps):
                        wp.launch(kern, dim=raster.stride, device=device, inputs=inputs)
                finally:
                    graph = wp.capture_end(device)
                wp.capture_launch(graph)
                e0, e1 = wp.Event(device, enable_timing=True), wp.Event(device, enable_timing=True)
                wp.record_event(e0)
                wp.capture_launch(graph)
                wp.record_event(e1)
                wp.synchronize_device(device)
                row[f"{name}_ms"] = round(wp.get_event_elapsed_time(e0, e1) / args.reps, 5)
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", default="pool,cornell")
    p.add_argument("--device", default=None)
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--rsm-size", type=int, default=2048)
    p.add_argument("--photons", type=int, default=2_000_000)
    p.add_argument("--reps", type=int, default=10)
    p.add_argument("--smoke", action="store_true")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.rsm_size, args.photons, args.reps = 64, 36, 64, 2000, 1
    wp.init()
    sys.path.insert(0, ROOT)
    device = wp.get_device(args.device)
    names = {"pool": "pool.usda", "cornell": "cornell_flooded.usda"}
    report = {}
    for sname in args.scenes.split(","):
        print(f"== {sname}", flush=True)
        report[sname] = probe_scene(os.path.join(ROOT, "scenes_usd", names.get(sname, sname)), args, device)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
