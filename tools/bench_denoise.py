#!/usr/bin/env python3
"""Per-kernel cost of the denoisers (caustic, svgf, gather) on one camera G-buffer, and a check of the
device's kernels against the CPU's on a crop.

    python tools/bench_denoise.py --gbuffer out/ --device cuda:0          # AOV folder of cisp-render
    python tools/bench_denoise.py --gbuffer pool.npz --device cuda:0 --check
    python tools/bench_denoise.py --pack out/ pool.npz                   # compact G-buffer for carrying
    python tools/bench_denoise.py --smoke                                 # seconds, CPU: what the tests run

The G-buffer (``depth``, ``normal``, ``tri_id``, ``photon_map``; motion 0: a still camera) is a render's AOVs.
Each frame's photon map is the render's thinned at random (each pixel kept with probability 1/2 and doubled:
same mean, new noise), so the temporal stages see a static caustic with fresh noise, as in a still shot.
Per kernel: ms per frame from Warp's CUDA activity timing (``wp.timing_begin``), on the first frame (no
history: the caustics denoiser filters everywhere) and as the median of the frames after ``--warmup``.
On the CPU the whole ``denoise`` call is timed with a synchronised wall clock instead.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import defaultdict

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

KEYS = ("depth", "normal", "tri_id", "photon_map")


def load_gbuffer(path: str) -> dict[str, np.ndarray]:
    """``path``: a folder of ``NAME.npy`` AOVs or an ``.npz`` written by ``--pack``; float32 / int32 arrays."""
    if path.endswith(".npz"):
        with np.load(path) as f:
            g = {k: f[k] for k in f.files}
    else:
        g = {k: np.load(os.path.join(path, f"{k}.npy")) for k in KEYS}
    g["depth"] = g["depth"].astype(np.float32)
    g["normal"] = g["normal"].astype(np.float32)
    g["photon_map"] = g["photon_map"].astype(np.float32)
    g["tri_id"] = g["tri_id"].astype(np.int32) if "tri_id" in g else np.where(g["depth"] > 0, 0, -1).astype(np.int32)
    return g


def pack(folder: str, out: str) -> None:
    """Write the G-buffer of an AOV folder compactly (normals and photon map as float16; tri_id as hit/miss)."""
    g = load_gbuffer(folder)
    np.savez_compressed(out, depth=g["depth"], normal=g["normal"].astype(np.float16),
                        photon_map=g["photon_map"].astype(np.float16), tri_id=np.where(g["tri_id"] >= 0, 0, -1).astype(np.int8))
    print(f"wrote {out} ({os.path.getsize(out) / 2**20:.1f} MiB)")


def synthetic(width: int, height: int) -> dict[str, np.ndarray]:
    """A tilted plane with a band of sky and a sparse photon map (tests and --smoke)."""
    rng = np.random.default_rng(0)
    x = np.arange(width)[None, :].repeat(height, 0)
    depth = (2.0 + 0.01 * x).astype(np.float32)
    depth[: height // 5] = 0.0
    normal = np.broadcast_to(np.array([0.0, 0.0, 1.0], np.float32), (height, width, 3)).copy()
    pm = ((rng.random((height, width)) < 0.2) * 40.0)[..., None] * np.ones(3, np.float32)
    pm[depth <= 0] = 0.0
    return dict(depth=depth, normal=normal, tri_id=np.where(depth > 0, 0, -1).astype(np.int32), photon_map=pm)


class Bench:
    """One denoiser on device arrays of the G-buffer, with ``variants`` thinned photon maps to cycle through."""

    def __init__(self, name: str, g: dict, device, variants: int = 4, seed: int = 0):
        import warp as wp

        from cisp_warp import denoise as D

        h, w = g["depth"].shape
        self.w, self.h, self.name, self.device = w, h, name, device
        rng = np.random.default_rng(seed)
        maps = [(g["photon_map"] * (2.0 * (rng.random((h, w)) < 0.5))[..., None]).astype(np.float32) for _ in range(variants)]
        self.maps = [wp.array(m.reshape(-1, 3), dtype=wp.vec3, device=device) for m in maps]
        # the photon pass's Σ luminance(e)² per pixel: each lit pixel holds one photon (grey, so luminance = e)
        self.m2s = [wp.array((m[..., 1] ** 2).reshape(-1), dtype=wp.float32, device=device) for m in maps]
        self.depth = wp.array(g["depth"].reshape(-1), dtype=wp.float32, device=device)
        self.normal = wp.array(g["normal"].reshape(-1, 3), dtype=wp.vec3, device=device)
        self.tri_id = wp.array(g["tri_id"].reshape(-1), dtype=wp.int32, device=device)
        self.motion = wp.zeros(w * h, dtype=wp.vec2, device=device)
        self.out = wp.zeros(w * h, dtype=wp.vec3, device=device)
        if name == "caustic":
            self.den = D.CausticDenoiser(w, h, device)
        elif name == "caustic_pixel":  # the gated levels per pixel (three launches a level) instead of tiled
            self.den = D.CausticDenoiser(w, h, device, levels="pixel")
        elif name == "svgf":
            self.den = D.SVGF(w, h, device)
        elif name == "gather":
            self.den = D.GaussianGather(w, h, device)
        else:
            raise SystemExit(f"unknown denoiser {name!r}: caustic, caustic_pixel, svgf, gather")
        self.frame = 0

    def step(self) -> None:
        e = self.maps[self.frame % len(self.maps)]
        if self.name == "gather":
            self.den.apply(e, self.depth, self.normal, self.tri_id, self.out)
        elif self.name == "caustic":
            self.den.denoise(e, self.depth, self.normal, self.motion, self.tri_id, self.out,
                             self.m2s[self.frame % len(self.m2s)])
        else:
            self.den.denoise(e, self.depth, self.normal, self.motion, self.tri_id, self.out)
        self.frame += 1


def time_kernels(bench: Bench, frames: int, warmup: int) -> tuple[dict, dict]:
    """({kernel: ms on the first frame}, {kernel: median ms per frame after ``warmup``}); on the CPU one
    entry, ``denoise`` (wall clock)."""
    import warp as wp

    d = wp.get_device(bench.device)
    first, later = {}, defaultdict(list)
    for f in range(frames):
        if d.is_cuda:
            wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
            bench.step()
            per = defaultdict(float)
            levels = 0  # atrous_level* launches so far; a level's guide pass (if any) comes just before it
            for r in wp.timing_end():
                name = r.name.replace("forward kernel ", "")
                per[name] += r.elapsed
                if name.startswith(("atrous_level", "atrous_guide")):  # each level's share too
                    per[f"  level {levels}"] += r.elapsed
                    levels += name.startswith("atrous_level")
            per["total"] = sum(v for k, v in per.items() if not k.startswith("  level"))
        else:
            t0 = time.perf_counter()
            bench.step()
            wp.synchronize_device(d)
            per = {"total": 1e3 * (time.perf_counter() - t0)}
        if f == 0:
            first = dict(per)
        elif f >= warmup:
            for k, v in per.items():
                later[k].append(v)
    return first, {k: float(np.median(v)) for k, v in later.items()}


def check_crop(g: dict, device, names: list[str], size: int = 192, frames: int = 3) -> list[str]:
    """Run each denoiser for ``frames`` frames on a ``size``² crop on ``device`` and on the CPU; report the
    largest difference relative to the image's largest value."""
    import warp as wp

    h, w = g["depth"].shape
    y0, x0 = max((h - size) // 2, 0), max((w - size) // 2, 0)
    crop = {k: np.ascontiguousarray(v[y0:y0 + size, x0:x0 + size]) for k, v in g.items()}
    lines = []
    for name in names:
        outs = []
        for dev in (device, "cpu"):
            b = Bench(name, crop, dev)
            for _ in range(frames):
                b.step()
            wp.synchronize_device(dev)
            outs.append(b.out.numpy().astype(np.float64))
        scale = max(np.abs(outs[1]).max(), 1e-30)
        lines.append(f"{name}: {size}x{size} crop, {frames} frames, max |device - cpu| / max = "
                     f"{np.abs(outs[0] - outs[1]).max() / scale:.2e}")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--gbuffer", action="append", default=[], help="AOV folder or .npz (repeatable)")
    p.add_argument("--pack", nargs=2, metavar=("FOLDER", "OUT_NPZ"), help="write a compact .npz of an AOV folder and exit")
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--denoisers", default="caustic,svgf,gather",
                   help="comma-separated: caustic, caustic_pixel (its levels per pixel), svgf, gather")
    p.add_argument("--frames", type=int, default=24, help="frames per denoiser")
    p.add_argument("--warmup", type=int, default=16, help="frames before the steady-state median")
    p.add_argument("--check", action="store_true", help="also compare the device's output with the CPU's on a crop")
    p.add_argument("--smoke", action="store_true", help="a 96x64 synthetic G-buffer, 4 frames, on the CPU")
    p.add_argument("--max-unroll", type=int, default=None,
                   help="Warp's loop-unrolling limit for the denoise kernels (default Warp's, 16: the 5x5 taps unrolled)")
    p.add_argument("--fast-math", action="store_true", help="compile the denoise kernels with fast math (approximate exp/log/div)")
    p.add_argument("--lattice-step", type=int, default=None,
                   help="SVGF and caustic: the smallest step whose level reads sub-lattice-major buffers (default "
                        "kernels_atrous.LATTICE_STEP; 0: none)")
    args = p.parse_args(argv)
    if args.pack:
        pack(*args.pack)
        return 0
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    from cisp_warp.denoise import kernels_atrous, kernels_caustic, kernels_svgf

    for module in (kernels_atrous, kernels_caustic, kernels_svgf):
        if args.max_unroll is not None:
            wp.set_module_options({"max_unroll": args.max_unroll}, module=module)
        if args.fast_math:
            wp.set_module_options({"fast_math": True}, module=module)
    if args.lattice_step is not None:
        from cisp_warp.denoise import caustic, svgf

        kernels_atrous.LATTICE_STEP = svgf.LATTICE_STEP = caustic.LATTICE_STEP = \
            args.lattice_step if args.lattice_step > 0 else 1 << 30
    if args.smoke:
        args.device, args.frames, args.warmup = "cpu", 4, 2
    device = args.device or wp.get_device().alias
    names = args.denoisers.split(",")
    sources = [(os.path.basename(s.rstrip("/")), load_gbuffer(s)) for s in args.gbuffer] or [("synthetic", synthetic(96, 64))]
    print(f"device {device} ({wp.get_device(device).name}), Warp {wp.config.version}; levels of step >= "
          f"{kernels_atrous.LATTICE_STEP} read sub-lattice-major")
    for label, g in sources:
        h, w = g["depth"].shape
        print(f"\n{label}: {w}x{h}, {100 * (g['depth'] > 0).mean():.1f}% of pixels with a surface; "
              f"{100 * (g['photon_map'][..., 1] > 0)[g['depth'] > 0].mean():.1f}% of those with photons")
        for name in names:
            first, steady = time_kernels(Bench(name, g, device), args.frames, args.warmup)
            print(f"  {name:<8} ms per frame: first {first['total']:.3f}, steady {steady.get('total', float('nan')):.3f}")
            for k in sorted(first, key=lambda k: -first[k]):
                if k != "total":
                    print(f"    {k:<28} first {first[k]:8.3f}   steady {steady.get(k, float('nan')):8.3f}")
        if args.check and wp.get_device(device).is_cuda:
            for line in check_crop(g, device, names):
                print("  check " + line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
