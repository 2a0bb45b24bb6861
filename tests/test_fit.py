"""The light views fitted on the device (``photons.fit``: Warp tile reductions and a solve kernel) against their
naive twin, the numpy fit (``views.fit_angle`` / ``fit_windows`` / ``LightMaps.set_windows``)."""

import math

import numpy as np
import pytest
import warp as wp

from cisp_warp import analytic
from cisp_warp.raster import LightViewSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.usd import load_usd


def _fitted(r):
    """Per fitted light: (views, states, outside windows, outside angles) as host records."""
    return [(lm.views.numpy(), lm.states.numpy(), lm.outside.numpy(), lm.outside_angle.numpy()) for lm in r.fitter.lights]


def _assert_same_fit(dev, host, what):
    for li, ((v0, s0, o0, a0), (v1, s1, o1, a1)) in enumerate(zip(dev, host)):
        tag = f"{what}, light {li}"
        np.testing.assert_array_equal(s0["active"], s1["active"], err_msg=tag)
        np.testing.assert_array_equal(s0["active_views"], s1["active_views"], err_msg=tag)
        np.testing.assert_allclose(a0, a1, atol=1e-6, err_msg=tag)
        np.testing.assert_allclose(o0, o1, rtol=1e-5, atol=1e-4, err_msg=tag)  # pilot pixels
        np.testing.assert_allclose(s0["skip_window"], s1["skip_window"], rtol=1e-5, atol=2e-3, err_msg=tag)  # texels
        np.testing.assert_allclose(s0["texel_scale"], s1["texel_scale"], rtol=1e-5, err_msg=tag)
        for f in ("fx", "fy", "cx", "cy"):
            np.testing.assert_allclose(v0[f], v1[f], rtol=1e-5, atol=2e-3, err_msg=f"{tag}: {f}")
        for f in ("near", "far", "width", "height", "orthographic"):
            np.testing.assert_array_equal(v0[f], v1[f], err_msg=f"{tag}: {f}")
        for f in ("world_to_view", "view_to_world"):
            np.testing.assert_allclose(v0[f], v1[f], rtol=1e-5, atol=1e-5, err_msg=f"{tag}: {f}")


def _closeup():
    return analytic.wavy_water(width=32, height=32, grid=64)


def _spot_closeup():
    from cisp_warp.scene import Camera, Light, LightKind
    from cisp_warp.scene.model import look_at_matrix

    water = (analytic.quad(0, 0, 0, (0.5, 0, 0), (0, 0, -0.5)), 1)
    floor = (analytic.quad(0, -0.5, 0, (2, 0, 0), (0, 0, -2)), 0)
    cam = Camera(look_at_matrix((0.3, 0.4, 0.1), (0.2, -0.5, 0)), fov_y=math.radians(45), width=32, height=32,
                 near=0.05, far=10)
    light = Light(LightKind.POINT, "lamp", intensity=100.0, position=(0.1, 0.8, 0.05), direction=(0, -1, 0))
    return analytic.build([water, floor], cam, [light])


SCENES = {
    "cornell": lambda device: load_usd("scenes_usd/cornell_flooded.usda", width=48, height=36, device=device),
    "pool": lambda device: load_usd("scenes_usd/pool.usda", width=48, height=36, device=device),
    "closeup": lambda device: _closeup(),
    "point_closeup": lambda device: _spot_closeup(),
}


@pytest.mark.parametrize("scene", sorted(SCENES))
@pytest.mark.parametrize("cascades", [1, 2])
def test_device_fit_matches_numpy_fit(device, scene, cascades):
    """Same receiver depths, two fits: the device's tile reductions and solve give the numpy fit's turn,
    windows, views, states and outside windows to float tolerance, on the shipped scenes' cameras and close-ups."""
    r = Renderer(SCENES[scene](device), RenderSettings(rsm_size=128, method="cisp", denoiser="none", photons=20_000,
                                                       light_views=LightViewSettings(cascades=cascades)), device=device)
    assert r.fitter.on_device
    r.render_frame()
    dev = _fitted(r)
    assert any(s["active"].any() for _, s, _, _ in dev) or scene == "none"
    r.fitter.fit_host()  # the same pilots' depths, fitted in numpy
    _assert_same_fit(dev, _fitted(r), f"{scene}, {cascades} cascade(s)")


