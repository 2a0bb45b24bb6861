"""Photon geometry: exact per-photon origin and normal (the surface under the sample point, not the texel),
and light views fitted to what the camera sees (cascades), with the energy ledger closing."""

import numpy as np
import pytest
from scipy.ndimage import uniform_filter

from cisp_warp import analytic
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.scene.device import triangle_neighbors


def naive_neighbors(indices):
    """Dictionary twin of :func:`triangle_neighbors`."""
    tri = np.asarray(indices).reshape(-1, 3)
    edges = {}
    for t, (a, b, c) in enumerate(tri):
        for corner, e in enumerate(((b, c), (c, a), (a, b))):
            edges.setdefault(tuple(sorted(int(v) for v in e)), []).append((t, corner))
    out = np.full((len(tri), 3), -1)
    for users in edges.values():
        if len(users) == 2:
            (t0, c0), (t1, c1) = users
            out[t0, c0], out[t1, c1] = t1, t0
    return out


def test_triangle_neighbors_match_naive_twin(rng):
    scene = analytic.wavy_water(grid=9)
    np.testing.assert_array_equal(triangle_neighbors(scene.indices), naive_neighbors(scene.indices))
    # a fan with a non-manifold edge (three triangles on edge 0-1) leaves that edge unconnected
    fan = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [2, 1, 5]])
    np.testing.assert_array_equal(triangle_neighbors(fan), naive_neighbors(fan))
    perm = rng.permutation(len(scene.indices))
    np.testing.assert_array_equal(triangle_neighbors(scene.indices[perm]), naive_neighbors(scene.indices[perm]))


def render(device, method, rsm, photons, seed, fit="scene", **kw):
    scene = analytic.wavy_water(width=32, height=32, grid=64, **kw)
    r = Renderer(scene, RenderSettings(rsm_size=rsm, method=method, denoiser="none",
                                       photons=PhotonSettings(photons=photons, seed=seed)), device=device)
    r.render_frame()
    return r, r.aovs(include_rsm=False)["photon_map"][..., 0].astype(np.float64)


def rel_rmse(a, b):
    a, b = uniform_filter(a, 3), uniform_filter(b, 3)
    return float(np.sqrt(((a - b) ** 2).mean()) / b.mean())


@pytest.mark.parametrize("method", ["sspm", "cisp"])
def test_converged_caustic_does_not_depend_on_rsm_size(device, method):
    """Wavy water (a 3 cm triangle grid) seen close up. With one normal per texel, a coarse RSM draws a
    lattice of its texels into the folded caustic (relative RMSE 0.51 against noise 0.019 here); with each
    photon's own surface normal it agrees with a finer RSM within the photon noise (measured between two
    seeds of the fine RSM). sspm: 6 cm texels (two triangles each) against 1.5 cm. cisp also marches the
    coarse RSM's depth, which moves its end points a little (its own error, 1.6× the noise at 3 cm
    texels): 3 cm against 1.5 cm."""
    photons = 1_500_000
    _, coarse = render(device, method, 32 if method == "sspm" else 64, photons, seed=1)
    r, fine = render(device, method, 128, photons, seed=2)
    _, fine2 = render(device, method, 128, photons, seed=3)
    noise = rel_rmse(fine2, fine)
    err = rel_rmse(coarse, fine)
    assert fine.mean() > 0 and r.photons.read_ledger().closure() < 1e-5
    limit = 1.5 if method == "sspm" else 2.2
    assert err < limit * noise, f"RSM 32² vs 128²: {err:.3f}, noise {noise:.3f}"


# ---------------------------------------------------------------------------------------------------------
# light views fitted to the camera


