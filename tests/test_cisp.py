"""CISP photon tracing: analytic irradiance, the energy ledger, the cascade and its stated limits."""

import math

import numpy as np
import pytest
import warp as wp

from cisp_warp import analytic
from cisp_warp.analytic import footprint_area, wall_mask, wall_scene
from cisp_warp.optics import fresnel_dielectric_np
from cisp_warp.photons import PhotonSettings
from cisp_warp.photons.common import L_OCCLUDED, L_STORED
from cisp_warp.photons.kernels_cisp import MARCH_ON, reproject_to_camera
from cisp_warp.photons.march import MARCH_EXIT, MARCH_HIT
from cisp_warp.raster.views import View, ViewParams
from cisp_warp.render import Renderer, RenderSettings

def render(scene, device, photons, rsm=256, **kw):
    r = Renderer(scene, RenderSettings(rsm_size=rsm, photons=PhotonSettings(photons=photons, seed=3, **kw)), device=device)
    r.render_frame()
    return r, r.aovs(include_rsm=False)


def flat_water(theta_deg):
    return analytic.flat_water(theta_deg), math.radians(theta_deg)


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0])
def test_flat_water_irradiance_is_analytic(device, theta_deg):
    """Floor under flat water: E = E⊥ · cos θ · (1 − F(θ)), within 1%."""
    scene, th = flat_water(theta_deg)
    r, a = render(scene, device, photons=300_000)
    eta = 1.33
    sin_t = math.sin(th) / eta
    shift = 0.5 * sin_t / math.sqrt(1 - sin_t ** 2)  # the refracted beam's offset on the floor
    x = a["position"]
    inner = (np.abs(x[..., 0] - shift) < 0.4) & (np.abs(x[..., 2]) < 0.4) & (a["depth"] > 0)
    assert inner.sum() > 400
    measured = a["photon_map"][inner].mean(axis=0)
    expected = 1000.0 * math.cos(th) * (1.0 - fresnel_dielectric_np(math.cos(th), eta))
    np.testing.assert_allclose(measured, expected, rtol=0.01)
    ledger = r.photons.read_ledger()
    assert ledger.closure() < 1e-5
    # point splats read no RSM position or normal: the views keep none (kernels.texel_surface gives them)
    assert not any(v.specular.has_surface for lm in r.lights for v in lm.rsm + lm.pilot)
    # irradiance × exact footprint area, summed, is the stored power
    stored = (a["photon_map"][..., 0].astype(np.float64) * footprint_area(a, r.view)).sum()
    np.testing.assert_allclose(stored, ledger["stored"][0], rtol=1e-4)


def test_paper_footprint_differs_by_cosines(device):
    """The paper's eq. 3 footprint (no 1/cos, times <-d, n>) is selectable and gives its own numbers."""
    scene, th = flat_water(0.0)
    _, exact = render(scene, device, photons=50_000)
    _, paper = render(scene, device, photons=50_000, footprint="paper")
    m = exact["photon_map"][..., 0] > 0
    ratio = paper["photon_map"][..., 0][m] / exact["photon_map"][..., 0][m]
    assert 0.5 < ratio.min() and ratio.max() < 1.0 + 1e-5  # cos factors only ever lower it here
    assert ratio.mean() < 0.999


def wall_power(r, a):
    return (a["photon_map"][..., 0].astype(np.float64) * footprint_area(a, r.view))[wall_mask(a)].sum()


def test_reflective_caustic_outside_light_frustum_found_through_camera(device):
    """Seed 000's main claim: the cascade finds a wall caustic the light view cannot see."""
    r, a = render(wall_scene(), device, photons=40_000)
    ledger = r.photons.read_ledger()
    reflected = ledger["reflected"][0]
    assert reflected > 0
    found = wall_power(r, a)
    assert found > 0.4 * reflected, f"wall received {found:.4g} W of {reflected:.4g} W reflected"
    assert ledger.closure() < 1e-5
    r2, a2 = render(wall_scene(), device, photons=40_000, cascade=False)
    assert wall_power(r2, a2) < 0.01 * reflected  # light view alone: the wall caustic is lost