@pytest.mark.parametrize("scene", ["pool", "point_closeup", "cornell"])
def test_pilot_branches_equal_one_thread_per_texel(device, scene):
    """The pilot traced one thread per texel and branch (pilot_branches + pilot_nearest) gives the one-thread-per-
    texel kernel's receiver depths bit for bit on the CPU, to an ulp on CUDA (the twin, pilot_receivers), with some
    texels seen by both branches."""
    r = Renderer(SCENES[scene](device), RenderSettings(rsm_size=64, method="cisp", denoiser="none", photons=2_000),
                 device=device)
    r.render_frame()
    f = r.fitter
    split = [d.numpy().copy() for d in f.receiver_depth_all]
    both = sum(int(((b[:, 0] < np.inf) & (b[:, 1] < np.inf)).sum()) for b in
               (x.numpy().reshape(-1, 2, f.lights[0].pilot[0].width ** 2) for x in f.branch_depth_all))
    for d in f.receiver_depth_all:
        d.fill_(-1.0)
    f.one_thread_per_texel = True
    f.trace_pilots(r.raster, r.view_params, 0)
    assert any((d > 0).any() for d in split)
    for a, b in zip(split, f.receiver_depth_all):
        if wp.get_device(device).is_cuda:  # CUDA's FMA contraction differs between the kernels: an ulp here and there
            np.testing.assert_allclose(a, b.numpy(), rtol=1e-6, atol=0)
        else:
            np.testing.assert_array_equal(a, b.numpy())
    if scene == "pool":
        assert both > 0  # the refracted branch competes with a reflected one somewhere


@pytest.mark.parametrize("scene", ["pool", "sinusoid"])
def test_pilot_trace_compiled_per_projection_equals_the_run_time_one(device, scene):
    """The pilot trace compiled for its pilot view's and the camera's projections (``LightViewFitter.pilot_kernel``,
    ``fit.projected_pilot_branches``) writes the run-time kernel's (``fit.pilot_branches``, the twin) branch depths bit
    for bit on the CPU (to an ulp on CUDA): the pool (an orthographic sun's and a perspective spot's pilots, a
    perspective camera) and the sinusoidal water (an orthographic sun and camera). The kernels compiled for the other
    projection of the pilot, or of the camera, write other depths: a wrong pick would fail here."""
    from cisp_warp.photons import fit as F

    make = SCENES[scene] if scene in SCENES else (lambda d: analytic.sinusoidal_water(48, 36))
    r = Renderer(make(device), RenderSettings(rsm_size=64, method="cisp", denoiser="none", photons=2_000),
                 device=device)
    f = r.fitter
    assert f.PROJECTED
    r.render_frame()
    projected = [b.numpy().copy() for b in f.branch_depth_all]
    cam_ortho = int(r.view.orthographic)
    seen = set()
    for i, lm in enumerate(f.lights):
        for r_pilot in lm.pilot:
            light_ortho = int(r_pilot.view.orthographic)
            seen.add((light_ortho, cam_ortho))
            assert f.pilot_kernel(r_pilot.view.orthographic) is F.projected_pilot_branches(light_ortho, cam_ortho)
    assert seen == ({(1, 0), (0, 0)} if scene == "pool" else {(1, 1)})
    f.PROJECTED = False  # the twin, on the same pilots, camera and streams
    f.trace_pilots(r.raster, r.view_params, 0)
    assert f.pilot_kernel(True) is F.pilot_branches
    for a, b in zip(projected, f.branch_depth_all):
        assert (a < np.inf).sum() > 50  # branches landing where the camera sees them
        if wp.get_device(device).is_cuda:  # FMA contraction may differ between the kernels: an ulp here and there
            np.testing.assert_allclose(a, b.numpy(), rtol=1e-6, atol=0)
        else:
            np.testing.assert_array_equal(a, b.numpy())
    for i, lm in enumerate(f.lights):  # the other projection compiled: other depths
        for vi, r_pilot in enumerate(lm.pilot):
            light_ortho = int(r_pilot.view.orthographic)
            run_time = f.branch_depth[i][vi].numpy()
            for wrong in ((1 - light_ortho, cam_ortho), (light_ortho, 1 - cam_ortho)):
                out = wp.zeros_like(f.branch_depth[i][vi])
                wp.launch(F.projected_pilot_branches(*wrong), dim=out.shape[0], device=device,
                          inputs=f.pilot_inputs(i, vi) + [out])
                assert not np.array_equal(out.numpy(), run_time), f"light {i} view {vi} compiled as {wrong}"


