"""The evaluation's figures (cisp_warp/metrics.py) against twins and exact answers, the composite of an
orthographic view, and tools/evaluate.py in its smoke setting."""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from cisp_warp import analytic, metrics
from cisp_warp.optics import fresnel_dielectric_np
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.scene import Camera
from cisp_warp.scene.model import look_at_matrix

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def render(scene, device, method="cisp", photons=50_000, denoiser="none", rsm=128):
    r = Renderer(scene, RenderSettings(rsm_size=rsm, method=method, denoiser=denoiser,
                                       photons=PhotonSettings(photons=photons, seed=2)), device=device)
    r.render_frame()
    return r, r.aovs(include_rsm=False)


def ortho_flat_water(size=32):
    """flat_water(0) seen straight down by an orthographic camera 0.6 m across."""
    scene = analytic.flat_water(0.0, size=size)
    scene.camera = Camera(look_at_matrix((0.0, 1.2, 0.0), (0.0, -0.5, 0.0), up=(0, 0, -1)), orthographic=True,
                          ortho_height=0.6, width=size, height=size, near=0.05, far=10)
    return scene


def test_footprint_matches_the_perspective_twin_and_the_ledger(device):
    """Perspective: the analytic twin; both projections: Σ E·A over the photon map is the stored power."""
    r, a = render(analytic.flat_water(30.0), device)
    np.testing.assert_allclose(metrics.pixel_footprint(a, r.view), analytic.footprint_area(a, r.view), rtol=1e-9)
    for scene in (analytic.flat_water(30.0), ortho_flat_water()):
        r, a = render(scene, device)
        stored = r.photons.read_ledger()["stored"][0]
        np.testing.assert_allclose(metrics.power(a["photon_map"], metrics.pixel_footprint(a, r.view)), stored, rtol=1e-4)


def test_orthographic_footprint_is_the_pixel_square(device):
    """Looking straight down on a floor: every pixel covers (0.6 m / 32)² exactly."""
    r, a = render(ortho_flat_water(), device)
    fp = metrics.pixel_footprint(a, r.view)
    np.testing.assert_allclose(fp[a["depth"] > 0], (0.6 / 32) ** 2, rtol=1e-5)


def test_orthographic_composite_looks_straight_through_flat_water(device):
    """Seen straight down through flat water, each pixel shows its own floor point: final = ρ/π · E ·
    (1 − F(0)) / η² exactly, E the caustic irradiance there (the view direction of an orthographic camera is
    its axis, not the direction to its origin)."""
    r, a = render(ortho_flat_water(), device)
    inner = analytic.flat_water_interior(a, 0.0, half=0.45)
    assert inner.sum() > 400
    seen = 0.8 / math.pi * (1 - fresnel_dielectric_np(1.0, 1.33)) / 1.33 ** 2
    exact = np.isclose(a["final"][inner], seen * a["caustics"][inner], rtol=1e-4, atol=1e-6).all(axis=-1)
    # all of them on the CPU; on CUDA fused multiply-adds put a ray running along the view axis one pixel
    # over now and then (3 of 1014 pixels on an H100), while the old bug blackened whole borders
    assert exact.mean() > 0.99, f"{(~exact).sum()} of {exact.size} pixels do not see their own floor point"


def test_relative_rmse_and_energy_ratio_are_exact_on_scaled_images():
    rng = np.random.default_rng(1)
    ref = rng.uniform(1.0, 2.0, (8, 8, 3))
    mask = np.ones((8, 8), bool)
    assert metrics.relative_rmse(ref, ref, mask) == 0.0
    y = metrics.irradiance_y(ref)
    expected = 0.1 * np.sqrt(np.mean(y ** 2)) / np.mean(y)  # RMSE over the mean, not a mean of ratios
    np.testing.assert_allclose(metrics.relative_rmse(1.1 * ref, ref, mask), expected, rtol=1e-12)
    assert metrics.relative_rmse(np.full((8, 8, 3), 1.1), np.ones((8, 8, 3)), mask) == pytest.approx(0.1, rel=1e-12)
    fp = rng.uniform(0.5, 1.0, (8, 8))
    np.testing.assert_allclose(metrics.energy_ratio(0.9 * ref, ref, fp), 0.9, rtol=1e-12)
    assert math.isnan(metrics.relative_rmse(ref, ref, np.zeros((8, 8), bool)))


