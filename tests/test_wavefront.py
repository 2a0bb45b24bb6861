"""Wavefront splatting (--splat wavefront): analytic irradiance from a few photons, the focus lines of the
sinusoid, the ledger, the fallback at silhouettes, and the splat against its naive numpy twin."""

import numpy as np
import pytest
import warp as wp

from cisp_warp import analytic
from cisp_warp.errors import SceneError
from cisp_warp.photons import PhotonSettings
from cisp_warp.photons import kernels_splat as K
from cisp_warp.photons.common import LEDGER_NAMES
from cisp_warp.photons.wavefront import pixel_triangle_overlap_np, splat_numpy
from cisp_warp.raster.views import LightViewSettings
from cisp_warp.render import Renderer, RenderSettings

METHODS = ["cisp", "sspm"]


def render(scene, device, method, grid, rsm=256, frame_count=1, fit="camera", **kw):
    """One frame (or ``frame_count``) with ``grid``² cells per light, raw (no denoiser); light views fitted to
    the camera (the default) or whole (``fit="scene"``)."""
    settings = RenderSettings(rsm_size=rsm, method=method, denoiser="none", light_views=LightViewSettings(fit=fit),
                              photons=PhotonSettings(photons=grid * grid, splat="wavefront", seed=3, **kw))
    r = Renderer(scene, settings, device=device)
    for _ in range(frame_count):
        r.render_frame()
    return r, r.aovs(include_rsm=False)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("theta_deg", [0.0, 30.0])
def test_flat_water_is_analytic_everywhere_from_a_64_grid(device, method, theta_deg):
    """Floor under flat water: every pixel inside the beam E⊥·cos θ·(1 − F) to 0.5%, from 64² cells
    (4k cells: point photons need ~100× as many for 1% on the mean); the ledger closes; the stored power is
    Σ irradiance × exact footprint."""
    r, a = render(analytic.flat_water(theta_deg), device, method, 64)
    inner = analytic.flat_water_interior(a, theta_deg, half=0.35)
    assert inner.sum() > 300
    expected, _ = analytic.flat_water_answer(theta_deg)
    e = a["photon_map"][inner]
    np.testing.assert_allclose(e, np.broadcast_to(expected, e.shape), rtol=0.005)
    ledger = r.photons.read_ledger()
    assert ledger.closure() < 1e-5
    stored = (a["photon_map"][..., 0].astype(np.float64) * analytic.footprint_area(a, r.view)).sum()
    np.testing.assert_allclose(stored, ledger["stored"][0], rtol=1e-4)
    # the refracted sheet is splatted, the reflected one (to the sky) falls back and is booked as lost
    state = r.photons.wavefront.last_view_state()
    cells = state["cells_x"] * state["cells_y"]
    refracted = state["tri_state"][: 2 * cells]
    assert (refracted == K.TRI_SPLAT).mean() > 0.4
    traced = ledger["refracted"].sum() + ledger["reflected"].sum()
    np.testing.assert_allclose(traced, ledger["sampled"].sum(), rtol=1e-6)