def test_device_fit_forced_cascades_and_empty_pilot(device):
    """Hand-made receiver depths (a near patch inside a far band, then nothing): the device fit nests two
    cascades as the numpy fit does, and leaves every cascade inactive (far = 0, no photons) when nothing is seen."""
    r = Renderer(_closeup(), RenderSettings(rsm_size=64, method="cisp", denoiser="none", photons=10_000,
                                            light_views=LightViewSettings(cascades=3)), device=device)
    r.render_frame()
    f = r.fitter
    p = r.lights[0].pilot[0]
    depth = np.zeros((p.height, p.width), np.float32)
    depth[30:60, 10:110] = 9.0
    depth[40:44, 50:54] = 1.0
    depth[100:102, 5:7] = 3.0
    for case in (depth, np.zeros_like(depth)):
        f.receiver_depth_all[0].assign(case.reshape(-1))
        f.fit_device()
        dev = _fitted(r)
        f.fit_host()
        _assert_same_fit(dev, _fitted(r), "hand-made depths")
    assert not any(r.lights[0].active)
    assert (r.lights[0].views.numpy()["far"] == 0.0).all()


@pytest.mark.parametrize("method,sort", [("cisp", False), ("sspm", False), ("cisp", True)])
def test_fixed_launch_dims_change_nothing(device, method, sort, monkeypatch):
    """The CUDA path, where the host does not know which cascades are active: every cascade is drawn (an inactive
    one, far = 0, draws nothing) and traced with the light's photons in whole blocks of slots, the kernels emitting
    ``cascade_photons`` of them (sorted: the surplus slots' keys sort last). On the CPU it gives the exact-count
    path's photon map and ledger bit for bit."""
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.raster.light_maps import LightMaps

    def frame():
        r = Renderer(SCENES["pool"](device), RenderSettings(rsm_size=64, method=method, denoiser="none",
                                                            photons=PhotonSettings(photons=3_000, sort_photons=sort)),
                     device=device)
        r.render_frame()
        return r.photons.photon_map.numpy(), r.photons.ledger.numpy(), r
    exact_map, exact_ledger, r = frame()
    assert not all(all(lm.active) for lm in r.lights)  # an inactive cascade is part of the case
    monkeypatch.setattr(LightMaps, "host_active", lambda self: None)
    fixed_map, fixed_ledger, r = frame()
    if wp_device_is_cpu(device):
        np.testing.assert_array_equal(fixed_map, exact_map)
        np.testing.assert_array_equal(fixed_ledger, exact_ledger)
    else:  # float atomics add in another order
        np.testing.assert_allclose(fixed_map, exact_map, rtol=1e-4, atol=1e-6 * exact_map.max())
        np.testing.assert_allclose(fixed_ledger, exact_ledger, rtol=1e-9, atol=1e-12 * np.abs(exact_ledger).max())
    assert r.photons.read_ledger().closure() < 1e-6


def wp_device_is_cpu(device) -> bool:
    import warp as wp

    return wp.get_device(device).is_cpu


