#!/usr/bin/env python
"""Benchmark the FFT water: time per ``FFTWater.evaluate(t)`` against numpy.fft, per grid size N.

For each N: median over ``--repeats`` timed frames after two warm-up frames, with
``wp.synchronize_device`` before and after each timed call. Columns:

- ``evaluate``: one whole frame (spectrum kernel, 2 ceil(log4 N) FFT stages, unpack kernel).
- ``warp fft``: the inverse FFT alone (4 packed complex fields).
- ``numpy.fft``: ``numpy.fft.ifft2`` of the same 4 complex64 fields, (4, N, N), on the host.

    python tools/bench_sim.py --device cpu --sizes 128,256,512,1024 --repeats 10
    python tools/bench_sim.py --smoke      # tiny sizes, seconds
"""

from __future__ import annotations

import argparse
import logging
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

from sim import FFTWater, WaterParams  # noqa: E402
from sim.water import PACKED_FIELDS  # noqa: E402

SMOKE_SIZES = (16, 32)
SMOKE_REPEATS = 3
WARM_UP_FRAMES = 2
FRAME_TIME = 1.0 / 60.0  # s between timed frames (only moves the phase; cost is the same)


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default=None,
                        help="Warp device, e.g. cpu or cuda:0 (default: Warp's default device)")
    parser.add_argument("--sizes", default="128,256,512,1024",
                        help="comma-separated FFT sizes N (powers of two)")
    parser.add_argument("--repeats", type=int, default=10, help="timed frames per size")
    parser.add_argument("--smoke", action="store_true",
                        help=f"quick check: sizes {SMOKE_SIZES}, {SMOKE_REPEATS} repeats")
    args = parser.parse_args(argv)
    if args.smoke:
        args.sizes, args.repeats = ",".join(map(str, SMOKE_SIZES)), SMOKE_REPEATS
    args.sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    if args.repeats < 1:
        parser.error("--repeats must be >= 1")
    return args


def median_seconds(step, repeats: int, device) -> float:
    """Median wall time of ``step(i)`` over ``repeats`` calls, device synchronised around each."""
    times = []
    for i in range(repeats):
        wp.synchronize_device(device)
        start = time.perf_counter()
        step(i)
        wp.synchronize_device(device)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def bench_size(n: int, repeats: int, device) -> dict:
    water = FFTWater(WaterParams(resolution=n), device)
    for i in range(WARM_UP_FRAMES):  # compiles/loads the modules, touches the memory
        water.evaluate(i * FRAME_TIME)
    evaluate_s = median_seconds(lambda i: water.evaluate(i * FRAME_TIME), repeats, device)
    fft_s = median_seconds(lambda i: water.fft.run(), repeats, device)

    rng = np.random.default_rng(0)
    fields = (rng.standard_normal((PACKED_FIELDS, n, n))
              + 1j * rng.standard_normal((PACKED_FIELDS, n, n))).astype(np.complex64)
    np.fft.ifft2(fields, axes=(1, 2))  # warm-up
    numpy_s = median_seconds(lambda i: np.fft.ifft2(fields, axes=(1, 2)), repeats, "cpu")
    return dict(n=n, launches=water.launches_per_frame, evaluate_s=evaluate_s, fft_s=fft_s,
                numpy_s=numpy_s)


def device_description(device) -> str:
    if device.is_cuda:
        return f"{device.alias} ({device.name})"
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            model = next(line.split(":", 1)[1].strip() for line in cpuinfo
                         if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{device.alias} ({model})"


def main(argv=None) -> int:
    args = parse_args(argv)
    wp.config.log_level = logging.WARNING  # no init banner or module-load lines
    wp.init()
    device = wp.get_device(args.device)
    print(f"sim benchmark: Warp {wp.config.version}, numpy {np.__version__}")
    print(f"device: {device_description(device)}; numpy.fft on the host CPU")
    print(f"median of {args.repeats} frames after {WARM_UP_FRAMES} warm-up; "
          f"{PACKED_FIELDS} packed complex fields (8 real fields)")
    header = (f"{'N':>6} {'launches':>9} {'evaluate ms':>12} {'warp fft ms':>12} "
              f"{'numpy.fft ms':>13} {'numpy/evaluate':>15}")
    print(header)
    print("-" * len(header))
    for n in args.sizes:
        r = bench_size(n, args.repeats, device)
        print(f"{r['n']:>6} {r['launches']:>9} {1e3 * r['evaluate_s']:>12.3f} "
              f"{1e3 * r['fft_s']:>12.3f} {1e3 * r['numpy_s']:>13.3f} "
              f"{r['numpy_s'] / r['evaluate_s']:>15.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