def test_hidden_photon_trail_is_marched_behind_the_screen(device):
    """Seed 000 §4.3 loses a trail hidden in the camera view (here by a screen between the camera and the water: the
    reprojected light-view end lies behind it). The camera rescue marches such a photon in the camera view from the
    water, behind the screen, to the wall it reaches: the wall gets the power it gets without the screen (the same
    photons: the screen is on none of their paths), the ledger closes; without the cascade it is lost."""
    r0, a0 = render(wall_scene(), device, photons=40_000)
    r1, a1 = render(wall_scene(occluder=True), device, photons=40_000)
    l0, l1 = r0.photons.read_ledger(), r1.photons.read_ledger()
    assert wall_power(r0, a0) > 0.4 * l0["reflected"][0]
    np.testing.assert_allclose(wall_power(r1, a1), wall_power(r0, a0), rtol=0.02)
    assert l1.closure() < 1e-5
    r2, a2 = render(wall_scene(occluder=True), device, photons=40_000, cascade=False)
    assert wall_power(r2, a2) < 0.01 * l0["reflected"][0]


@wp.kernel
def reproject_cases(camera: ViewParams, depth: wp.array(dtype=wp.float32), points: wp.array(dtype=wp.vec3),
                    status: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.int32)):
    i = wp.tid()
    entry, pix = reproject_to_camera(camera, depth, status[i], points[i], 0.02, 0.02, 1)
    out[i] = entry


def test_a_light_view_miss_is_marched_on_not_stored_in_the_air(device):
    """The light-view march ends a miss where the ray leaves the light view, in the air: within the thickness in
    front of a camera surface (a ray leaving the light view 3 cm before a wall) it marches on in the camera view
    (``MARCH_ON``); only a light-view crossing is stored where it reprojects. Behind the surface: occluded."""
    view = View(np.eye(4), 32, 32, near=0.1, far=100.0, fx=32.0, fy=32.0)
    depth = wp.array(np.full(32 * 32, 2.0, np.float32), device=device)
    pts = np.array([[0.0, 0.0, -1.97], [0.0, 0.0, -1.97], [0.0, 0.0, -1.5], [0.0, 0.0, -2.3]], np.float32)
    status = np.array([MARCH_HIT, MARCH_EXIT, MARCH_EXIT, MARCH_EXIT], np.int32)
    out = wp.zeros(4, dtype=wp.int32, device=device)
    wp.launch(reproject_cases, dim=4, device=device, inputs=[view.params(), depth,
              wp.array(pts, dtype=wp.vec3, device=device), wp.array(status, dtype=wp.int32, device=device), out])
    assert out.numpy().tolist() == [L_STORED, MARCH_ON, MARCH_ON, L_OCCLUDED]


def test_same_seed_same_frame_is_exact(device):
    scene, _ = flat_water(30.0)
    _, a = render(scene, device, photons=20_000)
    _, b = render(scene, device, photons=20_000)
    assert np.array_equal(a["photon_map"], b["photon_map"]) or device != "cpu"
    np.testing.assert_allclose(a["photon_map"], b["photon_map"], rtol=1e-5, atol=1e-3)


