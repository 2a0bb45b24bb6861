"""tools/regcount.py reads registers per thread from the sm_90 cubin that Warp's NVRTC builds without a GPU: a kernel
that keeps more values live must be reported with more registers; at a register bound that cannot hold them, its
local loads and stores must be found in the loop that spills them, attributed to the lines they come from."""

import inspect
import sys
from pathlib import Path

import pytest
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


@wp.kernel(launch_bounds=(128, 16))  # at most 32 registers: the 24 live floats spill
def many_live_values_bounded(a: wp.array(dtype=float), n: int, out: wp.array(dtype=float)):
    i = wp.tid()
    v = vec24()
    for k in range(24):
        v[k] = a[i + k]
    s = float(0.0)
    for j in range(n):
        for k in range(24):
            s = s * v[k] + v[k] * float(j)  # the line the spilled values are reloaded for
    out[i] = s


def test_registers_from_the_cubin(tmp_path):
    cubin = regcount.compile_module(__name__, 128, 90, tmp_path)  # Warp's wheel carries NVRTC: no GPU needed
    usage = regcount.kernel_usage(cubin)
    few, many = usage["few_live_values"], usage["many_live_values"]
    assert 4 <= few["registers"] and few["registers"] + 24 <= many["registers"] <= 255  # the 24 live floats
    assert few["frame_bytes"] == 0


@pytest.mark.skipif(regcount._cuda_tool("nvdisasm")[0] is None, reason="no nvdisasm (nvidia-cuda-nvdisasm wheel)")
def test_local_memory_found_in_the_loop_and_line_that_spill(tmp_path):
    cubin = regcount.compile_module(__name__, 128, 90, tmp_path, lineinfo=True)
    usage = regcount.kernel_usage(cubin)
    local = regcount.local_memory(cubin)
    assert usage["many_live_values_bounded"]["registers"] <= 32 < usage["many_live_values"]["registers"]
    assert local["few_live_values"] == [] and local["many_live_values"] == []
    ops = local["many_live_values_bounded"]
    assert {o["op"] for o in ops} == {"STL", "LDL"}
    lines, first = inspect.getsourcelines(many_live_values_bounded)
    body = first + next(i for i, text in enumerate(lines) if "the line the spilled values" in text)
    loads_in_loop = [o for o in ops if o["op"] == "LDL" and o["loop"] is not None]
    assert loads_in_loop and all(o["source"] for o in loads_in_loop)
    assert any(o["source"][-1] == f"test_regcount.py:{body}" for o in loads_in_loop)