def test_window_view_maps_the_pixels_of_its_window(rng):
    """A window view is the same view with pixels scaled and shifted: pixel (px, py) of the whole view is
    ((px − x0)·sx, (py − y0)·sy) of the window view, perspective and orthographic, whatever the aspect."""
    from cisp_warp.raster.views import View, window_view
    from cisp_warp.scene.model import look_at_matrix

    pose = look_at_matrix((0.3, 2.0, 0.1), (0.0, 0.0, 0.0))
    pts = rng.uniform(-1, 1, (200, 3)) * [1.0, 0.3, 1.0]
    for ortho, f in ((False, 300.0), (True, 150.0)):
        whole = View(pose, 256, 256, 0.01, 10.0, f, f, ortho, "w")
        win = (40.5, 17.0, 200.0, 101.0)
        v = window_view(whole, win, 64, "c")
        a, b = whole.project(pts), v.project(pts)
        sx, sy = 64 / (win[2] - win[0]), 64 / (win[3] - win[1])
        np.testing.assert_allclose(b[:, 0], (a[:, 0] - win[0]) * sx, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(b[:, 1], (a[:, 1] - win[1]) * sy, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(b[:, 2], a[:, 2])


def test_turned_view_maps_pixels_by_rotate_pixels(rng):
    """rotated_view's pixels are rotate_pixels of the view's, for square and non-square pixels (a sun's
    view fitted to a long pool has fx != fy), perspective and orthographic."""
    from cisp_warp.raster.views import View, rotate_pixels, rotated_view
    from cisp_warp.scene.model import look_at_matrix

    pose = look_at_matrix((0.3, 2.0, 0.1), (0.0, 0.0, 0.0))
    pts = rng.uniform(-1, 1, (100, 3)) * [1.0, 0.3, 1.0]
    for ortho, fx, fy in ((False, 300.0, 300.0), (True, 150.0, 60.0), (False, 200.0, 320.0)):
        v = View(pose, 128, 128, 0.01, 10.0, fx, fy, ortho, "w")
        for angle in (0.3, 1.2, -0.7):
            a, b = v.project(pts), rotated_view(v, angle).project(pts)
            u, w = rotate_pixels(a[:, 0], a[:, 1], v.cx, v.cy, angle, fx / fy)
            np.testing.assert_allclose(b[:, 0], u, atol=1e-9)
            np.testing.assert_allclose(b[:, 1], w, atol=1e-9)


def test_turned_windows_cover_a_diagonal_band_tightly():
    from cisp_warp.raster.views import fit_angle, fit_windows, rotate_pixels

    depth = np.zeros((64, 64), np.float32)
    for k in range(10, 54):  # a thin band along the diagonal
        depth[k, k - 3 : k + 3] = 1.0
    angle = fit_angle(depth)
    assert abs(angle - np.pi / 4) < 0.1
    (x0, y0, x1, y1), = fit_windows(depth, 1, 1.0, angle)
    (a0, b0, a1, b1), = fit_windows(depth, 1, 1.0, 0.0)
    assert (x1 - x0) * (y1 - y0) < 0.35 * (a1 - a0) * (b1 - b0)
    jj, ii = np.nonzero(depth)
    for di, dj in ((0, 0), (1, 0), (0, 1), (1, 1)):  # every useful texel's corners lie inside the turned window
        u, v = rotate_pixels(ii + di, jj + dj, 32.0, 32.0, angle)
        assert (u >= x0).all() and (u <= x1).all() and (v >= y0).all() and (v <= y1).all()


def test_fitted_texel_solid_angles_match_the_host_formula(device):
    """The device's float64 texel solid angles of a small off-centre window equal View.texel_solid_angle,
    and the window's texels sum to the solid angle of the whole view's pixels they cover."""
    import warp as wp

    from cisp_warp.raster.light_maps import texel_solid_angles
    from cisp_warp.raster.views import View, window_view

    whole = View(np.eye(4), 128, 128, 0.01, 10.0, 64.0, 64.0, False, "w")
    v = window_view(whole, (90.0, 20.0, 94.0, 23.0), 32, "c")
    out = wp.zeros(32 * 32, dtype=wp.float32, device=device)
    wp.launch(texel_solid_angles, dim=32 * 32, inputs=[v.params(), out], device=device)
    host = v.texel_solid_angle()
    np.testing.assert_allclose(out.numpy().reshape(32, 32), host, rtol=2e-4)
    np.testing.assert_allclose(host.sum(), whole.texel_solid_angle()[20:23, 90:94].sum(), rtol=1e-9)


def test_cascade_solid_angles_cover_every_texel_once_and_only_when_moved(device):
    """The per-frame kernel (several texels a thread) writes exactly what texel_solid_angles writes, for a texel
    count that is not a multiple of its texels per thread, and nothing when the view stood still."""
    import warp as wp

    from cisp_warp.raster.light_maps import (CASCADE_TEXELS_PER_THREAD, CascadeState, cascade_solid_angles,
                                             texel_solid_angles)
    from cisp_warp.raster.views import View, ViewParams, window_view

    whole = View(np.eye(4), 128, 128, 0.01, 10.0, 64.0, 64.0, False, "w")
    v = window_view(whole, (90.0, 20.0, 97.0, 25.0), 37, "c")  # 37² texels: 1369 = 171 * 8 + 1
    n = 37 * 37
    assert n % CASCADE_TEXELS_PER_THREAD != 0
    twin = wp.zeros(n, dtype=wp.float32, device=device)
    wp.launch(texel_solid_angles, dim=n, inputs=[v.params(), twin], device=device)
    views = wp.array([v.params(), v.params()], dtype=ViewParams, device=device)
    states = []
    for changed in (1, 0):
        st = CascadeState()
        st.active, st.active_views, st.texel_scale, st.changed = 1, 1, 1.0, changed
        states.append(st)
    states = wp.array(states, dtype=CascadeState, device=device)
    threads = (n + CASCADE_TEXELS_PER_THREAD - 1) // CASCADE_TEXELS_PER_THREAD
    for k, expect in ((0, twin.numpy()), (1, np.full(n, -1.0, np.float32))):
        out = wp.full(n, -1.0, dtype=wp.float32, device=device)
        wp.launch(cascade_solid_angles, dim=threads, inputs=[views, states, k, n, out], device=device)
        np.testing.assert_array_equal(out.numpy(), expect)


def test_fit_windows_nest_and_merge():
    from cisp_warp.raster.views import fit_windows

    depth = np.zeros((64, 64), np.float32)
    assert fit_windows(depth, 2, 2.0) == []
    depth[10:14, 20:24] = 1.0  # near receivers: a small patch
    depth[5:60, 8:50] = np.where(depth[5:60, 8:50] > 0, 1.0, 9.0)  # far ones around it
    wins = fit_windows(depth, 2, 1.0)
    assert len(wins) == 2
    (a0, b0, a1, b1), (c0, d0, c1, d1) = wins
    assert c0 <= a0 < a1 <= c1 and d0 <= b0 < b1 <= d1  # nested, finest first
    assert a0 <= 20 and a1 >= 24 and b0 <= 10 and b1 >= 14 and c0 <= 8 and c1 >= 50  # cover, with a margin
    np.testing.assert_allclose((c0, d0, c1, d1), (8 - 1 - 0.02 * 42, 5 - 1 - 0.02 * 55, 50 + 1 + 0.02 * 42,
                                                  60 + 1 + 0.02 * 55), atol=1e-6)
    depth[:] = np.where(depth > 0, 1.0, 0.0)  # one depth everywhere: one window
    assert len(fit_windows(depth, 3, 1.0)) == 1


def fitted_pair(device, method, scene_fn, photons, rsm=128, seed=1):
    """(scene-wide, camera-fitted) renders of the same scene and photon count: renderer, photon map, ledger."""
    from cisp_warp.raster import LightViewSettings

    out = {}
    for fit in ("scene", "camera"):
        r = Renderer(scene_fn(), RenderSettings(rsm_size=rsm, method=method, denoiser="none",
                                                light_views=LightViewSettings(fit=fit),
                                                photons=PhotonSettings(photons=photons, seed=seed)), device=device)
        r.render_frame()
        out[fit] = (r, r.aovs(include_rsm=False)["photon_map"][..., 0].astype(np.float64), r.photons.read_ledger())
    return out


@pytest.mark.parametrize("method", ["cisp", "sspm"])
def test_fitted_views_send_photons_where_the_camera_looks(device, method):
    """Close-up of a wavy floor caustic: the fitted views trace only the water whose light the camera sees
    (the rest booked outside_fitted_view), the ledger closes, the same power is sampled and stored, at
    least 10× the share of traced photons lands in view, and the image is the same but less noisy."""
    res = fitted_pair(device, method, lambda: analytic.wavy_water(width=32, height=32, grid=64), 400_000)
    (_, whole, lw), (rf, fitted, lf) = res["scene"], res["camera"]
    assert lw.closure() < 1e-5 and lf.closure() < 1e-5
    assert lw["outside_fitted_view"].sum() == 0.0 and lf["outside_fitted_view"][0] > 0.8 * lf["sampled"][0]
    np.testing.assert_allclose(lf["sampled"], lw["sampled"], rtol=2e-3)  # whole power, pilot vs RSM edges
    np.testing.assert_allclose(lf["stored"], lw["stored"], rtol=0.02)
    traced = lambda led: led["sampled"][0] - led["outside_fitted_view"][0]  # noqa: E731
    gain = (lf["stored"][0] / traced(lf)) / (lw["stored"][0] / traced(lw))
    assert gain > 10.0, f"photons landing in view: {gain:.1f}× the whole view's"
    np.testing.assert_allclose(fitted.mean(), whole.mean(), rtol=0.02)
    _, converged = render(device, method, 128, 4_000_000, seed=5)
    assert rel_rmse(fitted, converged) < 0.5 * rel_rmse(whole, converged)


@pytest.mark.parametrize("kind", ["spot", "point"])
def test_fitted_perspective_views_keep_the_energy(device, kind):
    """A spot's view and a point light's cube faces fitted to a camera that sees part of the floor: the
    floor irradiance it sees is the whole views', the ledger closes, and the skipped power is booked."""
    import math

    from cisp_warp.scene import Camera, Light, LightKind
    from cisp_warp.scene.model import look_at_matrix

    def scene():
        water = (analytic.quad(0, 0, 0, (0.5, 0, 0), (0, 0, -0.5)), 1)
        floor = (analytic.quad(0, -0.5, 0, (2, 0, 0), (0, 0, -2)), 0)
        cam = Camera(look_at_matrix((0.3, 0.4, 0.1), (0.2, -0.5, 0)), fov_y=math.radians(45), width=32, height=32,
                     near=0.05, far=10)
        light = Light(LightKind[kind.upper()], "lamp", intensity=100.0, position=(0.1, 0.8, 0.05),
                      direction=(0, -1, 0), cone_angle=math.radians(50))
        return analytic.build([water, floor], cam, [light])

    res = fitted_pair(device, "cisp", scene, 200_000)
    (_, whole, lw), (rf, fitted, lf) = res["scene"], res["camera"]
    assert lf.closure() < 1e-5
    assert lf["outside_fitted_view"][0] > 0.1 * lf["sampled"][0]
    np.testing.assert_allclose(lf["sampled"], lw["sampled"], rtol=0.01)
    assert sum(rf.lights[0].active) >= 1
    ref = Renderer(scene(), RenderSettings(rsm_size=128, method="reference", denoiser="none",
                                           photons=PhotonSettings(photons=1_000_000, reference_photons=2_000_000)),
                   device=device)
    ref.render_frame()
    truth = ref.photons.photon_map.numpy()[:, 0].astype(np.float64).mean()
    # the fitted views' finer texels are closer to the truth than the whole 128² view (2.5% low for the spot)
    assert abs(fitted.mean() / truth - 1.0) < 0.012
    assert abs(fitted.mean() / truth - 1.0) < abs(whole.mean() / truth - 1.0) + 0.005


def test_nothing_seen_nothing_traced(device):
    """A camera that sees none of the caustic's receivers: every cascade inactive, all the power booked
    outside_fitted_view, an empty photon map, and the ledger still closes."""
    import math

    from cisp_warp.scene import Camera
    from cisp_warp.scene.model import look_at_matrix

    def scene():
        s = analytic.wavy_water(width=16, height=16, grid=16)
        s.camera = Camera(look_at_matrix((0.0, 1.0, 0.0), (0.0, 3.0, 0.1)), fov_y=math.radians(30), width=16,
                          height=16, near=0.05, far=10)  # looking up at the sky
        return s

    r = Renderer(scene(), RenderSettings(rsm_size=64, denoiser="none", photons=PhotonSettings(photons=10_000)),
                 device=device)
    r.render_frame()
    led = r.photons.read_ledger()
    assert not any(r.lights[0].active)
    assert led["sampled"][0] > 0 and led.closure() < 1e-6
    np.testing.assert_allclose(led["outside_fitted_view"], led["sampled"], rtol=1e-6)
    assert r.photons.photon_map.numpy().max() == 0.0


def test_cascades_leave_their_finer_window_to_the_finer_view(device):
    """Two nested cascades forced on the close-up (the finer over the middle of the coarser): each
    region's power is sampled once, so the image equals the single fitted view's within noise and the
    ledger closes."""
    import warp as wp  # noqa: F401

    from cisp_warp.raster import LightViewSettings

    scene = analytic.wavy_water(width=32, height=32, grid=64)
    r = Renderer(scene, RenderSettings(rsm_size=128, method="sspm", denoiser="none",
                                       light_views=LightViewSettings(fit="camera", cascades=2),
                                       photons=PhotonSettings(photons=400_000, seed=2)), device=device)
    r.render_frame()  # fits one window
    lm = r.lights[0]
    (x0, y0, x1, y1) = lm.outside_windows[0]
    inner = (x0 + 0.3 * (x1 - x0), y0 + 0.3 * (y1 - y0), x0 + 0.6 * (x1 - x0), y0 + 0.6 * (y1 - y0))
    lm.set_windows([[inner, (x0, y0, x1, y1)]])
    assert lm.active == [True, True]
    sk = lm.skip_windows[1]
    assert sk[2] > sk[0] > 0 and sk[3] > sk[1] > 0
    for lmv in r.lights:
        lmv.render(r.raster)
    r.photons.trace(r.gbuffer, r.view_params, 1)
    two = r.photons.photon_map.numpy()[:, 0].astype(np.float64).reshape(32, 32)
    led = r.photons.read_ledger()
    assert led.closure() < 1e-5
    _, one = render(device, "sspm", 128, 4_000_000, seed=5)
    assert rel_rmse(two, one) < 0.1
    np.testing.assert_allclose(two.mean(), one.mean(), rtol=0.02)


def test_light_view_figures_smoke(tmp_path):
    """tools/light_view_figures.py runs end to end at smoke size and writes its table and crops."""
    import os
    import subprocess
    import sys

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {**os.environ, "PYTHONPATH": root}
    res = subprocess.run([sys.executable, os.path.join(root, "tools", "light_view_figures.py"), "store", "--smoke",
                          "--out", str(tmp_path)], capture_output=True, text=True, env=env, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    table = (tmp_path / "store.md").read_text()
    assert "wavy_closeup | camera" in table and "pool_floor_closeup | scene" in table
    assert (tmp_path / "wavy_closeup_photon_map_camera.png").exists()


def test_turned_windows_keep_the_energy(device, monkeypatch):
    """Windows turned about the light's axis (forced to 0.6 rad here) sample the same power and store the
    same caustic as the whole view: the outside booking's 4×4 texel measure and the turned cascade agree."""
    import cisp_warp.photons.fit as fit

    monkeypatch.setattr(fit, "FIT_ON_DEVICE", False)  # the numpy fit, whose turn can be forced
    monkeypatch.setattr(fit, "fit_angle", lambda depth, aspect=1.0: 0.6)
    res = fitted_pair(device, "sspm", lambda: analytic.wavy_water(width=32, height=32, grid=64), 400_000)
    (_, whole, lw), (rf, fitted, lf) = res["scene"], res["camera"]
    np.testing.assert_allclose(rf.lights[0].outside_angles, [0.6], rtol=1e-6)  # kept as float32 on the device
    assert lf.closure() < 1e-5
    np.testing.assert_allclose(lf["sampled"], lw["sampled"], rtol=2e-3)
    np.testing.assert_allclose(lf["stored"], lw["stored"], rtol=0.02)
    np.testing.assert_allclose(fitted.mean(), whole.mean(), rtol=0.02)


def test_cascade_solid_angles_of_a_light_in_one_launch_are_the_per_view_ones(device):
    """``cascade_solid_angles_all`` (every view of a light in one launch, into one array, a few threads a view each
    striding over its texels) writes each view's slice as ``cascade_solid_angles`` writes that view's array, bit for
    bit: a moved view, one that stood still, an inactive one; a texel count not a multiple of the threads."""
    import warp as wp

    from cisp_warp.raster.light_maps import (CASCADE_TEXELS_PER_THREAD, CascadeState, cascade_solid_angles,
                                             cascade_solid_angles_all)
    from cisp_warp.raster.views import View, ViewParams, window_view

    whole = View(np.eye(4), 128, 128, 0.01, 10.0, 64.0, 64.0, False, "w")
    n = 37 * 37
    params = [window_view(whole, w, 37, "c").params() for w in ((90.0, 20.0, 97.0, 25.0), (10.0, 12.0, 70.0, 60.0),
                                                                 (0.0, 0.0, 128.0, 128.0), (30.0, 30.0, 40.0, 44.0))]
    params[2].far = 0.0  # inactive
    views = wp.array(params, dtype=ViewParams, device=device)
    states = []
    for changed in (1, 0, 1, 1):
        st = CascadeState()
        st.active, st.active_views, st.texel_scale, st.changed = 1, 3, 1.0, changed
        states.append(st)
    states = wp.array(states, dtype=CascadeState, device=device)
    threads = (n + CASCADE_TEXELS_PER_THREAD - 1) // CASCADE_TEXELS_PER_THREAD
    fused = wp.full(4 * n, -1.0, dtype=wp.float32, device=device)
    wp.launch(cascade_solid_angles_all, dim=(4, 100), inputs=[views, states, n, 100, fused], device=device)  # 13.69 a thread
    for k in range(4):
        out = wp.full(n, -1.0, dtype=wp.float32, device=device)
        wp.launch(cascade_solid_angles, dim=threads, inputs=[views, states, k, n, out], device=device)
        assert fused.numpy()[k * n : (k + 1) * n].tobytes() == out.numpy().tobytes(), k
    written = fused.numpy().reshape(4, n) != -1.0
    assert written[0].all() and written[3].all() and not written[1].any() and not written[2].any()