def test_sinusoidal_caustic_lands_on_the_analytic_ray_map(device):
    """Water h(x) = A sin(kx) under a vertical distant light: the floor irradiance profile follows the
    analytic refraction ray map X(x) = x + (h + D)·t_x/(−t_y), weighted by (1 − F), binned per pixel."""
    W, H = 64, 32
    r, a = render(analytic.sinusoidal_water(W, H), device, photons=400_000, rsm=512)
    measured = a["photon_map"][H // 4 : 3 * H // 4, :, 0].mean(axis=0)
    expected = analytic.sinusoidal_answer(W, H)
    assert expected.max() > 1.5 * expected.mean()  # the surface does focus light: a real caustic
    # the caustic lines sit in the same pixel columns (periodic: compare the set of bright columns)
    assert np.array_equal(measured > 1.5 * measured.mean(), expected > 1.5 * expected.mean())
    rel = np.linalg.norm(measured - expected) / np.linalg.norm(expected)
    assert rel < 0.1, f"profile differs by {rel:.3f} (relative L2)"
    print(f"sinusoid profile relative L2 {rel:.4f}")



def test_hits_are_recorded_only_when_asked(device):
    """The frame loop records no landing points (``record_hits`` off: ``hits`` untouched); asked for, every stored
    photon has its landing pixel and point there, every other -1, and the same frame's photon map is unchanged."""
    scene, _ = flat_water(30.0)
    settings = RenderSettings(rsm_size=64, photons=PhotonSettings(photons=20_000, seed=3, sort_photons=False))
    off = Renderer(scene, settings, device=device)
    off.render_frame()
    assert not off.photons.hits.numpy().any()
    on = Renderer(flat_water(30.0)[0], settings, device=device)
    on.set_concurrent(False)  # the records of one program's views: CUDA's concurrent one keeps them per lane
    on.photons.record_hits = True
    on.render_frame()
    hits, outcome = on.photons.hits.numpy(), on.photons.outcome.numpy()
    n = on.photons.photons_per_view(on.lights[0])
    stored = outcome[:n, 3] == int(L_STORED)  # unsorted: thread t traces photon t (CUDA sorts by default)
    assert stored.sum() > 1000
    assert np.all(hits[:n][stored, 3] >= 0) and np.all(hits[:n][~stored, 3] == -1)
    np.testing.assert_array_equal(on.photons.photon_map.numpy(), off.photons.photon_map.numpy())


@pytest.mark.parametrize("method", ["cisp", "sspm"])
def test_photon_m2_is_the_sum_of_squared_deposits(device, method):
    """``photon_m2`` holds Σ luminance(e)² of each pixel's deposits. Flat water under the sun: every photon carries
    the same power, so a pixel that stores k photons of irradiance e holds E = k e and photon_m2 = k e²: the ratio
    luminance(E)² / photon_m2 is a whole number, k, and for CISP the count of its hit records in that pixel; no
    photon, no m2. The reference and caustics mapping keep none (they do not store points per frame)."""
    scene, _ = flat_water(30.0)
    r = Renderer(scene, RenderSettings(rsm_size=128, method=method, denoiser="none",
                                       photons=PhotonSettings(photons=60_000, seed=3)), device=device)
    r.photons.record_hits = method == "cisp"
    r.render_frame()
    lum = r.photons.photon_map.numpy().astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])
    m2 = r.photons.photon_m2.numpy().astype(np.float64)
    stored = lum > 0
    assert stored.sum() > 1000
    assert np.all(m2[~stored] == 0.0) and np.all(m2[stored] > 0.0)
    k = lum[stored] ** 2 / m2[stored]
    assert k.max() > 3.0  # several photons share a pixel
    np.testing.assert_allclose(k, np.round(k), atol=2e-3 * k.max())
    if method == "cisp":
        hits = r.photons.hits.numpy()
        pix = hits[:, 3][hits[:, 3] >= 0].astype(np.int64)
        count = np.bincount(pix, minlength=lum.size)
        np.testing.assert_array_equal(np.round(k).astype(np.int64), count[stored])
    r.render_frame()  # cleared each frame: the same frame count, not twice
    np.testing.assert_allclose(r.photons.photon_m2.numpy().sum(), m2.sum(), rtol=0.05)


def test_photon_m2_is_kept_by_point_stores_only(device):
    scene, _ = flat_water(0.0)
    for method, kept in (("cisp", True), ("sspm", True), ("caustics_map", False), ("reference", False)):
        r = Renderer(scene, RenderSettings(rsm_size=64, method=method, denoiser="none",
                                           photons=PhotonSettings(photons=2_000, reference_photons=4_000)),
                     device=device)
        assert (r.photons.photon_m2 is not None) == kept, method


def test_every_seed_in_range_renders_and_others_are_refused(device):
    """Seeds past int32 (the pilot streams' seed·7919 + frame·131 wraps mod 2^32) render a finite frame that the
    same seed reproduces; a negative, fractional, boolean or 2^63-and-above seed is one clear SceneError."""
    from cisp_warp.errors import SceneError

    scene, _ = flat_water(30.0)
    for seed in (271_300, 1 << 62):
        settings = RenderSettings(rsm_size=32, photons=PhotonSettings(photons=2_000, seed=seed))
        maps = []
        for _ in range(2):
            r = Renderer(scene, settings, device=device)
            r.render_frame()
            maps.append(r.photons.photon_map.numpy())
        assert np.isfinite(maps[0]).all() and maps[0].sum() > 0
        np.testing.assert_array_equal(maps[0], maps[1])
    for bad in (-1, 1 << 63, 1.5, True):
        with pytest.raises(SceneError, match="seed must be an integer"):
            RenderSettings(photons=PhotonSettings(photons=2_000, seed=bad))


