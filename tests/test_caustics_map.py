"""Caustics mapping (seed 004): analytic irradiance through the light-space map, the ledger, the stated
limit (no caustic outside the light's view), determinism and seed 004's temporal filter."""

import math

import numpy as np
import pytest

from cisp_warp import analytic
from cisp_warp.photons import PhotonSettings
from cisp_warp.raster import LightViewSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.scene import Camera, Light, LightKind
from cisp_warp.scene.model import look_at_matrix


def renderer(scene, device, photons, method="caustics_map", rsm=256, seed=3, **kw):
    """A renderer whose denoiser matches the gather: none after the light-space gather, seed 004's
    7x7 eye-space Gaussian after the eye-space projection. Light views over the whole scene for every
    method (caustics_map's own), so that cisp traces the same photons."""
    denoiser = "gather" if kw.get("cmap_gather") == "eye" else "none"
    return Renderer(scene, RenderSettings(rsm_size=rsm, method=method, denoiser=denoiser,
                                          light_views=LightViewSettings(fit="scene"),
                                          photons=PhotonSettings(photons=photons, seed=seed, **kw)), device=device)


def render(scene, device, photons, **kw):
    r = renderer(scene, device, photons, **kw)
    r.render_frame()
    return r, r.aovs(include_rsm=False)


def wall_power(r, a):
    """Power [W] on the wall of :func:`analytic.wall_scene`: irradiance × exact pixel footprint."""
    power = a["photon_map"][..., 0].astype(np.float64) * analytic.footprint_area(a, r.view)
    return power[analytic.wall_mask(a)].sum()


def light_space_power(cm, channel=0):
    """Σ E·A over a view's caustic map (before the gather): the power it holds [W]."""
    return float((cm.irradiance.numpy()[:, channel].astype(np.float64) * cm.receiver_area.numpy()).sum())


@pytest.mark.parametrize("gather", ["light", "eye"])
@pytest.mark.parametrize("theta_deg", [0.0, 30.0])
def test_flat_water_irradiance_is_analytic(device, theta_deg, gather):
    """Floor under flat water, read back through the camera: E = E⊥ · cos θ · (1 − F(θ)) within 2%."""
    r, a = render(analytic.flat_water(theta_deg), device, photons=200_000, cmap_gather=gather)
    inner = analytic.flat_water_interior(a, theta_deg)
    assert inner.sum() > 400
    expected, _ = analytic.flat_water_answer(theta_deg)
    measured = a["caustics"][inner]
    np.testing.assert_allclose(measured.mean(axis=0), expected, rtol=0.02)
    assert np.percentile(np.abs(measured[:, 0] / expected - 1.0), 90) < 0.1  # and pixel by pixel, loosely
    ledger = r.photons.read_ledger()
    assert ledger.closure() < 1e-6
    for name in ("lost_camera_view", "occluded"):  # decided per pixel at projection, not per photon
        assert ledger[name].sum() == 0.0
    # "stored" is light-space energy: the single frame's caustic map holds exactly the stored power
    np.testing.assert_allclose(light_space_power(r.photons.maps[0][0]), ledger["stored"][0], rtol=1e-5)


@pytest.mark.parametrize("kind", ["point", "spot"])
def test_perspective_light_agrees_with_cisp(device, kind):
    """Perspective receiver area A = Ω_t·r²/|cos θ| (six cube faces for the point light): where both
    methods see the whole beam, the floor irradiance matches CISP's, whose store uses the camera's footprint."""
    water = (analytic.quad(0, 0, 0, (0.5, 0, 0), (0, 0, -0.5)), 1)
    floor = (analytic.quad(0, -0.5, 0, (2, 0, 0), (0, 0, -2)), 0)
    cam = Camera(look_at_matrix((0.2, 1.2, 0.0001), (0.2, -0.5, 0)), fov_y=math.radians(45), width=48, height=48,
                 near=0.05, far=10)
    light = Light(LightKind[kind.upper()], "lamp", intensity=100.0, position=(0.1, 0.8, 0.05), direction=(0, -1, 0),
                  cone_angle=math.radians(50))
    maps = {}
    for method in ("cisp", "caustics_map"):
        r, a = render(analytic.build([water, floor], cam, [light]), device, photons=200_000, method=method, seed=1)
        assert len(r.lights[0].rsm) == (6 if kind == "point" else 1)
        maps[method] = a["photon_map"][..., 0]
    x = a["position"]
    inner = (np.abs(x[..., 0]) < 0.25) & (np.abs(x[..., 2]) < 0.25) & (a["depth"] > 0)
    assert inner.sum() > 200
    ratio = maps["caustics_map"][inner].mean() / maps["cisp"][inner].mean()
    print(f"{kind} light: caustics_map / cisp floor irradiance {ratio:.4f}")
    assert abs(ratio - 1.0) < 0.02