@pytest.mark.parametrize("block", [1, 32, 128, 160])
def test_fit_reductions_by_columns_equal_the_naive_ones(device, monkeypatch, block):
    """fit_reduce_angles / fit_reduce_cascades (a column's first and last useful texels turned) write the naive
    kernels' boxes, counts and angles bit for bit: random sparse depths with gaps in columns, a full view, a diagonal
    band, on 40² pilots (blocks narrower and wider than a row, lanes left idle; 160: four rows at a time, as FIT_BLOCK
    = 512 takes a 128² pilot's)."""
    import warp as wp

    from cisp_warp.photons import fit as F

    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    rng = np.random.default_rng(5)
    p, cascades = 40, 3
    depth = np.zeros((4, p, p), np.float32)
    depth[0] = np.where(rng.random((p, p)) < 0.05, rng.uniform(0.5, 9.0, (p, p)), 0.0)
    depth[1, 5:30, 3:17] = rng.uniform(1.0, 2.0, (25, 14))
    depth[1, 31:33, 20:39] = 7.0  # a far band: a cascade of its own
    depth[2] = rng.uniform(0.1, 3.0, (p, p))
    jj, ii = np.mgrid[0:p, 0:p]
    depth[3] = np.where(np.abs(ii - jj) < 3, rng.uniform(1.0, 4.0, (p, p)), 0.0)  # a diagonal band: fitted turned
    nv = depth.shape[0]
    d = wp.array(depth.reshape(-1), dtype=wp.float32, device=device)
    aspects = wp.array([1.0, 0.7, 1.3, 1.0], dtype=wp.float64, device=device)
    out = []
    unused = wp.zeros(1, dtype=wp.float32, device=device)
    for angles_kernel, cascades_kernel in ((F.fit_reduce_angles_naive, F.fit_reduce_cascades_naive),
                                           (F.fit_reduce_angles, F.fit_reduce_cascades)):
        boxes = wp.zeros(nv * (F.FIT_STEPS + 1), dtype=wp.vec4d, device=device)
        cboxes = wp.zeros(nv * cascades, dtype=wp.vec4d, device=device)
        counts = wp.zeros(nv * cascades, dtype=wp.float64, device=device)
        angles = wp.zeros(nv, dtype=wp.float64, device=device)
        head = [] if angles_kernel is F.fit_reduce_angles_naive else [unused, 0]  # from the receiver depths
        wp.launch_tiled(angles_kernel, dim=(nv, F.FIT_STEPS + 1), block_dim=block, device=device,
                        inputs=head + [d, p, p, aspects, boxes])
        wp.launch_tiled(cascades_kernel, dim=(nv, cascades), block_dim=block, device=device,
                        inputs=[d, p, p, aspects, cascades, boxes, cboxes, counts, angles])
        out.append([a.numpy() for a in (boxes, cboxes, counts, angles)])
    for naive, fast in zip(*out):
        np.testing.assert_array_equal(fast, naive)
    assert out[0][3][3] != 0.0  # the band's view turned
    assert (out[0][2].reshape(nv, cascades)[:2] > 0).all()


def test_fit_reductions_do_not_depend_on_the_block_size(device, monkeypatch):
    """The fit's tile reductions over blocks of 32 threads (CPU blocks enabled) give the one-thread blocks' fit."""
    import warp as wp

    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    r = Renderer(SCENES["pool"](device), RenderSettings(rsm_size=64, method="cisp", denoiser="none", photons=2_000),
                 device=device)
    r.render_frame()
    fits = []
    for block in (1, 32):
        r.fitter.fit_block = block
        r.fitter.fit_device()
        fits.append(_fitted(r))
    for (v0, s0, o0, a0), (v1, s1, o1, a1) in zip(*fits):
        np.testing.assert_array_equal(s0, s1)
        np.testing.assert_array_equal(o0, o1)
        np.testing.assert_array_equal(a0, a1)
        np.testing.assert_array_equal(v0, v1)


