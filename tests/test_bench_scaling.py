"""tools/bench_scaling.py: the scene sweep's water grids and the whole tool in its smoke setting (no timings checked)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

import bench_scaling  # noqa: E402


@pytest.mark.parametrize("target", [16_000, 1_000_000, 4_000_000])
def test_water_spacing_gives_the_asked_triangle_count(target):
    from cisp_warp.pool_scene import PoolOptions

    nx, nz = PoolOptions(water_spacing=bench_scaling.spacing_for(target)).water_counts()
    assert abs(2 * (nx - 1) * (nz - 1) / target - 1.0) < 0.02


def test_bench_scaling_smoke(tmp_path):
    result = subprocess.run([sys.executable, str(ROOT / "tools" / "bench_scaling.py"), "--smoke", "--device", "cpu",
                             "--out", str(tmp_path)], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    report = json.loads((tmp_path / "scaling.json").read_text())
    assert report["device"].startswith("cpu") and report["methods"] == ["cisp", "sspm"]
    assert [(r["method"], r["photons"]) for r in report["photon_sweep"]] == [
        ("cisp", 1000), ("cisp", 2000), ("sspm", 1000), ("sspm", 2000)]
    tris = [r["water_triangles"] for r in report["scene_sweep"] if r["method"] == "sspm"]
    assert len(tris) == 2 and tris[1] > 3 * tris[0]
    for r in report["photon_sweep"] + report["scene_sweep"]:
        assert set(r["stages"]) >= {"water", "refit", "raster", "trace+store", "denoise", "shade"}
        assert all(v >= 0.0 for v in r["stages"].values())
        assert r["traced"] == 2 * r["photons"]  # the pool's two lights
    # the scene sweep's scenes carry the finer water: the whole scene grows by the water's triangles
    sweep = [r for r in report["scene_sweep"] if r["method"] == "cisp"]
    assert sweep[1]["triangles"] - sweep[0]["triangles"] == sweep[1]["water_triangles"] - sweep[0]["water_triangles"]
    assert "1. photons per light" in result.stdout and "2. water triangles" in result.stdout