def test_wall_caustic_outside_light_frustum_is_lost(device):
    """The stated limit: a reflection onto a wall the spot's view does not see. CISP's cascade delivers it;
    caustics mapping, whose photons end in the light view or nowhere, delivers none of it."""
    r_c, a_c = render(analytic.wall_scene(), device, photons=40_000, method="cisp")
    r_m, a_m = render(analytic.wall_scene(), device, photons=40_000)
    reflected = r_c.photons.read_ledger()["reflected"][0]
    cisp_wall, cmap_wall = wall_power(r_c, a_c), wall_power(r_m, a_m)
    print(f"wall caustic: cisp {cisp_wall:.4g} W, caustics_map {cmap_wall:.4g} W of {reflected:.4g} W reflected")
    assert cisp_wall > 0.4 * reflected
    assert cmap_wall < 0.05 * cisp_wall
    ledger = r_m.photons.read_ledger()
    assert ledger.closure() < 1e-6
    np.testing.assert_allclose(ledger["reflected"], r_c.photons.read_ledger()["reflected"], rtol=1e-6)  # same photons
    assert ledger["lost_light_view"][0] >= 0.9 * reflected  # where the wall's share went


def test_same_seed_same_frame_is_exact(device):
    """Seed and frame reproduce the photon map (ring included) bit for bit on the CPU; another seed does not."""
    scene = analytic.flat_water(30.0)
    maps = []
    for seed in (3, 3, 4):
        r = renderer(scene, device, photons=20_000, seed=seed)
        for _ in range(3):
            r.render_frame()
        maps.append(r.photons.photon_map.numpy())
    if device == "cpu":
        assert np.array_equal(maps[0], maps[1])
    np.testing.assert_allclose(maps[0], maps[1], rtol=1e-5, atol=1e-3)
    assert not np.array_equal(maps[0], maps[2])


def test_temporal_filter_is_the_mean_of_the_last_frames_and_cuts_flicker(device):
    """Seed 004, 3.2.3: the map is the mean of the last ``cmap_history`` frames' maps (twin: single-frame
    maps of the same seed and frames, averaged in numpy), and on a static scene it flickers less."""
    scene = analytic.flat_water(0.0)
    history, frames = 4, 8
    runs = {}
    for h in (1, history):
        r = renderer(scene, device, photons=3_000, rsm=64, cmap_history=h)
        light_maps, photon_maps = [], []
        for _ in range(frames):
            r.render_frame()
            light_maps.append(r.photons.maps[0][0].irradiance.numpy().copy())
            photon_maps.append(r.photons.photon_map.numpy()[:, 0].copy())
        runs[h] = (np.array(light_maps), np.array(photon_maps), r.aovs(include_rsm=False))
    single, filtered = runs[1][0], runs[history][0]
    for f in range(frames):
        twin = single[max(0, f - history + 1) : f + 1].mean(axis=0)
        np.testing.assert_allclose(filtered[f], twin, rtol=1e-5, atol=1e-3)
    inner = analytic.flat_water_interior(runs[1][2], 0.0).reshape(-1)
    stats = {}
    for h in (1, history):
        e = runs[h][1][history - 1 :, inner]  # frames once the ring is full
        stats[h] = (e.mean(), e.std(axis=0).mean() / e.mean(), np.sqrt((np.diff(e, axis=0) ** 2).mean()) / e.mean())
    print(f"temporal std {stats[1][1]:.4f} -> {stats[history][1]:.4f}, "
          f"frame-to-frame rms {stats[1][2]:.4f} -> {stats[history][2]:.4f}")
    np.testing.assert_allclose(stats[history][0], stats[1][0], rtol=0.01)  # same energy
    assert stats[history][1] < 0.6 * stats[1][1]  # ~1/2 for 4 independent frames
    assert stats[history][2] < 0.4 * stats[1][2]  # ~1/4: consecutive means share 3 of 4 frames