def test_landings_lie_on_the_receiver(device):
    """A light-view crossing lies within an RSM texel's depth of the receiver (nearest-texel depth, the sun's view
    tilted 30° over the floor, a coarse 64² RSM); cut with the tangent plane of the surface its camera pixel shows
    (``refine_landing``), every stored photon lands on the floor plane (y = −0.5 m) to rounding."""
    scene, _ = flat_water(30.0)
    r = Renderer(scene, RenderSettings(rsm_size=64, photons=PhotonSettings(photons=20_000, seed=3, sort_photons=False)),
                 device=device)
    r.set_concurrent(False)  # the records of one program's views: CUDA's concurrent one keeps them per lane
    r.photons.record_hits = True
    r.render_frame()
    hits, outcome = r.photons.hits.numpy(), r.photons.outcome.numpy()
    n = r.photons.photons_per_view(r.lights[0])
    stored = outcome[:n, 3] == int(L_STORED)
    assert stored.sum() > 1000
    np.testing.assert_allclose(hits[:n][stored, 1], -0.5, atol=1e-4)


def test_camera_bounds_cover_the_back_face_layer(device):
    """The camera's depth bounds that the trace's camera marches skip cells by are built from the depth with its
    back-face layer (what the marches read), not from the front depth alone: on the Cornell box (the ball's far
    half: 2 of 360 cells at 192x108) the two differ, and the trace's bounds are the layered ones."""
    import os

    from cisp_warp.photons.cisp import build_bounds
    from cisp_warp.usd import load_usd

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    scene = load_usd(os.path.join(root, "scenes_usd", "cornell_flooded.usda"), width=192, height=108, device=device)
    r = Renderer(scene, RenderSettings(rsm_size=64, method="cisp", denoiser="none", photons=2_000), device=device)
    r.render_frame()
    g, p = r.gbuffer, r.photons
    built = {}
    for name, depth in (("layers", g.depth_layers), ("front", g.depth)):
        b = wp.zeros_like(p.cam_bounds)
        build_bounds(depth, g.width, g.height, p.settings.thickness, p.settings.thickness_rel, b, device)
        built[name] = b.numpy()
    assert not np.array_equal(built["layers"], built["front"])
    np.testing.assert_array_equal(p.cam_bounds.numpy(), built["layers"])



def _pool(width, height):
    from pathlib import Path

    from cisp_warp.usd import load_usd

    return load_usd(str(Path(__file__).resolve().parents[1] / "scenes_usd" / "pool.usda"), width=width, height=height,
                    device="cpu")


@pytest.mark.parametrize("name, make, projections", [
    ("pool", _pool, {(0, 0), (1, 0)}),  # an orthographic sun, a perspective spot and camera
    ("sinusoid", lambda w, h: analytic.sinusoidal_water(w, h), {(1, 1)}),  # a sun and an orthographic camera
])
def test_the_trace_compiled_per_projection_equals_the_run_time_one(name, make, projections):
    """The pass launches the trace compiled for each RSM view's projection and the camera's
    (``kernels_cisp.projected_trace``); each launch replayed with ``trace_photons``, which reads the projections at
    run time, on the same inputs: photon map, its second moment, the ledger's block rows, landings, outcome records
    and the hidden map bit for bit the same, over two frames, with photons stored under every projection seen."""
    from cisp_warp.photons import kernels_cisp as K

    r = Renderer(make(48, 36), RenderSettings(rsm_size=64, method="cisp", denoiser="svgf",
                                              photons=PhotonSettings(photons=20_000, seed=3)), device="cpu")
    p = r.photons
    p.record_hits = True
    at = {a.label: i for i, a in enumerate(K.trace_photons.adj.args)}
    outputs = ("photon_map", "photon_m2", "ledger", "hits", "outcome", "hidden_flux")
    launch = p.launch_photons
    seen = []

    def both(kernel, n, inputs):
        if kernel in (K.trace_photons, K.trace_photons_flow) or kernel not in K.trace_kernels():
            return launch(kernel, n, inputs)
        proj = (int(inputs[at["light_views"]].numpy()[inputs[at["view_index"]]]["orthographic"]),
                int(inputs[at["cameras"]].numpy()[0]["orthographic"]))
        assert kernel is K.projected_trace(False, *proj)
        before = {o: inputs[at[o]].numpy().copy() for o in outputs}
        launch(kernel, n, inputs)
        fast = {o: inputs[at[o]].numpy().copy() for o in outputs}
        for o in outputs:
            inputs[at[o]].assign(before[o])
        launch(K.trace_photons, n, inputs)
        for o in outputs:
            assert np.array_equal(inputs[at[o]].numpy(), fast[o]), o
        seen.append((proj, int((fast["outcome"][:, 3] == L_STORED).sum())))

    p.launch_photons = both
    for _ in range(2):
        r.render_frame()
    assert {proj for proj, _ in seen} == projections
    for proj in projections:
        assert sum(stored for q, stored in seen if q == proj) > 0, proj
