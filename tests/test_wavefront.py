"""Wavefront splatting (--splat wavefront): analytic irradiance from a few photons, the focus lines of the
sinusoid, the ledger, the fallback at silhouettes, and the splat against its naive numpy twin."""

import numpy as np
import pytest
import warp as wp

from cisp_warp import analytic
from cisp_warp.errors import SceneError
from cisp_warp.photons import PhotonSettings
from cisp_warp.photons import kernels_meshgrid as MK
from cisp_warp.photons import kernels_splat as K
from cisp_warp.photons.common import LEDGER_NAMES
from cisp_warp.photons.meshgrid import mesh_cells_numpy, sub_cells_numpy
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
    # the grid's corners read the RSM texels' position and normal: kept (LightMaps.keep_surface_maps), not the pilots
    assert all(r.specular.has_surface for r in rc.lights[0].rsm + rs.lights[0].rsm)
    assert not any(r.specular.has_surface for r in rc.lights[0].pilot)
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
    with pytest.raises(SceneError, match="--wavefront-grid"):
        PhotonSettings(splat="wavefront", wavefront_grid="texels").validate()
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
    assert E.Config("cisp", 10, "none", "wavefront", "mesh").label == "cisp wavefront mesh 10 none"
    assert E.render_settings(E.Config("cisp", 4096, "none", "wavefront", "mesh"), 64).photons.wavefront_grid == "mesh"
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


