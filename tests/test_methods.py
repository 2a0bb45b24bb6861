"""The methods CISP is measured against: world-space SSPM (seed 003) and the converged reference.

Caustics Mapping (seed 004) has its own file, ``test_caustics_map.py``.
"""

import math

import numpy as np
import pytest

from cisp_warp import analytic
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import METHODS, Renderer, RenderSettings


def render(scene, device, method, photons, rsm=256, denoiser="none", **kw):
    settings = RenderSettings(rsm_size=rsm, method=method, denoiser=denoiser,
                              photons=PhotonSettings(photons=photons, seed=kw.pop("seed", 3), **kw))
    r = Renderer(scene, settings, device=device)
    r.render_frame()
    return r, r.aovs(include_rsm=False)


def test_every_method_is_selectable():
    assert {"cisp", "sspm", "caustics_map", "reference", "none"} <= set(METHODS)


@pytest.mark.parametrize("method", ["sspm", "reference"])
@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0])
def test_flat_water_irradiance_is_analytic(device, method, theta_deg):
    """Floor under flat water: E = E⊥ · cos θ · (1 − F(θ)), within 1%, and the ledger closes."""
    r, a = render(analytic.flat_water(theta_deg), device, method, photons=300_000, reference_photons=600_000)
    inner = analytic.flat_water_interior(a, theta_deg)
    assert inner.sum() > 400
    expected, _ = analytic.flat_water_answer(theta_deg)
    np.testing.assert_allclose(a["photon_map"][inner].mean(axis=0), expected, rtol=0.01)
    ledger = r.photons.read_ledger()
    assert ledger.closure() < 1e-5
    assert ledger["stored"][0] > 0.5 * ledger["sampled"][0]


def test_sspm_follows_several_bounces(device):
    """A photon refracted into water and reflected by a mirror under it needs three bounces to reach the
    floor; with max_bounces=1 it is booked as out of bounces instead, and the ledger says so."""
    from cisp_warp.analytic import FLOOR, WATER, build, quad
    from cisp_warp.scene import Material

    mirror = Material("mirror", albedo=(0.9, 0.9, 0.9), roughness=0.0, metallic=1.0)
    base = analytic.flat_water(0.0)
    parts = [((quad(0, 0, 0, (0.5, 0, 0), (0, 0, -0.5))), 1), ((quad(0, -0.5, 0, (2, 0, 0), (0, 0, -2))), 0),
             ((quad(0.0, -0.3, 0, (0.3, 0.0, 0), (0, -0.05, -0.3))), 2)]  # tilted mirror under the water
    scene = build(parts, base.camera, base.lights, (FLOOR, WATER, mirror))
    r3, a3 = render(scene, device, "sspm", photons=50_000, max_bounces=4)
    r1, a1 = render(scene, device, "sspm", photons=50_000, max_bounces=1)
    l3, l1 = r3.photons.read_ledger(), r1.photons.read_ledger()
    assert l3.closure() < 1e-5 and l1.closure() < 1e-5
    assert l1["bounce_limit"][0] > 0.1 * l1["sampled"][0]
    assert l3["bounce_limit"][0] < 1e-3 * l3["sampled"][0]
    assert l3["absorbed"][0] > 0  # the mirror keeps 90%
    assert l3["stored"][0] > l1["stored"][0]


