"""Tests of sim settings: WaterParams validation and round trip, choose_lod, the benchmark tool."""

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from sim import SimParameterError, WaterParams, choose_lod, peak_wavelength

REPO = Path(__file__).resolve().parents[1]

BAD_PARAMS = [
    ("resolution", 100),
    ("resolution", 2),
    ("resolution", 8192),
    ("resolution", 64.0),
    ("patch_size", 0.0),
    ("patch_size", -1.0),
    ("depth", 0.0),
    ("depth", -0.5),
    ("depth", float("nan")),
    ("wind_speed", float("nan")),
    ("wind_speed", float("inf")),
    ("wind_speed", 0.0),
    ("wind_direction", float("nan")),
    ("wind_direction", (0.0, 0.0)),
    ("fetch", -3.0),
    ("spectrum", "pierson"),
    ("amplitude", -1.0),
    ("small_wave_cutoff", float("inf")),
    ("choppiness", float("nan")),
    ("choppiness", -0.5),
    ("seed", -1),
    ("seed", 1.5),
    # upper bounds: each of these overflowed the spectrum or the kernels' float32 (fuzzer, issue 16)
    ("wind_speed", 1e300),
    ("wind_speed", 101.0),
    ("choppiness", 1e30),
    ("patch_size", 1e5),
    ("depth", 1e6),
    ("fetch", 1e300),
    ("amplitude", 1e20),
    ("small_wave_cutoff", 1e5),
    ("seed", 2**31),
    ("wind_direction", 1e300),
]


@pytest.mark.parametrize("name,value", BAD_PARAMS)
def test_bad_parameter_is_rejected_by_name(name, value):
    with pytest.raises(SimParameterError) as error:
        WaterParams(**{name: value})
    message = str(error.value)
    assert message.startswith(f"{name}=")
    assert repr(value) in message
    assert isinstance(error.value, ValueError)


def test_good_parameters_normalise():
    p = WaterParams(spectrum="JONSWAP", wind_direction=(0.0, 2.0), depth=math.inf)
    assert p.spectrum == "jonswap"
    assert p.wind_direction == pytest.approx(math.pi / 2)
    assert p.wind_vector == pytest.approx((0.0, 1.0), abs=1e-12)
    assert hash(p) == hash(WaterParams(spectrum="jonswap", wind_direction=math.pi / 2,
                                       depth=math.inf))


def test_params_round_trip_through_dict():
    p = WaterParams(resolution=64, patch_size=3.0, depth=0.8, wind_speed=5.0, wind_direction=1.0,
                    fetch=20.0, spectrum="phillips", amplitude=0.5, small_wave_cutoff=0.03,
                    choppiness=1.2, seed=99)
    d = p.to_dict()
    assert set(d) == {"resolution", "patch_size", "depth", "wind_speed", "wind_direction", "fetch",
                      "spectrum", "amplitude", "small_wave_cutoff", "choppiness", "seed"}
    assert WaterParams.from_dict(d) == p
    with pytest.raises(SimParameterError, match="keys"):
        WaterParams.from_dict({**d, "wind": 3.0})


def test_peak_wavelength_depends_on_wind_and_fetch():
    base = WaterParams(spectrum="jonswap", wind_speed=3.0, fetch=50.0, depth=math.inf)
    stronger = base.replace(wind_speed=6.0)
    longer = base.replace(fetch=500.0)
    assert peak_wavelength(stronger) > peak_wavelength(base)
    assert peak_wavelength(longer) > peak_wavelength(base)
    # deep water: lambda_p = 2 pi g / omega_p^2
    omega_p = 22.0 * (9.81**2 / (3.0 * 50.0)) ** (1.0 / 3.0)
    assert peak_wavelength(base) == pytest.approx(2.0 * math.pi * 9.81 / omega_p**2, rel=1e-9)
    # shallow water shortens the wave of the same frequency
    assert peak_wavelength(base.replace(depth=0.01)) < peak_wavelength(base)


@pytest.mark.parametrize("camera,light", [(0.002, 0.004), (0.01, 0.003), (0.0005, 0.05)])
def test_choose_lod_resolves_the_views(camera, light):
    rect = (-2.0, -1.0, 2.0, 1.0)
    peak = 0.17
    lod = choose_lod(camera, light, rect, peak)
    n, patch = lod.resolution, lod.patch_size
    assert n & (n - 1) == 0 and 16 <= n <= 1024
    assert lod.finest_footprint == min(camera, light)
    assert patch / n <= lod.small_wave_cutoff / 4.0 * (1 + 1e-12)  # >= 4 samples per l_min
    assert patch >= min(4.0 * peak, 4.0)  # a few peak wavelengths, up to the pool size
    if n < 1024:  # uncapped: the cutoff is the Nyquist wavelength of the finest view
        assert lod.small_wave_cutoff == pytest.approx(2.0 * min(camera, light))
        assert n < 2 * 4.0 * patch / lod.small_wave_cutoff  # and N is not larger than needed
    else:  # capped: the shortest wave grows instead
        assert lod.small_wave_cutoff >= 2.0 * min(camera, light)
    nx, nz = lod.vertex_counts
    assert nx * nz <= 1 << 22
    wanted = max(min(camera, light), patch / n)  # a vertex per finest footprint, not past the grid
    spacing = 4.0 / (nx - 1), 2.0 / (nz - 1)
    if (4.0 / wanted + 1) * (2.0 / wanted + 1) <= 1 << 22:
        assert all(0.5 * wanted < s <= wanted * (1 + 1e-9) for s in spacing)
    else:  # vertex cap: coarser spacing
        assert all(s > wanted for s in spacing)
    params = lod.apply(WaterParams())
    assert params.resolution == n and params.small_wave_cutoff == lod.small_wave_cutoff


def test_choose_lod_follows_the_footprint():
    coarse = choose_lod(0.02, 0.02, (0.0, 0.0, 4.0, 2.0), 0.17)
    fine = choose_lod(0.002, 0.02, (0.0, 0.0, 4.0, 2.0), 0.17)
    assert fine.resolution > coarse.resolution
    assert fine.small_wave_cutoff < coarse.small_wave_cutoff
    assert fine.vertex_counts[0] > coarse.vertex_counts[0]


@pytest.mark.parametrize("kwargs,name", [
    (dict(camera_footprint=0.0), "camera_footprint"),
    (dict(light_footprint=float("nan")), "light_footprint"),
    (dict(rect=(0.0, 0.0, -1.0, 1.0)), "rect"),
    (dict(peak_wavelength=-1.0), "peak_wavelength"),
    (dict(max_resolution=1000), "max_resolution"),
])
def test_choose_lod_rejects_bad_inputs(kwargs, name):
    args = dict(camera_footprint=0.01, light_footprint=0.01, rect=(0.0, 0.0, 1.0, 1.0),
                peak_wavelength=0.2)
    args.update(kwargs)
    with pytest.raises(SimParameterError, match=name):
        choose_lod(**args)


def test_bench_sim_smoke():
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    result = subprocess.run([sys.executable, str(REPO / "tools" / "bench_sim.py"), "--smoke",
                             "--device", "cpu"], capture_output=True, text=True, env=env,
                            timeout=120, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert "evaluate" in result.stdout and "numpy.fft" in result.stdout