def plane(h=6, w=8, shift=0):
    """Synthetic G-buffer of the plane y = 0 seen from above, 1 cm pixels, every pixel its own triangle."""
    ys, xs = np.mgrid[0:h, 0:w]
    pos = np.stack([0.01 * (xs + shift), np.zeros((h, w)), 0.01 * ys], -1)
    return {"position": pos, "normal": np.tile([0.0, 1.0, 0.0], (h, w, 1)), "depth": np.ones((h, w)),
            "tri_id": (ys * 100 + xs + shift).astype(np.int32), "motion": np.zeros((h, w, 2))}


def test_flicker_follows_the_motion_vectors():
    """A camera move of one pixel: reprojected, an unchanged caustic does not flicker, a 10% brighter one
    flickers 0.1/1.1; pixels whose previous position left the image are not counted."""
    prev, cur = plane(shift=0), plane(shift=1)  # cur pixel x sees what prev pixel x + 1 saw
    cur["motion"][..., 0] = 1.0
    pattern = lambda a: np.repeat((1.0 + np.sin(a["position"][..., :1] * 300)) * 5, 3, -1)  # noqa: E731
    prev["caustics"], cur["caustics"] = pattern(prev), pattern(cur)
    fp = np.full((6, 8), 1e-4)
    mask = np.ones((6, 8), bool)
    assert metrics.flicker(prev, cur, fp, mask) < 1e-12
    q, valid = metrics.reprojection(prev, cur, fp)
    assert not valid[:, -1].any() and valid[:, :-1].all()
    cur["caustics"] = 1.1 * cur["caustics"]
    np.testing.assert_allclose(metrics.flicker(prev, cur, fp, mask), 0.1 / 1.1, rtol=1e-9)
    cur["motion"][..., 0] = 0.0  # wrong motion: other triangles, nothing valid
    assert math.isnan(metrics.flicker(prev, cur, fp, mask))


def test_geometric_edges_are_silhouettes_and_creases():
    a = plane(8, 8)
    assert not metrics.geometric_edges(a)[1:-1, 1:-1].any()  # a plane has none inside the frame
    a["position"][:, 4:, 1] = 0.05  # a 5 cm step between columns 3 and 4
    e = metrics.geometric_edges(a)
    assert e[1:-1, 3:5].all() and not e[1:-1, 1:3].any() and not e[1:-1, 5:7].any()


def test_evaluate_smoke(tmp_path):
    """The tool runs end to end: CSV and JSON with the device and every configuration, finite figures."""
    out = tmp_path / "eval"
    res = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "evaluate.py"), "--smoke", "--device", "cpu",
                          "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    data = json.loads((out / "results.json").read_text())
    assert data["device"].startswith("cpu") and data["preset"] == "smoke" and data["warp"]
    runs = data["runs"]
    assert {(r["method"], r["denoiser"]) for r in runs} == {
        (m, d) for m in ("cisp", "sspm", "caustics_map") for d in ("caustic", "svgf", "none")} | {("caustics_map", "own")}
    for r in runs:
        assert r["finite"] and r["ledger_closure"] < 1e-5
        assert 0.9 < r["energy_ratio_raw"] < 1.1, r  # sinusoid: nothing is out of any method's reach
        assert r["frame_ms"] > 0 and math.isfinite(r["rel_rmse"])
    assert (out / "results.csv").read_text().count("\n") == len(runs) + 1
    assert any(p.startswith("reference_sinusoid") for p in os.listdir(out / "references"))
