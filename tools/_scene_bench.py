"""The command line the per-scene GPU probes share (``tools/trace_ablate.py``, ``tools/bench_order.py``): the shipped
scenes by name, the full-size defaults (1920x1080, RSM 2048², 2M photons per light), ``--smoke`` for a tiny run, and
one sentence for bad input."""

from __future__ import annotations

import argparse
import os
import sys
from typing import Callable

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)
SCENES = {"cornell": os.path.join(ROOT, "scenes_usd", "cornell_flooded.usda"),
          "pool": os.path.join(ROOT, "scenes_usd", "pool.usda")}


def scene_bench_main(prog: str, doc: str, run_scene: Callable, reps: int, argv=None) -> int:
    """Parse the shared options and call ``run_scene(name, args, device)`` for every scene asked for.
    ``args.n_photons`` holds the parsed photon count; ``reps`` is the default of ``--reps``."""
    import warp as wp

    p = argparse.ArgumentParser(prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", default="cornell,pool", help="comma-separated: cornell, pool (default both)")
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--rsm", type=int, default=2048)
    p.add_argument("--photons", default="2M", help="photons per light (default 2M)")
    p.add_argument("--reps", type=int, default=reps, help=f"timed replays per variant (default {reps})")
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--smoke", action="store_true", help="tiny (96x54, RSM 64, 4k photons, 2 reps)")
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.rsm, args.photons, args.reps = 96, 54, 64, "4k", 2
    from cisp_warp.cli import parse_count

    try:
        args.n_photons = parse_count(args.photons)
    except Exception as e:  # noqa: BLE001 - one sentence for bad input
        raise SystemExit(f"{prog}: {e}")
    names = [s.strip() for s in args.scenes.split(",")]
    for s in names:
        if s not in SCENES:
            raise SystemExit(f"{prog}: unknown scene {s!r}: {', '.join(SCENES)}")
    wp.config.quiet = True
    wp.init()
    device = wp.get_device(args.device)
    for s in names:
        run_scene(s, args, device)
    return 0