@pytest.mark.parametrize("block", [1, 32, 128])
def test_fit_reduce_angles_from_branches_equals_pilot_nearest_first(device, monkeypatch, block):
    """fit_reduce_angles reading pilot_branches' scratch (each texel's nearer branch taken in every block, written by
    the depth-range block) gives pilot_nearest's receiver depths and the boxes fit_reduce_angles finds in them, bit for
    bit: two 40² views (rows not a multiple of the four a round), branches landing alone, both, or neither."""
    from cisp_warp.photons import fit as F

    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    rng = np.random.default_rng(11)
    p, nv = 40, 2
    inf = np.float32(np.inf)
    branches = np.where(rng.random((nv, 2, p, p)) < 0.3, rng.uniform(0.5, 9.0, (nv, 2, p, p)), inf).astype(np.float32)
    branches[0, :, :10] = inf  # rows seen by neither branch
    branches[1, 0, 5:20, 5:20] = 2.0  # a patch both branches reach, the refracted one nearer
    branches[1, 1, 5:20, 5:20] = 1.5
    b = wp.array(branches.reshape(-1), dtype=wp.float32, device=device)
    aspects = wp.array([1.0, 0.8], dtype=wp.float64, device=device)
    depth = wp.zeros(nv * p * p, dtype=wp.float32, device=device)
    wp.launch(F.pilot_nearest, dim=nv * p * p, device=device, inputs=[b, p * p, depth])
    boxes = wp.zeros(nv * (F.FIT_STEPS + 1), dtype=wp.vec4d, device=device)
    wp.launch_tiled(F.fit_reduce_angles, dim=(nv, F.FIT_STEPS + 1), block_dim=block, device=device,
                    inputs=[b, 0, depth, p, p, aspects, boxes])
    folded = wp.full(nv * p * p, -1.0, dtype=wp.float32, device=device)
    folded_boxes = wp.zeros_like(boxes)
    wp.launch_tiled(F.fit_reduce_angles, dim=(nv, F.FIT_STEPS + 1), block_dim=block, device=device,
                    inputs=[b, 1, folded, p, p, aspects, folded_boxes])
    np.testing.assert_array_equal(folded.numpy(), depth.numpy())
    np.testing.assert_array_equal(folded_boxes.numpy(), boxes.numpy())
    assert (depth.numpy() > 0).sum() > 100 and (depth.numpy() == 1.5).sum() == 225


def test_fit_solve_per_cascade_is_the_one_thread_solve(device):
    """``fit_solve_cascades`` (a thread a cascade) writes ``fit_solve``'s views, states, outside windows and turns,
    and through them the cascades' solid angles, bit for bit: a point light's six pilot views with three cascades
    each, on the frame's own depths, on hand-made ones (nested windows, a merge, cascades left inactive) and on none
    (every cascade inactive), each twice (the second time nothing moved: ``changed`` 0)."""
    r = Renderer(_spot_closeup(), RenderSettings(rsm_size=32, method="cisp", denoiser="none", photons=5_000,
                                                 light_views=LightViewSettings(cascades=3, pilot_size=64)),
                 device=device)
    r.render_frame()
    f, lm = r.fitter, r.lights[0]
    assert len(lm.pilot) == 6
    outputs = (lm.views, lm.states, lm.outside, lm.outside_angle, lm.cascade_solid_angle)
    p = lm.pilot[0]
    frame = f.receiver_depth_all[0].numpy().copy()
    made = np.zeros((len(lm.pilot), p.height, p.width), np.float32)
    made[0, 10:30, 5:60] = 9.0
    made[0, 15:18, 20:23] = 1.0
    made[2, 40:42, 3:5] = 3.0
    made[3, 5:60, 5:60] = 2.0  # one depth: the cascades merge
    start = [a.numpy().copy() for a in outputs]
    for depths in (frame, made.reshape(-1), np.zeros_like(frame)):
        got = {}
        for per_cascade in (False, True):
            for a, v in zip(outputs, start):
                a.assign(v)
            f.solve_per_cascade = per_cascade
            got[per_cascade] = []
            for _ in range(2):
                f.receiver_depth_all[0].assign(depths)
                f.fit_device()
                got[per_cascade].append([a.numpy().tobytes() for a in outputs])
        assert got[True] == got[False]
        start = [a.numpy().copy() for a in outputs]
    assert not any(lm.active)  # the last depths: nothing seen