def test_reference_converges(device):
    """RMSE against a much longer run halves when the photon count is ×4 (after taking the long run's
    own reported noise out), and the reported standard error matches the error actually made."""
    scene = lambda: analytic.sinusoidal_water(64, 32)  # noqa: E731
    per_pass = 100_000
    _, long_run = render(scene(), device, "reference", per_pass, reference_photons=32 * per_pass, seed=99)
    truth = long_run["photon_map"][..., 0].astype(np.float64)
    own_noise = np.mean(long_run["caustics_stderr"][..., 0].astype(np.float64) ** 2)
    rmse, reported = [], []
    for n in (2 * per_pass, 8 * per_pass):
        _, a = render(scene(), device, "reference", per_pass, reference_photons=n, seed=1)
        err2 = np.mean((a["photon_map"][..., 0] - truth) ** 2)
        rmse.append(math.sqrt(max(err2 - own_noise, 0.0)))
        reported.append(math.sqrt(np.mean(a["caustics_stderr"][..., 0].astype(np.float64) ** 2)))
    ratio = rmse[0] / rmse[1]
    assert 1.7 < ratio < 3.0, f"RMSE {rmse[0]:.4g} -> {rmse[1]:.4g} (×{ratio:.2f}) for ×4 photons"
    for e, s in zip(rmse, reported):
        assert 0.6 < s / e < 1.6, f"reported standard error {s:.4g} vs RMSE {e:.4g}"
    # and it converges to the analytic answer
    expected = analytic.sinusoidal_answer(64, 32)
    profile = truth[8:24].mean(axis=0)
    assert np.linalg.norm(profile - expected) / np.linalg.norm(expected) < 0.01


def test_reference_final_sees_the_caustic_through_the_water(device):
    """The reference's own final image: camera paths through the water reach the floor's caustic, so
    the floor seen through flat water is (1 − F)/η² × what it would be seen directly (L/n² invariant)."""
    r, a = render(analytic.flat_water(0.0), device, "reference", 100_000, reference_photons=400_000)
    final = a["final"][..., 0]
    assert np.isfinite(a["final"]).all() and np.isfinite(a["caustics_stderr"]).all()
    inner = analytic.flat_water_interior(a, 0.0, half=0.3)
    e, _ = analytic.flat_water_answer(0.0)
    from cisp_warp.optics import fresnel_dielectric_np

    seen = 0.8 / math.pi * e * (1 - fresnel_dielectric_np(1.0, 1.33)) / 1.33 ** 2
    np.testing.assert_allclose(np.median(final[inner]), seen, rtol=0.05)


def test_world_space_methods_are_deterministic(device):
    scene = analytic.flat_water(30.0)
    for method in ("sspm", "reference"):
        _, a = render(analytic.flat_water(30.0), device, method, 20_000, reference_photons=40_000)
        _, b = render(scene, device, method, 20_000, reference_photons=40_000)
        if device == "cpu":
            assert np.array_equal(a["photon_map"], b["photon_map"])
            assert np.array_equal(a["final"], b["final"])
        np.testing.assert_allclose(a["photon_map"], b["photon_map"], rtol=1e-4, atol=1e-2)


def test_methods_agree_within_their_noise(device):
    """On sinusoidal water (no method fails there) every method's floor profile agrees with the
    reference within the noise it shows from frame to frame, plus 3% for its screen-space discretisation."""
    W, H = 64, 32
    _, ref = render(analytic.sinusoidal_water(W, H), device, "reference", 200_000, rsm=512, reference_photons=1_600_000)
    ref_profile = ref["photon_map"][H // 4 : 3 * H // 4, :, 0].mean(axis=0)
    ref_err = np.sqrt((ref["caustics_stderr"][H // 4 : 3 * H // 4, :, 0] ** 2).mean(axis=0) / (H // 2))
    for method in [m for m in METHODS if m not in ("reference", "none")]:
        r = Renderer(analytic.sinusoidal_water(W, H), RenderSettings(
            rsm_size=512, method=method, denoiser="none",
            photons=PhotonSettings(photons=200_000, seed=5, cmap_history=1)), device=device)
        profiles = []
        for _ in range(4):
            r.render_frame()
            profiles.append(r.aovs(include_rsm=False)["photon_map"][H // 4 : 3 * H // 4, :, 0].mean(axis=0))
        profiles = np.array(profiles)
        mean = profiles.mean(axis=0)
        noise = profiles.std(axis=0, ddof=1) / 2.0
        bound = 4.0 * np.sqrt(noise ** 2 + ref_err ** 2) + 0.03 * ref_profile.mean()
        rel = np.linalg.norm(mean - ref_profile) / np.linalg.norm(ref_profile)
        assert np.mean(np.abs(mean - ref_profile) <= bound) > 0.9, f"{method}: relative L2 {rel:.4f} to the reference"
        assert rel < 0.05, f"{method}: relative L2 {rel:.4f} to the reference"
