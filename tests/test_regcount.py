"""tools/regcount.py reads registers per thread from the sm_90 cubin that Warp's NVRTC builds without a GPU: a kernel
that keeps more values live must be reported with more registers."""

import sys
from pathlib import Path

import warp as wp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

import regcount  # noqa: E402

wp.set_module_options({"enable_backward": False})

vec24 = wp.types.vector(length=24, dtype=float)


@wp.kernel
def few_live_values(a: wp.array(dtype=float), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = a[i] * 2.0


@wp.kernel
def many_live_values(a: wp.array(dtype=float), n: int, out: wp.array(dtype=float)):
    i = wp.tid()
    v = vec24()  # 24 loads kept live through a loop of unknown length
    for k in range(24):
        v[k] = a[i + k]
    s = float(0.0)
    for j in range(n):
        for k in range(24):
            s = s * v[k] + v[k] * float(j)
    out[i] = s


def test_registers_from_the_cubin(tmp_path):
    cubin = regcount.compile_module(__name__, 128, 90, tmp_path)  # Warp's wheel carries NVRTC: no GPU needed
    usage = regcount.kernel_usage(cubin)
    few, many = usage["few_live_values"], usage["many_live_values"]
    assert 4 <= few["registers"] and few["registers"] + 24 <= many["registers"] <= 255  # the 24 live floats
    assert few["frame_bytes"] == 0