@pytest.mark.parametrize("method", METHODS)
def test_sinusoid_matches_the_analytic_ray_map_from_a_128_grid(device, method):
    """Water h(x) = A sin(kx): the floor irradiance per pixel column (binned, focus lines included) follows
    the analytic ray map to 3% relative L2 from 128² cells; the brightest column sits where the map says."""
    W, H = 64, 32
    r, a = render(analytic.sinusoidal_water(W, H), device, method, 128)
    measured = a["photon_map"][H // 4 : 3 * H // 4, :, 0].mean(axis=0)
    expected = analytic.sinusoidal_answer(W, H)
    assert expected.max() > 2.5 * expected.min()  # it does focus
    rel = np.linalg.norm(measured - expected) / np.linalg.norm(expected)
    assert rel < 0.03, f"profile differs by {rel:.4f} (relative L2)"
    assert np.array_equal(measured > 1.5 * measured.mean(), expected > 1.5 * expected.mean())
    assert r.photons.read_ledger().closure() < 1e-5


def test_folded_caustic_sums_its_sheets(device):
    """A = 3 cm: the waves focus 0.21 m below the surface, above the floor (0.3 m): the map folds, each cell's
    triangle turns over past the focus, and the sheets add up to the analytic profile (its sharp peak
    included: power integrated per pixel stays finite)."""
    W, H = 64, 32
    r, a = render(analytic.sinusoidal_water(W, H, A=0.03), device, "cisp", 128)
    measured = a["photon_map"][H // 4 : 3 * H // 4, :, 0].mean(axis=0)
    expected = analytic.sinusoidal_answer(W, H, A=0.03)
    assert expected.max() > 5 * expected.mean()  # a fold's bright line
    rel = np.linalg.norm(measured - expected) / np.linalg.norm(expected)
    assert rel < 0.04, f"folded profile differs by {rel:.4f}"
    assert np.isfinite(a["photon_map"]).all()
    assert r.photons.read_ledger().closure() < 1e-5


def test_no_noise_same_map_every_frame(device):
    """The grid is the same every frame (no random sampling): a static scene gives the same map."""
    r, a = render(analytic.flat_water(30.0), device, "cisp", 32, frame_count=1)
    r.render_frame()
    b = r.aovs(include_rsm=False)
    np.testing.assert_allclose(a["photon_map"], b["photon_map"], rtol=1e-6, atol=1e-6)


def plate_scene(size=48):
    """Flat water over a floor with an opaque plate floating 0.2 m above it: the plate's silhouette splits
    grid cells between two receivers 0.2 m apart."""
    base = analytic.flat_water(20.0, size=size)
    parts = [(analytic.quad(0, 0, 0, (0.5, 0, 0), (0, 0, -0.5)), 1),
             (analytic.quad(0, -0.5, 0, (2, 0, 0), (0, 0, -2)), 0),
             (analytic.quad(0.25, -0.3, 0.0, (0.15, 0, 0), (0, 0, -0.2)), 0)]
    return analytic.build(parts, base.camera, base.lights, base.materials)


@pytest.mark.parametrize("method", METHODS)
def test_silhouette_cells_fall_back_to_points(device, method):
    """Grid triangles with corners on the plate and on the floor (seen, or hidden under the plate) are not
    splatted across the gap: they fall back to point deposits; triangles on the floor alone are splatted (one
    whole light view: its grid's records are the last view's)."""
    r, a = render(plate_scene(), device, method, 64, fit="scene")
    state = r.photons.wavefront.last_view_state()
    cx, cy = state["cells_x"], state["cells_y"]
    row = cx + 1
    landed = [LEDGER_NAMES.index(n) for n in ("stored", "occluded", "lost_camera_view")]
    split = floor = 0
    for t in np.flatnonzero(state["tri_state"][: 2 * cx * cy]):  # refracted sheet
        c, half = t // 2, t % 2
        base = (c // cx) * row + c % cx
        ids = [base, base + 1, base + row + 1] if half == 0 else [base, base + row + 1, base + row]
        if not all(state["entry"][i] in landed for i in ids):
            continue
        heights = state["pos"][ids, 1]
        if heights.max() > -0.35 and heights.min() < -0.45:  # plate (-0.3 m) and floor (-0.5 m) corners
            split += 1
            assert state["tri_state"][t] == K.TRI_FALLBACK
        elif heights.max() < -0.45 and all(state["entry"][i] == landed[0] for i in ids):
            floor += 1
            assert state["tri_state"][t] == K.TRI_SPLAT
    assert split > 20 and floor > 1000
    assert r.photons.read_ledger().closure() < 1e-5
    assert np.isfinite(a["photon_map"]).all()


@pytest.mark.parametrize("method", METHODS)
def test_fitted_cascades_share_the_light_as_whole_views_do(device, method):
    """Grids over the camera-fitted cascades (the plate scene fits two: the finer window inside the coarser
    one, whose grid leaves the window's texels to it): the light's specular power is sampled once (as by one
    whole view, to the texels cut by the window edges), the ledger closes, and the floor's irradiance is the
    whole view's where both splat it."""
    rc, ac = render(plate_scene(), device, method, 64)
    rs, as_ = render(plate_scene(), device, method, 64, fit="scene")
    assert all(rc.lights[0].active) and rc.lights[0].skip_windows[1][2] > 0  # two cascades, a window skipped
    lc, ls = rc.photons.read_ledger(), rs.photons.read_ledger()
    assert lc.closure() < 1e-5
    whole = lc["sampled"].sum()
    np.testing.assert_allclose(whole, ls["sampled"].sum(), rtol=2e-3)
    ec, es = ac["photon_map"][..., 0], as_["photon_map"][..., 0]
    floor = (np.abs(ac["position"][..., 1] + 0.5) < 1e-3) & (es > 0)
    assert floor.sum() > 400
    assert np.median(np.abs(ec[floor] / es[floor] - 1.0)) < 0.01
    np.testing.assert_allclose(lc["stored"].sum(), ls["stored"].sum(), rtol=0.02)


def test_splat_matches_its_naive_twin(device):
    """The splat kernel against the numpy twin (polygon clipping the other way round) on the same photon
    records: photon map and every ledger part the splat books, splats, fallbacks and occlusions included (one
    whole light view, so that the map and the ledger are the last view's alone)."""
    r, a = render(plate_scene(size=32), device, "cisp", 24, fit="scene")
    state = r.photons.wavefront.last_view_state()
    state["image_width"] = r.view.width
    g = r.gbuffer
    ps = r.settings.photons
    foot = analytic.footprint_area(a, r.view).reshape(-1)
    twin = splat_numpy(state, r.view.project, g.depth.numpy().reshape(-1), g.position.numpy().reshape(-1, 3),
                       g.normal.numpy().reshape(-1, 3), foot, ps.thickness, ps.thickness_rel, r.view.near)
    assert (twin["tri_state"] == 1).sum() > 50 and (twin["tri_state"] == 2).sum() > 50
    np.testing.assert_array_equal(twin["tri_state"][state["tri_power"].any(axis=1)],
                                  state["tri_state"][state["tri_power"].any(axis=1)])
    np.testing.assert_allclose(a["photon_map"].reshape(-1, 3), twin["photon_map"], rtol=2e-3, atol=1e-3 * 1000)
    ledger = r.photons.read_ledger()
    for name in ("stored", "occluded", "lost_camera_view", "rejected"):
        np.testing.assert_allclose(ledger[name], twin["ledger"].get(name, np.zeros(3)), rtol=1e-4, atol=1e-6)


@wp.kernel
def _overlaps(tris: wp.array(dtype=wp.vec2), px: int, py: int, out: wp.array(dtype=float)):
    t, j, i = wp.tid()
    a, b, c = tris[3 * t], tris[3 * t + 1], tris[3 * t + 2]
    out[(t * py + j) * px + i] = K.triangle_pixel_overlap(a, b, c, float(i), float(j))


@wp.kernel
def _covers(tris: wp.array(dtype=wp.vec2), px: int, py: int, out: wp.array(dtype=float)):
    t, j, i = wp.tid()
    a, b, c = tris[3 * t], tris[3 * t + 1], tris[3 * t + 2]
    orient = wp.sign((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]))
    out[(t * py + j) * px + i] = K.pixel_cover(a, b, c, orient, float(i), float(j))


def test_pixel_cover_shortcuts_agree_with_clipping(device, rng):
    """The splat's pixel cover (no clipping for pixels wholly outside or inside the triangle) equals the
    clipped overlap on every pixel, for large triangles (many inside pixels), slivers and sub-pixel ones."""
    n, size = 60, 12
    tris = rng.uniform(-2.0, size + 2.0, (n, 3, 2))
    tris[:10] = tris[:10] * 0.05 + 4.3
    tris[10:20, 2] = tris[10:20, 0] + 1e-3 * (tris[10:20, 1] - tris[10:20, 0])
    tris[20:25] = np.round(tris[20:25])  # corners on pixel corners: edges along pixel edges
    flat = wp.array(tris.reshape(-1, 2), dtype=wp.vec2, device=device)
    got = wp.zeros(n * size * size, dtype=float, device=device)
    want = wp.zeros(n * size * size, dtype=float, device=device)
    wp.launch(_covers, dim=(n, size, size), inputs=[flat, size, size, got], device=device)
    wp.launch(_overlaps, dim=(n, size, size), inputs=[flat, size, size, want], device=device)
    assert (got.numpy() == 1.0).sum() > 200  # the inside shortcut is taken
    np.testing.assert_allclose(got.numpy(), want.numpy(), atol=2e-5)


def test_pixel_triangle_overlap_against_numpy(device, rng):
    """Triangle ∩ pixel areas (either orientation, slivers, triangles inside one pixel) equal the numpy
    twin's, and add up to the triangle's area over the pixels that hold it."""
    n, size = 60, 6
    tris = rng.uniform(0.0, size, (n, 3, 2))
    tris[:10] = tris[:10] * 0.1 + 2.3  # inside one pixel or two
    tris[10:20, 2] = tris[10:20, 0] + 1e-3 * (tris[10:20, 1] - tris[10:20, 0])  # slivers
    out = wp.zeros(n * size * size, dtype=float, device=device)
    wp.launch(_overlaps, dim=(n, size, size), inputs=[wp.array(tris.reshape(-1, 2), dtype=wp.vec2, device=device),
                                                      size, size, out], device=device)
    got = out.numpy().reshape(n, size, size)
    want = np.array([[[pixel_triangle_overlap_np(t, i, j) for i in range(size)] for j in range(size)] for t in tris])
    np.testing.assert_allclose(got, want, atol=2e-5)
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    np.testing.assert_allclose(got.sum(axis=(1, 2)), area, rtol=1e-4, atol=1e-5)


def test_splat_setting_is_checked():
    with pytest.raises(SceneError, match="--splat"):
        PhotonSettings(splat="quads").validate()
    with pytest.raises(SceneError, match="cisp or sspm"):
        RenderSettings(method="caustics_map", photons=PhotonSettings(splat="wavefront")).validate()


def test_evaluation_runs_a_wavefront_curve():
    """evaluate.py's configs carry the splat to the renderer, and its analytic sinusoid reference is the
    ray map's profile on every floor pixel with no standard error."""
    import os
    import sys

    from cisp_warp import evaluation as E

    s = E.render_settings(E.Config("cisp", 4096, "none", "wavefront"), 64)
    assert s.photons.splat == "wavefront" and s.denoiser == "none" and s.photons.photons == 4096
    assert E.Config("sspm", 10, "caustic", "wavefront").label == "sspm wavefront 10 caustic"
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tools"))
    from evaluate import analytic_sinusoid_reference

    w, h = 32, 16
    depth = np.ones((h, w), np.float32)
    depth[0, 0] = 0.0
    ref = {"depth": depth, "photon_map": np.zeros((h, w, 3), np.float32),
           "caustics_stderr": np.ones((h, w, 3), np.float32)}
    out = analytic_sinusoid_reference(ref, w, h)
    profile = analytic.sinusoidal_answer(w, h)
    np.testing.assert_allclose(out["photon_map"][1, :, 1], profile, rtol=1e-3)
    assert out["photon_map"][0, 0].max() == 0.0 and not out["caustics_stderr"].any()