# --- the mesh grid (wavefront_grid="mesh") ---------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("theta_deg", [0.0, 30.0])
def test_mesh_grid_flat_water_is_analytic_everywhere(device, method, theta_deg):
    """The mesh grid over flat water (two triangles cut 45 × 45, ~4k cells): every pixel inside the beam
    E⊥·cos θ·(1 − F) to 0.5%; the ledger closes; the sampled power is E⊥·cos θ·(water area) exactly (the flux
    through the surface, not a sum of texels); stored = Σ irradiance × exact footprint."""
    r, a = render(analytic.flat_water(theta_deg), device, method, 64, wavefront_grid="mesh")
    assert r.photons.wavefront.grid.n == 45
    inner = analytic.flat_water_interior(a, theta_deg, half=0.35)
    assert inner.sum() > 300
    expected, _ = analytic.flat_water_answer(theta_deg)
    e = a["photon_map"][inner]
    np.testing.assert_allclose(e, np.broadcast_to(expected, e.shape), rtol=0.005)
    ledger = r.photons.read_ledger()
    assert ledger.closure() < 1e-5
    np.testing.assert_allclose(ledger["sampled"][0] + ledger["outside_fitted_view"][0],
                               1000.0 * np.cos(np.radians(theta_deg)) * 1.0, rtol=1e-4)
    stored = (a["photon_map"][..., 0].astype(np.float64) * analytic.footprint_area(a, r.view)).sum()
    np.testing.assert_allclose(stored, ledger["stored"][0], rtol=1e-4)
    state = r.photons.wavefront.last_view_state()
    refracted = state["tri_state"][: len(state["tri_state"]) // 2]
    assert (refracted == K.TRI_SPLAT).mean() > 0.4


def test_mesh_grid_sinusoid_matches_the_analytic_ray_map(device):
    """The sinusoid's strips of triangles cut 5 × 5 (~16k cells): the floor's profile follows the analytic ray
    map to 0.2% relative L2 (the RSM grid: 0.3% from 128² cells); the ledger closes."""
    W, H = 64, 32
    r, a = render(analytic.sinusoidal_water(W, H), device, "cisp", 128, wavefront_grid="mesh")
    measured = a["photon_map"][H // 4 : 3 * H // 4, :, 0].mean(axis=0)
    expected = analytic.sinusoidal_answer(W, H)
    rel = np.linalg.norm(measured - expected) / np.linalg.norm(expected)
    assert rel < 0.002, f"profile differs by {rel:.4f} (relative L2)"
    assert r.photons.read_ledger().closure() < 1e-5


@pytest.mark.parametrize("method", METHODS)
def test_mesh_grid_ledger_closes_over_cascades_and_silhouettes(device, method):
    """The plate scene (a silhouette, two fitted cascades): every watt the mesh cells sample ends in one ledger
    entry, the cascades share the water's cells once (sampled as by one whole view, to the cells the pilot's
    outside window cuts), cells split by the plate fall back, and the floor's irradiance is the RSM grid's."""
    rc, ac = render(plate_scene(), device, method, 64, wavefront_grid="mesh")
    rs, as_ = render(plate_scene(), device, method, 64, fit="scene", wavefront_grid="mesh")
    assert all(rc.lights[0].active) and rc.lights[0].skip_windows[1][2] > 0
    lc, ls = rc.photons.read_ledger(), rs.photons.read_ledger()
    assert lc.closure() < 1e-5 and ls.closure() < 1e-5
    np.testing.assert_allclose(lc["sampled"].sum(), ls["sampled"].sum(), rtol=5e-3)
    assert (rs.photons.wavefront.last_view_state()["tri_state"] == K.TRI_FALLBACK).sum() > 20
    _, ar = render(plate_scene(), device, method, 64, fit="scene")
    em, er = as_["photon_map"][..., 0], ar["photon_map"][..., 0]
    floor = (np.abs(as_["position"][..., 1] + 0.5) < 1e-3) & (er > 0) & (em > 0)
    assert floor.sum() > 400
    assert np.median(np.abs(em[floor] / er[floor] - 1.0)) < 0.01
    assert np.isfinite(ac["photon_map"]).all()


@wp.kernel
def _sub_cells(n: int, out: wp.array(dtype=wp.int32)):
    s = wp.tid()
    a, b, c = MK.sub_cell(n, s)
    for k in range(3):
        q = a
        if k == 1:
            q = b
        elif k == 2:
            q = c
        slot = MK.corner_slot(n, q[0], q[1])
        i, j = MK.corner_lattice(n, slot)
        out[(s * 3 + k) * 3 + 0] = q[0]
        out[(s * 3 + k) * 3 + 1] = q[1]
        out[(s * 3 + k) * 3 + 2] = int(i == q[0] and j == q[1])


def test_sub_cells_against_numpy(device):
    """The kernels' sub-triangle of a triangle cut n × n (closed-form row) equals the numpy enumeration for
    n = 1..40, its corners' slots invert, and the n² cells tile the triangle once (areas add to 1/2 · n²)."""
    for n in list(range(1, 13)) + [40]:
        out = wp.zeros(9 * n * n, dtype=wp.int32, device=device)
        wp.launch(_sub_cells, dim=n * n, inputs=[n, out], device=device)
        got = out.numpy().reshape(n * n, 3, 3)
        assert got[..., 2].all()
        want = np.array(sub_cells_numpy(n))
        np.testing.assert_array_equal(got[..., :2], want)
        e1, e2 = want[:, 1] - want[:, 0], want[:, 2] - want[:, 0]
        cross = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        assert (cross == 1).all()  # every cell one lattice half-square, wound as its triangle


def twin_scene():
    """Wavy water (a 6 × 6 grid with interpolated normals) under a soft-edged spot light, part of it shaded by
    an opaque card above it; beside it a metal plate and a rough specular plate; a floor below."""
    from cisp_warp.scene import Camera, Light, LightKind, Material, Scene
    from cisp_warp.scene.model import look_at_matrix

    k = 6
    xs = np.linspace(-0.5, 0.5, k + 1)
    x, z = np.meshgrid(xs, xs)
    h = 0.03 * np.sin(5.0 * x) * np.cos(4.0 * z)
    hx, hz = 0.15 * np.cos(5.0 * x) * np.cos(4.0 * z), -0.12 * np.sin(5.0 * x) * np.sin(4.0 * z)
    pts = np.stack([x, h, z], -1).reshape(-1, 3)
    nrm = np.stack([-hx, np.ones_like(h), -hz], -1).reshape(-1, 3)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    faces = []
    for j in range(k):
        for i in range(k):
            v = j * (k + 1) + i
            faces += [(v, v + k + 1, v + 1), (v + 1, v + k + 1, v + k + 2)]
    parts = [((pts, np.array(faces)), 1),
             (analytic.quad(0, -0.5, 0, (2, 0, 0), (0, 0, -2)), 0),
             (analytic.quad(0.2, 0.3, -0.1, (0.15, 0, 0), (0, 0, -0.15)), 0),
             (analytic.quad(0.75, 0.0, 0.0, (0.1, 0, 0), (0, 0, -0.45)), 2),
             (analytic.quad(-0.75, 0.0, 0.0, (0.15, 0, 0), (0, 0, -0.3)), 3)]
    metal = Material("metal", albedo=(0.9, 0.6, 0.3), roughness=0.05, metallic=1.0)
    rough = Material("brushed", albedo=(0.5, 0.5, 0.5), roughness=0.8, metallic=1.0)
    mats = [analytic.FLOOR, analytic.WATER, metal, rough]
    spot = Light(LightKind.SPOT, "spot", intensity=400.0, position=(0.05, 2.0, 0.02), direction=(0.0, -1.0, 0.0),
                 cone_angle=np.radians(26.0), cone_softness=0.4)
    cam = Camera(look_at_matrix((0.3, 1.6, 0.9), (0.0, -0.4, 0.0)), fov_y=np.radians(50), width=32, height=32,
                 near=0.05, far=10)
    flat = analytic.build(parts, cam, [spot], mats)
    nr = flat.normals.copy()
    nr[: len(pts)] = nrm  # the water's interpolated normals
    return Scene(flat.points, nr.astype(np.float32), flat.indices, flat.triangle_material, mats, [spot], cam)


def test_mesh_cells_match_their_naive_twin(device):
    """mesh_cells against the numpy twin (loops over triangles and sub-triangles, float64) on the twin scene:
    every cell's power in both sheets and the ledger parts the cells book (sampled, refracted, reflected,
    culled by roughness, absorbed by the metal); the card's shadow and the spot's soft edge are in it."""
    scene = twin_scene()
    r, _ = render(scene, device, "cisp", 24, rsm=128, fit="scene", wavefront_grid="mesh")
    lm = r.lights[0]
    vi = max(i for i, a in enumerate(lm.active) if a)
    state = r.photons.wavefront.last_view_state()
    rv = lm.rsm[vi]
    shadow = rv.shadow_depth.numpy()
    ps = r.settings.photons
    assert vi == 0
    args = (scene, scene.lights[0], [rv.view], lm.skip_windows, vi)
    rest = (state["tris"], state["bary"], state["n"], ps.roughness_cutoff, ps.thickness, ps.thickness_rel)
    twin = mesh_cells_numpy(*args, shadow, *rest)
    unshaded = mesh_cells_numpy(*args, np.zeros_like(shadow), *rest)
    assert state["n"] >= 2 and len(np.unique(state["tris"])) == 76
    assert len(state["tris"]) > 76  # the plates' elongated triangles are cut across
    tol = 1e-4 * np.abs(twin["tri_power"]).max()
    np.testing.assert_allclose(state["tri_power"], twin["tri_power"], rtol=1e-4, atol=tol)
    ledger = r.photons.read_ledger()
    for name in ("sampled", "refracted", "reflected", "culled_roughness", "absorbed"):
        want = twin["ledger"].get(name, np.zeros(3))
        assert want.sum() > 0, name
        np.testing.assert_allclose(ledger[name], want, rtol=1e-4)
    # the card shades part of the water, the spot's soft edge dims some cells against their neighbours
    assert 0.9 * unshaded["ledger"]["sampled"].sum() > twin["ledger"]["sampled"].sum()
    assert ledger.closure() < 1e-5


def test_grid_compare_tool_smoke(tmp_path):
    """tools/wavefront_grid_compare.py in its smoke setting (the sinusoid, 16k cells): both grids land within 1%
    of the analytic ray map, the ledgers close (no timings checked)."""
    import json
    import os
    import subprocess
    import sys

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = tmp_path / "grids.json"
    res = subprocess.run([sys.executable, os.path.join(root, "tools", "wavefront_grid_compare.py"), "--smoke",
                          "--device", "cpu", "--json", str(out)], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    run = json.loads(out.read_text())["runs"][0]
    assert run["mesh_n"] == 1  # the strips cut across into ~16k pieces, one cell each
    for g in ("rsm", "mesh"):
        assert run[g]["rel_rmse"] < 0.01 and run[g]["ledger_closure"] < 1e-5


def test_mesh_grid_refinement_resolves_silhouettes(device):
    """The plate's shadow and silhouette on the floor: cells whose corners land on the plate and the floor are cut
    4 × 4 and traced again instead of falling back to points at their corners. Against a fine grid (256² cells,
    refined), the map from 32² cells is at least twice as close refined as not; the ledger closes either way and
    the refinement's photons are counted."""
    def floor_error(r, a, ref):
        e, er = a["photon_map"][..., 0].astype(np.float64), ref["photon_map"][..., 0].astype(np.float64)
        m = er > 0
        return np.sqrt(np.mean((e[m] - er[m]) ** 2)) / np.mean(er[m])

    _, ref = render(plate_scene(), device, "cisp", 256, fit="scene", wavefront_grid="mesh")
    rr, ar = render(plate_scene(), device, "cisp", 32, fit="scene", wavefront_grid="mesh")
    rp, ap = render(plate_scene(), device, "cisp", 32, fit="scene", wavefront_grid="mesh", wavefront_refine=1)
    wf = rr.photons.wavefront
    listed, refined = wf.refined[0]
    assert refined == listed > 20
    assert (wf.last_view_state()["tri_state"] == K.TRI_REFINE).sum() == refined
    sub = wf.sub_state.numpy()[: refined * 16]
    assert (sub == K.TRI_SPLAT).sum() > 0.25 * (sub != K.TRI_EMPTY).sum()
    assert wf.photons_traced() == rp.photons.wavefront.photons_traced() + refined * 15
    plain, fine = floor_error(rp, ap, ref), floor_error(rr, ar, ref)
    assert fine < 0.5 * plain, f"refined {fine:.4f}, plain {plain:.4f}"
    for r in (rr, rp):
        assert r.photons.read_ledger().closure() < 1e-5


def test_cli_wavefront_grid_flags(tmp_path, capsys):
    """--wavefront-grid takes rsm or mesh; a --wavefront-refine below 1 is one sentence, before rendering."""
    from cisp_warp.cli import main

    tiny = ["--width", "32", "--height", "18", "--rsm-size", "64", "--photons", "2000", "--device", "cpu"]
    assert main(["--demo", "pool", "--out", str(tmp_path / "o"), "--splat", "wavefront", "--wavefront-grid", "mesh",
                 "--wavefront-refine", "0", *tiny]) == 2
    err = capsys.readouterr().err
    assert "--wavefront-refine must be an integer >= 1" in err and "Traceback" not in err
    with pytest.raises(SystemExit):
        main(["--demo", "pool", "--wavefront-grid", "texels", *tiny])


def test_grid_triangles_cut_strips_into_pieces_that_tile_them():
    """The sinusoid's strips (1 m long, 400 times longer than wide) are cut across into pieces of about one cell
    each (2.5 mm wide, 1/40 of the strip long at 65k cells) that tile every strip exactly (areas add up, same
    winding, corners inside it); a grid of right isoceles triangles is left whole."""
    from cisp_warp.photons.meshgrid import grid_triangles
    from cisp_warp.scene.model import LAYER_SPECULAR

    s = analytic.sinusoidal_water(64, 32)
    spec = np.flatnonzero(s.triangle_layers() & LAYER_SPECULAR)
    tris, bary = grid_triangles(s.points, s.indices, spec, 65536)
    assert 0.8 * 65536 < len(tris) < 1.2 * 65536 and set(tris) == set(spec)
    assert (bary >= -1e-6).all() and (bary.sum(-1) <= 1 + 1e-6).all()
    e1, e2 = bary[:, 1] - bary[:, 0], bary[:, 2] - bary[:, 0]
    signed = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]  # share of the scene triangle, + = same winding
    assert (signed > 0).all()
    np.testing.assert_allclose(np.bincount(tris, weights=signed)[spec], 1.0, rtol=1e-5)
    p = s.points.astype(np.float64)[s.indices.reshape(-1, 3)[tris]]
    x = p[:, :1] + (p[:, 1:2] - p[:, :1]) * bary[..., :1] + (p[:, 2:3] - p[:, :1]) * bary[..., 1:]
    edges = np.linalg.norm(np.roll(x, -1, axis=1) - x, axis=-1)
    twice = np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)
    assert edges.max() < 0.03  # the 1 m strips in ~40 stripes (their tips stay as thin as the strip's)
    assert twice.max() < 3.0 * 2.0 / 65536  # no piece above 3 cells of the budget (cells of area 1 m² / 65536)
    k = 16  # a regular grid of right isoceles triangles stays whole
    g = np.stack(np.meshgrid(np.arange(k + 1), np.arange(k + 1)), -1).reshape(-1, 2).astype(np.float32)
    pts = np.stack([g[:, 0], np.zeros(len(g)), g[:, 1]], 1)
    faces = [(j * (k + 1) + i, (j + 1) * (k + 1) + i, j * (k + 1) + i + 1) for j in range(k) for i in range(k)]
    t2, _ = grid_triangles(pts, np.array(faces), np.arange(len(faces)), 65536)
    assert len(t2) == len(faces)
