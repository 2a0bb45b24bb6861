"""Tests of the denoise pass: the caustics denoiser (constant, convergence to the long-run mean, step change,
disocclusion, energy, naive twin), SVGF (constant, energy, disocclusion, motion, naive twin) and the Gaussian
gather.

G-buffers are built by hand in numpy: a tilted plane (depth linear in x, one normal), optionally a
box in front of it and a corner with no surface. Sizes are tiny; generators are seeded.
"""

from dataclasses import fields, replace

import numpy as np
import pytest
import warp as wp

from cisp_warp.denoise import (SVGF, CausticDenoiser, CausticSettings, GaussianGather, SVGFSettings,
                               launch_atrous_level)
from cisp_warp.denoise.kernels_atrous import launch_atrous
from cisp_warp.denoise import kernels_caustic as K
from cisp_warp.denoise.naive import (atrous_level_naive, blur_variance_naive, caustic_frame_naive, caustic_motion_naive,
                                   depth_slope_naive)

W, H = 32, 24
PLANE_NORMAL = np.array([0.3, 0.0, 1.0]) / np.hypot(0.3, 1.0)


def plane(w=W, h=H, hole=True):
    """Tilted plane G-buffer as numpy arrays (H, W[, C]); a 3x3 top-left corner without surface if ``hole``."""
    x = np.arange(w)[None, :].repeat(h, 0)
    depth = (2.0 + 0.02 * x).astype(np.float32)
    normal = np.broadcast_to(PLANE_NORMAL, (h, w, 3)).astype(np.float32).copy()
    tri = np.where(np.arange(h)[:, None] + x * h / w < h, 0, 1).astype(np.int32)  # two triangles
    motion = np.zeros((h, w, 2), np.float32)
    if hole:
        depth[:3, :3] = 0.0
        tri[:3, :3] = -1
    return dict(depth=depth, normal=normal, tri_id=tri, motion=motion)


def upload(g, device):
    types = dict(depth=wp.float32, normal=wp.vec3, tri_id=wp.int32, motion=wp.vec2, irradiance=wp.vec3)
    return {k: wp.array(np.ascontiguousarray(v).reshape((-1,) + v.shape[2:]), dtype=types[k], device=device)
            for k, v in g.items()}


def run_frame(svgf, g_np, irradiance, out, photon_m2=None, flow=None):
    g = upload(dict(g_np, irradiance=irradiance.astype(np.float32)), svgf.device)
    if flow is not None:  # the caustic flow (H, W, 4): only the caustics denoiser takes it
        f = wp.array(np.ascontiguousarray(flow, np.float32).reshape(-1, 4), dtype=wp.vec4, device=svgf.device)
        m2 = None if photon_m2 is None else wp.array(np.ascontiguousarray(photon_m2, np.float32).reshape(-1),
                                                     dtype=wp.float32, device=svgf.device)
        svgf.denoise(g["irradiance"], g["depth"], g["normal"], g["motion"], g["tri_id"], out, m2, f)
    elif photon_m2 is None:
        svgf.denoise(g["irradiance"], g["depth"], g["normal"], g["motion"], g["tri_id"], out)
    else:
        m2 = wp.array(np.ascontiguousarray(photon_m2, np.float32).reshape(-1), dtype=wp.float32, device=svgf.device)
        svgf.denoise(g["irradiance"], g["depth"], g["normal"], g["motion"], g["tri_id"], out, m2)
    return out.numpy().reshape(svgf.height, svgf.width, 3)


def uniform_flow(shift, h=H, w=W, count=6.0, s2=0.02):
    """A caustic flow (H, W, 4) as the photon pass splats it (Σ D, Σ s_D², count) for a caustic displaced by
    ``shift`` (x, y) [pixels] since the last frame: each pixel's ``count`` photons all saying D = −shift (previous
    position minus current), with variance ``s2`` [pixels²] each."""
    f = np.zeros((h, w, 4), np.float32)
    f[..., 0], f[..., 1] = -shift[0] * count, -shift[1] * count
    f[..., 2], f[..., 3] = s2 * count, count
    return f


def history(svgf):
    return svgf.history_length.numpy().reshape(svgf.height, svgf.width)


def poisson_map(rng, truth, photon):
    """A photon map whose pixels hold Poisson counts of photons of irradiance ``photon`` [W/m²] with mean
    ``truth`` (H, W) [W/m²]: the sparse, integer-valued noise of a real photon map (grey)."""
    return (rng.poisson(truth / photon) * photon)[..., None] * np.ones(3, np.float32)


def poisson_m2(e, photon):
    """The ``photon_m2`` of :func:`poisson_map`'s map ``e``: k photons of luminance ``photon`` hold k photon²."""
    return e[..., 1] * photon


def caustic_pattern(w=W, h=H, shift=0.0):
    """A smooth caustic-like irradiance [W/m²]: bright bands 3-4 pixels wide over a dim floor."""
    x = np.arange(w)[None, :] - shift
    y = np.arange(h)[:, None]
    return 2.0 + 30.0 * np.exp(-np.sin(0.25 * x + 0.5 * np.sin(0.3 * y)) ** 2 / 0.1)


def photon_map(rng, h, w, density, value):
    """Sparse photon map: each pixel holds one photon of irradiance ``value`` with probability ``density``."""
    return (rng.random((h, w)) < density)[..., None] * np.asarray(value, np.float32)


def test_constant_input_unchanged(device):
    g = plane()
    surf = g["depth"] > 0
    e = np.array([1.5, 0.7, 0.2], np.float32)
    svgf = SVGF(W, H, device, SVGFSettings())
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    for frame in range(10):
        res = run_frame(svgf, g, np.broadcast_to(e, (H, W, 3)), out)
        if frame in (0, 9):
            np.testing.assert_allclose(res[surf], np.broadcast_to(e, res[surf].shape), rtol=1e-5)
            assert np.all(res[~surf] == 0.0)
    assert np.all(history(svgf)[surf] == 10) and np.all(history(svgf)[~surf] == 0)


def test_energy_and_variance_reduction(device):
    """Sparse photon maps on a static scene: the output mean follows the temporal average of the input
    means (each stage preserves the mean) within 1 %, and the pixel variance falls by a large factor."""
    rng = np.random.default_rng(7)
    g = plane(hole=False)
    s = SVGFSettings()
    svgf = SVGF(W, H, device, s)
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    value = np.array([40.0, 25.0, 10.0], np.float32)  # W/m² of one photon's pixel
    density = 0.2
    ema = np.zeros(3)
    frames = 16
    for k in range(1, frames + 1):
        e = photon_map(rng, H, W, density, value)
        res = run_frame(svgf, g, e, out)
        a = max(1.0 / min(k, s.max_history), s.alpha_color)
        ema = (1 - a) * ema + a * e.reshape(-1, 3).mean(0)
    ratio = res.reshape(-1, 3).mean(0) / ema
    var_in = (value ** 2) * density * (1 - density)  # per-pixel variance of one photon map
    var_out = res.reshape(-1, 3).var(0)
    print(f"energy ratio out/in {ratio}, variance in {var_in}, out {var_out}, reduction {var_in / var_out}")
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)
    # the frame mean itself lies within 5 % of the photon map's expected irradiance (statistics of 768 pixels)
    np.testing.assert_allclose(res.reshape(-1, 3).mean(0), density * value, rtol=0.05)
    assert np.all(var_in / var_out > 50.0)


def test_disocclusion_resets_history(device):
    rng = np.random.default_rng(3)
    g = plane()
    svgf = SVGF(W, H, device, SVGFSettings())
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    for _ in range(6):
        run_frame(svgf, g, photon_map(rng, H, W, 0.3, [5.0, 5.0, 5.0]), out)
    surf = g["depth"] > 0
    assert np.all(history(svgf)[surf] == 6)
    moved = dict(g, depth=g["depth"].copy(), tri_id=g["tri_id"].copy())
    region = np.zeros((H, W), bool)
    region[8:16, 10:20] = True
    moved["depth"][region] *= 0.7  # a box appears in front of the plane
    gone = np.zeros((H, W), bool)
    gone[20:, 25:] = True
    moved["depth"][gone] = 0.0
    moved["tri_id"][gone] = -1  # and a patch of sky
    res = run_frame(svgf, moved, photon_map(rng, H, W, 0.3, [5.0, 5.0, 5.0]), out)
    h = history(svgf)
    assert np.all(h[region] == 1)
    assert np.all(h[gone] == 0) and np.all(res[gone] == 0.0)
    assert np.all(h[surf & ~region & ~gone] == 7)
    run_frame(svgf, moved, photon_map(rng, H, W, 0.3, [5.0, 5.0, 5.0]), out)
    assert np.all(history(svgf)[region] == 2) and np.all(history(svgf)[surf & ~region & ~gone] == 8)


def moving_scene(t, w=W, h=H):
    """Scene translating by +1 pixel per frame: a smooth irradiance pattern and a box 0.5 m in front."""
    g = plane(w, h, hole=False)
    x = np.arange(w)[None, :] - t  # content coordinate of each pixel
    y = np.arange(h)[:, None]
    box = (x % 16 >= 4) & (x % 16 < 10) & (y >= 6) & (y < 18)
    g["depth"] = np.where(box, 1.5, 2.0 + 0.02 * x).astype(np.float32)
    e = (1.0 + 0.5 * np.sin(0.4 * x) + 0.25 * np.cos(0.3 * y))[..., None] * np.array([3.0, 2.0, 1.0])
    return g, e.astype(np.float32), box


def test_motion_vectors_reproject_history(device):
    svgf = SVGF(W, H, device, SVGFSettings(feedback_level=-1))  # history = unfiltered accumulation
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    frames = 8
    for t in range(frames):
        g, e, _ = moving_scene(t)
        g["motion"][..., 0] = -1.0  # each point was one pixel to the left in the previous frame
        run_frame(svgf, g, e, out)
    xs = np.arange(W)[None, :].repeat(H, 0)
    np.testing.assert_array_equal(history(svgf), np.minimum(xs + 1, frames))
    # the history followed the content: accumulating the moving pattern gives the pattern itself
    integrated = svgf.integrated.numpy().reshape(H, W, 3)
    np.testing.assert_allclose(integrated[:, 1:], e[:, 1:], rtol=1e-5)

    # control: without motion vectors the box edges, which moved, are disoccluded every frame
    svgf.reset()
    for t in range(frames):
        g, e, box = moving_scene(t)
        run_frame(svgf, g, e, out)
    _, _, prev_box = moving_scene(frames - 2)
    h = history(svgf)
    assert np.all(h[box != prev_box] == 1)
    assert np.all(h[(box == prev_box) & ~box & (xs > 0)] > 1)  # the plane is static in depth where both agree


def test_fractional_motion_keeps_constant(device):
    g = plane(hole=False)
    g["depth"][:] = 2.0
    g["motion"][:] = (0.3, -0.6)
    e = np.broadcast_to(np.array([2.0, 1.0, 0.5], np.float32), (H, W, 3))
    svgf = SVGF(W, H, device, SVGFSettings())
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    for _ in range(5):
        res = run_frame(svgf, g, e, out)
    np.testing.assert_allclose(res, np.broadcast_to(e, res.shape), rtol=1e-5)
    # interior: all four bilinear taps on screen, history grows every frame
    assert np.all(history(svgf)[1:-1, 1:-1] == 5)


@pytest.mark.parametrize("step,conserve,gate", [(1, True, None), (2, True, None), (4, True, None), (1, False, None),
                                                (2, False, None), (1, True, 0.2), (2, True, 0.1)])
def test_atrous_level_matches_naive_twin(device, step, conserve, gate):
    """One à-trous level against the per-pixel float64 twin; ``gate``: the caustics denoiser's gated level
    (noise target chosen so that the footprint radii straddle the step: some pixels filtered, some kept)."""
    rng = np.random.default_rng(11 + step)
    w, h = 16, 12
    g = plane(w, h)
    g["depth"][4:9, 6:11] = 1.2  # a depth edge
    n = g["normal"] + 0.15 * rng.standard_normal((h, w, 3)).astype(np.float32)
    g["normal"] = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
    color = rng.exponential(2.0, (h, w, 3)).astype(np.float32)
    color[g["depth"] <= 0] = 0.0
    variance = rng.exponential(1.0, (h, w)).astype(np.float32)
    s = SVGFSettings(sigma_luminance=2.0, sigma_normal=32.0, conserve_energy=conserve)
    dev = upload(dict(depth=g["depth"], normal=g["normal"], irradiance=color), device)
    slope = wp.array(depth_slope_naive(g["depth"]).astype(np.float32).reshape(-1), dtype=wp.float32, device=device)
    var_in = wp.array(variance.reshape(-1), dtype=wp.float32, device=device)
    guide_a = wp.zeros(w * h, dtype=wp.vec4, device=device)
    guide_b = wp.zeros(w * h, dtype=wp.vec4, device=device)
    color_variance = wp.zeros(w * h, dtype=wp.vec4, device=device)
    weight_sum = wp.zeros(w * h, dtype=wp.float32, device=device)
    c_out = wp.zeros(w * h, dtype=wp.vec3, device=device)
    v_out = wp.zeros(w * h, dtype=wp.float32, device=device)
    launch_atrous_level(dev["irradiance"], var_in, dev["depth"], dev["normal"], slope, w, h, step, s.sigma_depth,
                        s.sigma_normal, s.sigma_luminance, conserve, guide_a, guide_b, color_variance, weight_sum, c_out, v_out,
                        noise_target=gate)
    c_ref, v_ref = atrous_level_naive(color, variance, g["depth"], g["normal"], step,
                                      s.sigma_depth, s.sigma_normal, s.sigma_luminance, conserve, noise_target=gate)
    if gate is not None:  # the gate really splits the image: some pixels kept, some filtered
        radius = blur_variance_naive(color, variance, g["depth"], gate)[1][g["depth"] > 0]
        assert np.any(2 * radius <= step) and np.any(radius >= step)
    c_warp = c_out.numpy().reshape(h, w, 3)
    np.testing.assert_allclose(c_warp, c_ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(v_out.numpy().reshape(h, w), v_ref, rtol=1e-5, atol=1e-7)
    if conserve:  # exchange form: the image sum is kept exactly (edges, borders and holes included)
        np.testing.assert_allclose(c_warp.reshape(-1, 3).sum(0), color.reshape(-1, 3).sum(0), rtol=1e-5)


def test_depth_slope_matches_naive_twin(device):
    g = plane(16, 12)
    g["depth"][4:9, 6:11] = 1.2
    svgf = SVGF(16, 12, device, SVGFSettings())
    run_frame(svgf, g, np.ones((12, 16, 3), np.float32), wp.zeros(16 * 12, dtype=wp.vec3, device=device))
    np.testing.assert_allclose(svgf.depth_slope.numpy().reshape(12, 16), depth_slope_naive(g["depth"]),
                               rtol=1e-4, atol=1e-6)


def test_every_setting_reaches_a_kernel(device):
    """Changing any one setting changes the output of a short sequence over a scene that exercises it."""
    rng = np.random.default_rng(5)
    frames = []
    for t in range(6):
        g = plane()
        g["depth"][8:16, 10:20] = 1.5  # box: depth edges
        g["depth"] *= 1.0 + 0.05 * (t % 2)  # depth jitter that depth_tolerance decides on
        tilt = 0.1 * (t % 2)  # normal jitter that normal_tolerance decides on
        n = np.stack([PLANE_NORMAL[0] + tilt + 0.05 * np.sin(np.arange(W) * 0.7)[None, :].repeat(H, 0),
                      np.zeros((H, W)), np.ones((H, W))], -1)
        g["normal"] = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
        frames.append((g, photon_map(rng, H, W, 0.3, [4.0, 2.0, 1.0])))
    changed = dict(alpha_color=0.5, alpha_moments=0.6, max_history=2, atrous_levels=3, sigma_depth=0.1,
                   sigma_normal=4.0, sigma_luminance=0.5, depth_tolerance=0.01, normal_tolerance=0.999,
                   feedback_level=2, conserve_energy=False)
    assert set(changed) == {f.name for f in fields(SVGFSettings)}

    def sequence(settings):
        svgf = SVGF(W, H, device, settings)
        out = wp.zeros(W * H, dtype=wp.vec3, device=device)
        return np.stack([run_frame(svgf, g, e, out).copy() for g, e in frames])

    base = sequence(SVGFSettings())
    for name, value in changed.items():
        assert not np.allclose(sequence(replace(SVGFSettings(), **{name: value})), base, rtol=1e-4, atol=0), name


def test_settings_validation():
    with pytest.raises(ValueError):
        SVGFSettings(alpha_color=0.0)
    with pytest.raises(ValueError):
        SVGFSettings(atrous_levels=2, feedback_level=2)
    SVGFSettings(atrous_levels=0, feedback_level=-1)


def test_gaussian_gather_constant_and_impulse(device):
    g = plane()
    g["depth"][14:, 20:] = 1.0  # a second surface in front
    surf = g["depth"] > 0
    gather = GaussianGather(W, H, device, radius=3)
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)

    e = np.broadcast_to(np.array([3.0, 2.0, 1.0], np.float32), (H, W, 3))
    d = upload(dict(g, irradiance=e), device)
    gather.apply(d["irradiance"], d["depth"], d["normal"], d["tri_id"], out)
    res = out.numpy().reshape(H, W, 3)
    np.testing.assert_allclose(res[surf], e[surf], rtol=1e-6)
    assert np.all(res[~surf] == 0.0)

    # an impulse 7 px from every edge of the plane: every pixel it reaches has a full window, so it spreads
    # with total weight 1 (energy preserved), over the 7x7 window only, and nothing lands on the box
    impulse = np.zeros((H, W, 3), np.float32)
    impulse[8, 11] = (49.0, 7.0, 1.0)
    d = upload(dict(g, irradiance=impulse), device)
    gather.apply(d["irradiance"], d["depth"], d["normal"], d["tri_id"], out)
    res = out.numpy().reshape(H, W, 3)
    np.testing.assert_allclose(res.reshape(-1, 3).sum(0), impulse[8, 11], rtol=1e-5)
    assert np.count_nonzero(res[..., 0]) == 49 and np.all(res[14:, 20:] == 0.0)

    # next to the box's edge, nothing crosses onto the other surface
    impulse = np.zeros((H, W, 3), np.float32)
    impulse[12, 22] = 1.0
    d = upload(dict(g, irradiance=impulse), device)
    gather.apply(d["irradiance"], d["depth"], d["normal"], d["tri_id"], out)
    assert np.all(out.numpy().reshape(H, W, 3)[14:, 20:] == 0.0)


# ---- the caustics denoiser ---------------------------------------------------------------------------------


def test_caustic_constant_stays_constant(device):
    g = plane()
    g["depth"][8:16, 10:20] = 1.5  # a box: depth edges
    surf = g["depth"] > 0
    e = np.array([1.5, 0.7, 0.2], np.float32)
    den = CausticDenoiser(W, H, device)
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    for frame in range(8):
        res = run_frame(den, g, np.broadcast_to(e, (H, W, 3)), out)
        np.testing.assert_allclose(res[surf], np.broadcast_to(e, res[surf].shape), rtol=1e-5)
        assert np.all(res[~surf] == 0.0)
    np.testing.assert_allclose(history(den)[surf], 8.0, rtol=1e-5)  # nothing changed: a plain running mean
    assert np.all(history(den)[~surf] == 0)


@pytest.mark.parametrize("with_m2", [False, True])
def test_caustic_static_converges_to_long_run_mean(device, with_m2):
    """A still caustic under fresh photon noise every frame: the accumulated estimate is the running mean of
    the raw photon maps (no change is detected), the error against the true irradiance falls like 1/sqrt(n),
    the spatial filter gives way as the estimate converges, and SVGF, which feeds filtered output back,
    stays far behind. With the photons' Σ e² (``with_m2``; exact here, Poisson counts of equal photons, so it
    caps s² about as often as not) the same holds, with a few more false changes: over seeds 21-26, 0.797 of the
    pixels keep 0.9 of the frames (0.811 without) and the history is 0.0188 from the running mean (0.0176)."""
    rng = np.random.default_rng(21)
    g = plane(hole=False)
    truth = caustic_pattern()
    photon = 1.0  # W/m² per photon: 2 to 32 photons per pixel and frame
    den = CausticDenoiser(W, H, device, CausticSettings(noise_target=0.03, noise_target_m2=0.03))
    svgf = SVGF(W, H, device)
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    out_svgf = wp.zeros(W * H, dtype=wp.vec3, device=device)
    raw_sum = np.zeros((H, W))
    err, err_svgf = [], []
    frames = 48
    for k in range(1, frames + 1):
        e = poisson_map(rng, truth, photon)
        raw_sum += e[..., 1]
        res = run_frame(den, g, e, out, poisson_m2(e, photon) if with_m2 else None)
        res_svgf = run_frame(svgf, g, e, out_svgf)
        err.append(np.sqrt(np.mean((res[..., 1] - truth) ** 2)) / truth.mean())
        err_svgf.append(np.sqrt(np.mean((res_svgf[..., 1] - truth) ** 2)) / truth.mean())
    integrated = den.integrated.numpy().reshape(H, W, 3)[..., 1]
    running_mean = raw_sum / frames
    # few false alarms: the history is close to the plain running mean of the raw maps (0.82 of the pixels here;
    # 0.86 with change_persistence=0: a change found on a short history is kept for some frames; the error
    # against the truth is the same, 0.051)
    print(f"pixels with at least 0.9 x {frames} frames of history: {np.mean(history(den) >= 0.9 * frames):.3f}")
    assert np.mean(history(den) >= 0.9 * frames) > (0.78 if with_m2 else 0.8)
    assert np.sqrt(np.mean((integrated - running_mean) ** 2)) / truth.mean() < (0.025 if with_m2 else 0.02)
    # error falls with the frames, to about the running mean's own (Poisson: sqrt(truth·photon / n))
    floor = np.sqrt(np.mean(truth * photon / frames)) / truth.mean()
    print(f"relative RMSE after 1, 8, 48 frames: {err[0]:.3f} {err[7]:.3f} {err[-1]:.3f}; running mean's "
          f"noise {floor:.3f}; SVGF {err_svgf[-1]:.3f}")
    assert err[-1] < 0.45 * err[7] and err[-1] < 1.3 * floor
    # the filter gives way where the estimate has converged (the bands: 1536 photons per pixel, 2.6% noise,
    # below the 3% target set here): there the output is the accumulated estimate
    bands = truth > 20.0
    kept = np.abs(res[..., 1] - integrated) <= 1e-5 * np.abs(integrated)
    print(f"output = accumulated estimate on {np.mean(kept[bands]):.2f} of the bands, {np.mean(kept):.2f} overall")
    assert np.mean(kept[bands]) > 0.8
    assert err[-1] < 0.5 * err_svgf[-1]


@pytest.mark.parametrize("noisy,with_m2", [(False, False), (True, False), (True, True)])
def test_caustic_follows_a_step_change(device, noisy, with_m2):
    """The caustic doubles after 24 still frames: within 3 frames the estimate is the new level (the history
    is cut back where the new photons disagree with it), where a plain running mean would still be at 1.1x;
    with the photons' Σ e² given too (``with_m2``)."""
    rng = np.random.default_rng(4)
    g = plane(hole=False)
    truth = caustic_pattern()
    den = CausticDenoiser(W, H, device)
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)

    def frame(t):
        tr = truth * (2.0 if t >= 24 else 1.0)
        return poisson_map(rng, tr, 0.25) if noisy else np.repeat(tr[..., None], 3, -1).astype(np.float32)

    for t in range(27):
        e = frame(t)
        res = run_frame(den, g, e, out, poisson_m2(e, 0.25) if with_m2 else None)
    bright = truth > 10.0
    integrated = den.integrated.numpy().reshape(H, W, 3)[..., 1]
    ratio = integrated[bright].mean() / (2.0 * truth[bright].mean())
    print(f"accumulated estimate over the bright bands 3 frames after the step: {ratio:.3f} of the new level; "
          f"output image mean {res[..., 1].mean() / (2.0 * truth.mean()):.3f}")
    assert abs(ratio - 1.0) < (0.03 if noisy else 1e-4)
    assert abs(res[..., 1].mean() / (2.0 * truth.mean()) - 1.0) < (0.03 if noisy else 1e-4)
    assert np.median(history(den)[bright]) <= 4.0
    if not noisy:  # no noise, no spatial filter: the output is the new caustic itself
        np.testing.assert_allclose(res[..., 1], 2.0 * truth, rtol=1e-4)


def test_caustic_disocclusion_resets(device):
    rng = np.random.default_rng(3)
    g = plane()
    den = CausticDenoiser(W, H, device)
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    truth = caustic_pattern()
    for _ in range(6):
        run_frame(den, g, poisson_map(rng, truth, 0.5), out)
    surf = g["depth"] > 0
    assert np.median(history(den)[surf]) == pytest.approx(6.0)
    moved = dict(g, depth=g["depth"].copy(), tri_id=g["tri_id"].copy())
    region = np.zeros((H, W), bool)
    region[8:16, 10:20] = True
    moved["depth"][region] *= 0.7  # a box appears in front of the plane
    gone = np.zeros((H, W), bool)
    gone[20:, 25:] = True
    moved["depth"][gone] = 0.0
    moved["tri_id"][gone] = -1  # and a patch of sky
    res = run_frame(den, moved, poisson_map(rng, truth, 0.5), out)
    h = history(den)
    np.testing.assert_allclose(h[region], 1.0, rtol=1e-6)
    assert np.all(h[gone] == 0) and np.all(res[gone] == 0.0)
    assert np.median(h[surf & ~region & ~gone]) == pytest.approx(7.0)


def test_caustic_conserves_energy(device):
    """Every à-trous level keeps the image's total irradiance: output sum = accumulated sum (sparse maps, a
    box and a hole); and the accumulated mean follows the running mean of the input means."""
    rng = np.random.default_rng(8)
    g = plane()
    g["depth"][8:16, 10:20] = 1.5
    surf = g["depth"] > 0
    den = CausticDenoiser(W, H, device)
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    truth = caustic_pattern()
    in_sum = np.zeros(3)
    for k in range(1, 13):
        e = poisson_map(rng, truth, 8.0)  # sparse: most pixels 0 in a frame
        e[~surf] = 0.0
        in_sum += e.reshape(-1, 3).sum(0)
        res = run_frame(den, g, e, out)
        integrated = den.integrated.numpy().reshape(H, W, 3)
        np.testing.assert_allclose(res.reshape(-1, 3).sum(0), integrated.reshape(-1, 3).sum(0), rtol=1e-5)
    assert np.mean((e[..., 1] == 0)[surf]) > 0.4
    np.testing.assert_allclose(integrated.reshape(-1, 3).sum(0), in_sum / 12, rtol=0.03)


@pytest.mark.parametrize("levels,with_m2,atrous,radius,size", [
    ("tiled", False, 3, 2, (20, 14)), ("tiled", True, 3, 2, (20, 14)), ("pixel", False, 3, 2, (20, 14)),
    ("pixel", True, 3, 2, (20, 14)), ("tiled", True, 4, 2, (20, 14)), ("tiled", True, 3, 3, (35, 21)),
    ("tiled", False, 3, 1, (35, 21))])
def test_caustic_matches_naive_twin(device, levels, with_m2, atrous, radius, size):
    """Three frames (a box with a depth edge, noisy normals, a hole, fractional camera motion, sparse photons;
    with the photons' Σ e² or without) against the float64 twin written from the equations; the gated levels
    tiled (the default) or per pixel; 4 levels: the step-8 level reads its inputs in sub-lattice-major order;
    35 x 21: accumulate's 16 x 16 tiles split the image both ways (windows across tile edges and partial tiles)
    at the largest and the smallest change window."""
    rng = np.random.default_rng(17)
    w, h = size
    s = CausticSettings(atrous_levels=atrous, noise_target=0.1, change_radius=radius)
    den = CausticDenoiser(w, h, device, s, levels=levels)
    out = wp.zeros(w * h, dtype=wp.vec3, device=device)
    hist = None
    truth = caustic_pattern(w, h)
    for t in range(3):
        g = plane(w, h)
        g["depth"][4:9, 6:11] = 1.2 if t < 2 else 1.4  # the box moves back: disoccluded in frame 2
        nrm = g["normal"] + 0.05 * rng.standard_normal((h, w, 3)).astype(np.float32)
        g["normal"] = (nrm / np.linalg.norm(nrm, axis=-1, keepdims=True)).astype(np.float32)
        g["motion"][:] = (0.3 * (t > 0), -0.2 * (t > 0))
        e = poisson_map(rng, truth, 4.0)
        e[g["depth"] <= 0] = 0.0
        m2 = poisson_m2(e, 4.0) if with_m2 else None
        res = run_frame(den, g, e, out, m2)
        ref, hist = caustic_frame_naive(e, g["depth"], g["normal"], g["motion"], hist, s, m2)
        np.testing.assert_allclose(history(den), hist["frames"], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(den.variance.numpy().reshape(h, w), hist["variance"], rtol=1e-4, atol=1e-6)
        np.testing.assert_allclose(res, ref, rtol=1e-5, atol=1e-5 * truth.max())
    assert np.any(hist["frames"] < 1.5) and np.any(hist["frames"] > 2.5)  # both reset and accumulated pixels
    if atrous == 4:  # the step-8 level's sub-lattice-major copies were written (else its lattice went unused)
        assert den.lattice is not None and np.abs(den.lattice[1].numpy()).max() > 0.0
    if with_m2:  # the photons' variance capped s² somewhere (else this compared nothing new)
        assert np.any(hist["photon_var"] > 0) and np.any(hist["moments"][..., 2] > hist["photon_var"])


def test_caustic_cooperative_cpu_blocks(monkeypatch):
    """The tiled accumulate with real multi-lane blocks on the CPU (cooperative fibers): the barrier between its
    window region's loads and the windows is where a race would show; equals the twin like the one-lane block."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    test_caustic_matches_naive_twin("cpu", "tiled", True, 3, 3, (35, 21))


def test_caustic_every_setting_reaches_a_kernel(device):
    """Changing any one setting changes the output of a short sequence over a scene that exercises it."""
    rng = np.random.default_rng(5)
    truth = caustic_pattern()
    frames = []
    for t in range(6):
        g = plane()
        g["depth"][8:16, 10:20] = 1.5
        g["depth"] *= 1.0 + 0.05 * (t % 2)  # depth jitter that depth_tolerance decides on
        tilt = 0.1 * (t % 2)  # normal jitter that normal_tolerance decides on
        n = np.stack([PLANE_NORMAL[0] + tilt + 0.05 * np.sin(np.arange(W) * 0.7)[None, :].repeat(H, 0),
                      np.zeros((H, W)), np.ones((H, W))], -1)
        g["normal"] = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
        e = poisson_map(rng, truth * (1.0 + 0.5 * (t >= 3)), 2.0)
        frames.append((g, e, poisson_m2(e, 2.0)))
    changed = dict(use_photon_m2=False,
                   max_history=3, change_radius=1, change_sigmas=0.5, pixel_sigmas=0.5, change_persistence=0.0,
                   atrous_levels=2, noise_target=0.3, noise_target_m2=0.3,
                   sigma_depth=0.1, sigma_normal=4.0, sigma_luminance=0.5, depth_tolerance=0.01,
                   normal_tolerance=0.999)
    flow_changed = dict(caustic_flow=False, flow_sigmas=40.0, flow_radius=0, flow_history=4.0)  # base: the default
    assert set(changed) | set(flow_changed) == {f.name for f in fields(CausticSettings)}

    def sequence(settings, with_m2=True):
        den = CausticDenoiser(W, H, device, settings)
        out = wp.zeros(W * H, dtype=wp.vec3, device=device)
        return np.stack([run_frame(den, g, e, out, m2 if with_m2 else None).copy() for g, e, m2 in frames])

    base = {True: sequence(CausticSettings()), False: sequence(CausticSettings(), False)}
    for name, value in changed.items():
        with_m2 = name != "noise_target"  # τ of the frames without the photons' Σ e²
        assert not np.allclose(sequence(replace(CausticSettings(), **{name: value}), with_m2), base[with_m2],
                               rtol=1e-4, atol=0), name
    # the caustic flow: a displacement of 1.5 pixels in the left half (0.5 in the right: under flow_sigmas = 40's
    # threshold there), its variance 0.01 pixels², counted 2 a pixel (flow_radius 0 pools one pixel, not nine)
    flow = uniform_flow((1.5, 0.0), count=2.0, s2=0.01)
    flow[:, W // 2:, 0] = -0.5 * 2.0
    flow[::2, :, 3] = 0.0  # every other row without photons: the pooled count differs from one pixel's

    def flow_sequence(settings):
        den = CausticDenoiser(W, H, device, settings)
        out = wp.zeros(W * H, dtype=wp.vec3, device=device)
        return np.stack([run_frame(den, g, e, out, m2, flow).copy() for g, e, m2 in frames])

    flow_base = flow_sequence(CausticSettings())  # the default follows a flow when it is given one
    assert not np.allclose(flow_base, base[True], rtol=1e-4, atol=0), "a caustic flow given"
    for name, value in flow_changed.items():
        assert not np.allclose(flow_sequence(replace(CausticSettings(), **{name: value})), flow_base,
                               rtol=1e-4, atol=0), name


def test_caustic_settings_validation():
    for bad in (dict(max_history=1), dict(change_sigmas=0.0), dict(pixel_sigmas=-1.0), dict(noise_target=0.0),
                dict(change_persistence=1.0), dict(change_persistence=-0.1),
                dict(atrous_levels=-1),
                dict(sigma_luminance=0.0), dict(normal_tolerance=1.5), dict(flow_sigmas=0.0), dict(flow_radius=-1),
                dict(flow_history=0.5)):
        with pytest.raises(ValueError):
            CausticSettings(**bad)


def test_bench_denoise_smoke():
    """tools/bench_denoise.py runs end to end on its synthetic G-buffer and names every denoiser."""
    import os
    import subprocess
    import sys

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    res = subprocess.run([sys.executable, os.path.join(root, "tools", "bench_denoise.py"), "--smoke"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    for name in ("caustic", "svgf", "gather"):
        assert f"  {name} " in res.stdout


def test_caustic_camera_pan_keeps_the_caustic_sharp(device):
    """A still caustic under a camera that pans half a pixel per frame (motion vectors say so): the history
    is fetched by Catmull-Rom where the whole 4x4 footprint is the same surface, so after 24 frames the
    accumulated estimate is within 1.5x the running mean's own noise of the truth (repeated bilinear fetches
    blur the bands frame after frame: 3x or more), and the output beats the raw photon map by a wide margin."""
    rng = np.random.default_rng(9)
    w, h = 40, 24
    den = CausticDenoiser(w, h, device)
    out = wp.zeros(w * h, dtype=wp.vec3, device=device)
    photon = 0.5
    frames = 24

    def pattern(shift):  # bands about 5 pixels wide: sampled finely enough to be interpolated
        x = np.arange(w)[None, :] - shift
        return 2.0 + 30.0 * np.exp(-np.sin(0.15 * x + 0.3 * np.sin(0.2 * np.arange(h)[:, None])) ** 2 / 0.25)

    for t in range(frames):
        g = plane(w, h, hole=False)
        g["depth"][:] = 2.0  # a fronto-parallel floor: the pan changes no depth
        g["motion"][:] = (-0.5 * (t > 0), 0.0)  # each point was half a pixel to the left
        truth = pattern(0.5 * t)
        e = poisson_map(rng, truth, photon)
        res = run_frame(den, g, e, out)
    integrated = den.integrated.numpy().reshape(h, w, 3)[..., 1]
    # off the columns reached by the left border's history (its off-screen tap is dropped, not interpolated:
    # half a pixel per frame of error that the pan carries inwards)
    inner = (slice(2, -2), slice(16, -2))
    n = history(den)[inner]
    floor = np.sqrt(np.mean(truth[inner] * photon / n)) / truth[inner].mean()
    err = np.sqrt(np.mean((integrated[inner] - truth[inner]) ** 2)) / truth[inner].mean()
    err_out = np.sqrt(np.mean((res[..., 1][inner] - truth[inner]) ** 2)) / truth[inner].mean()
    err_raw = np.sqrt(np.mean((e[..., 1][inner] - truth[inner]) ** 2)) / truth[inner].mean()
    print(f"pan: median history {np.median(n):.1f}, accumulated error {err:.4f} (noise floor {floor:.4f}), "
          f"output {err_out:.4f}, raw {err_raw:.4f}")
    assert np.median(n) > 0.5 * frames
    assert err < 1.5 * floor and err_out < 0.5 * err_raw


@pytest.mark.parametrize("photon,with_m2", [(0.05, False), (0.05, True), (0.5, False), (0.5, True)])
def test_caustic_moving_caustic_never_worse_than_raw(device, photon, with_m2):
    """A caustic sweeping across a still floor a pixel per frame (a moving light: the motion vectors are
    zero): over the last frames the output is no further from the truth than the raw photon map, and it
    follows the caustic (no more than 1.5x the truth's own frame-to-frame change as flicker)."""
    rng = np.random.default_rng(12)
    g = plane(hole=False)
    den = CausticDenoiser(W, H, device)
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    err, err_raw, flicker, truth_change = [], [], [], []
    prev = prev_truth = None
    for t in range(16):
        truth = caustic_pattern(shift=1.0 * t)
        e = poisson_map(rng, truth, photon)
        res = run_frame(den, g, e, out, poisson_m2(e, photon) if with_m2 else None)[..., 1].copy()
        if t >= 10:
            err.append(np.sqrt(np.mean((res - truth) ** 2)) / truth.mean())
            err_raw.append(np.sqrt(np.mean((e[..., 1] - truth) ** 2)) / truth.mean())
            flicker.append(np.abs(res - prev).sum() / res.sum())
            truth_change.append(np.abs(truth - prev_truth).sum() / truth.sum())
        prev, prev_truth = res, truth
    print(f"moving caustic, {photon} W/m² per photon{' (photon_m2)' if with_m2 else ''}: "
          f"error {np.mean(err):.4f} (raw {np.mean(err_raw):.4f}), "
          f"flicker {np.mean(flicker):.4f} (truth's change {np.mean(truth_change):.4f})")
    assert np.mean(err) <= np.mean(err_raw)
    assert np.mean(flicker) <= 1.5 * np.mean(truth_change)


@pytest.mark.parametrize("photon,speed", [(0.25, 4.0), (1.0, 2.0)])
def test_caustic_fast_caustic_as_good_as_a_reset_every_frame(device, photon, speed):
    """A still caustic for 16 frames, then moving ``speed`` pixels a frame over a still floor (a turning sun:
    motion vectors zero, the history stale at every frame): no history is usable, and the best a temporal stage
    can do is a reset every frame. The denoiser's error over the moving frames is within 5% of a denoiser reset
    before each frame on the same maps (measured 0.98-1.01x; perf_notes section 18), and the pixels it cut to
    about a frame's worth hand the spatial filter the variance their estimate has (Poisson: truth · photon / n;
    measured 0.83-1.07 of it over the cut pixels, a reset frame's own estimate 0.74-0.96): the filter of a
    fresh frame, not one sized for the history they no longer have."""
    rng = np.random.default_rng(17)
    g = plane(hole=False)
    den, reset = CausticDenoiser(W, H, device), CausticDenoiser(W, H, device)
    out, out_reset = wp.zeros(W * H, dtype=wp.vec3, device=device), wp.zeros(W * H, dtype=wp.vec3, device=device)
    err, err_reset, variance_ratio = [], [], []
    for t in range(22):
        truth = caustic_pattern(shift=speed * max(t - 15, 0))
        e = poisson_map(rng, truth, photon)
        res = run_frame(den, g, e, out, poisson_m2(e, photon))[..., 1]
        reset.reset()
        res_reset = run_frame(reset, g, e, out_reset, poisson_m2(e, photon))[..., 1]
        if t >= 16:
            err.append(np.sqrt(np.mean((res - truth) ** 2)) / truth.mean())
            err_reset.append(np.sqrt(np.mean((res_reset - truth) ** 2)) / truth.mean())
            n = history(den)
            cut = n < 1.3
            assert cut.mean() > 0.5  # the stale history is cut nearly everywhere
            variance_ratio.append(den.variance.numpy().reshape(H, W)[cut].mean() / (truth * photon / n)[cut].mean())
    print(f"caustic moving {speed} px a frame, {photon} W/m² per photon: error {np.mean(err):.4f}, reset every "
          f"frame {np.mean(err_reset):.4f}; cut pixels' variance over their true one {min(variance_ratio):.2f}-"
          f"{max(variance_ratio):.2f}")
    assert np.mean(err) <= 1.05 * np.mean(err_reset)
    assert 0.75 <= min(variance_ratio) and max(variance_ratio) <= 1.5


def test_caustic_slow_drift_keeps_the_history_short(device):
    """A caustic drifting a third of a pixel per frame (a slowly turning sun): too slow for one frame's change
    test, so without keeping the window's change ratio from frame to frame (change_persistence) the history
    lags the caustic and the output is worse than the raw photon map (0.177 against 0.165 relative RMSE);
    with it the output is no worse than raw (0.164); with the photons' Σ e² and its τ, too."""

    def error(settings, with_m2=False):
        rng = np.random.default_rng(31)
        g = plane(hole=False)
        den = CausticDenoiser(W, H, device, settings)
        out = wp.zeros(W * H, dtype=wp.vec3, device=device)
        err, err_raw = [], []
        for t in range(24):
            truth = caustic_pattern(shift=0.35 * t)
            e = poisson_map(rng, truth, 0.2)
            res = run_frame(den, g, e, out, poisson_m2(e, 0.2) if with_m2 else None)[..., 1]
            if t >= 16:
                err.append(np.sqrt(np.mean((res - truth) ** 2)) / truth.mean())
                err_raw.append(np.sqrt(np.mean((e[..., 1] - truth) ** 2)) / truth.mean())
        return np.mean(err), np.mean(err_raw)

    err, err_raw = error(CausticSettings())
    err_forget, _ = error(CausticSettings(change_persistence=0.0))
    err_m2, _ = error(CausticSettings(), with_m2=True)  # the photons' Σ e² given: its own, lower τ
    print(f"slow drift: error {err:.4f}, without persistence {err_forget:.4f}, with photon_m2 {err_m2:.4f}, "
          f"raw {err_raw:.4f}")
    assert err <= err_raw < err_forget
    assert err_m2 <= err_raw


def test_caustic_stays_finite_after_a_history_of_vanishing_irradiance(device):
    """A history that decayed towards float32's smallest numbers, then a bright frame: the change ratio over
    the underflowing variance overflows; the history must reset (α = 1), never turn into NaN."""
    rng = np.random.default_rng(4)
    g = plane()
    surf = g["depth"] > 0
    den = CausticDenoiser(W, H, device)
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    for frame in range(12):
        run_frame(den, g, poisson_map(rng, np.full((H, W), 1e-36), 1e-36), out)
    for frame in range(3):
        res = run_frame(den, g, poisson_map(rng, caustic_pattern(), 5.0), out)
        assert np.all(np.isfinite(res))
    assert res[surf].mean() > 1.0  # the bright frames are followed, not held at the vanished history


def test_caustic_photon_m2_of_zero_is_no_information(device):
    """``photon_m2`` = 0 where no photon landed: a window without any leaves the variance estimate to the photon
    map alone (bit for bit the run without it, with photons or without), and frames with no photons after a
    history of them, then photons again, stay finite and are followed."""
    rng = np.random.default_rng(6)
    g = plane()
    surf = g["depth"] > 0
    truth = caustic_pattern()
    outs = {}
    for mode in ("none", "zeros", "m2"):  # one τ for all three: the runs differ by the variance estimate only
        den = CausticDenoiser(W, H, device, CausticSettings(noise_target_m2=CausticSettings().noise_target))
        out = wp.zeros(W * H, dtype=wp.vec3, device=device)
        rng = np.random.default_rng(6)
        seq = []
        for t in range(14):
            e = poisson_map(rng, truth, 0.5) if not 6 <= t < 10 else np.zeros((H, W, 3), np.float32)
            m2 = {"none": None, "zeros": np.zeros((H, W), np.float32), "m2": poisson_m2(e, 0.5)}[mode]
            res = run_frame(den, g, e, out, m2).copy()
            assert np.all(np.isfinite(res)) and np.all(np.isfinite(den.variance.numpy()))
            seq.append(res)
        outs[mode] = np.stack(seq)
    assert np.array_equal(outs["zeros"], outs["none"])
    dark = outs["m2"][6:10]  # no photons for four frames: the history is cut back towards zero, not held
    assert dark[-1][surf].mean() < 0.2 * truth.mean()
    back = outs["m2"][-1][..., 1]  # four frames after the photons came back
    assert abs(back[surf].mean() / truth[surf].mean() - 1.0) < 0.1


def test_caustic_photon_m2_follows_a_caustic_the_differences_take_for_noise(device):
    """Stratified photon maps (each pixel floor(E/e + u) photons of e = 0.05 W/m², u uniform: sub-Poisson, as
    low-discrepancy emission leaves them; Σ e² is then far above their variance). The bands' curvature inflates
    the neighbour differences, so without photon_m2 a caustic moving a pixel a frame passes for noise and lags
    (0.023 relative RMSE); capped by the photons' Σ e² it is followed (0.007). Held still, both are the same."""

    def error(speed, with_m2):
        rng = np.random.default_rng(12)
        g = plane(hole=False)
        den = CausticDenoiser(W, H, device, CausticSettings(noise_target_m2=CausticSettings().noise_target))  # one τ
        out = wp.zeros(W * H, dtype=wp.vec3, device=device)
        err = []
        for t in range(24):
            truth = caustic_pattern(shift=speed * t)
            k = np.floor(truth / 0.05 + rng.random(truth.shape))
            e = (k * 0.05)[..., None] * np.ones(3, np.float32)
            res = run_frame(den, g, e, out, k * 0.05 ** 2 if with_m2 else None)[..., 1]
            if t >= 16:
                err.append(np.sqrt(np.mean((res - truth) ** 2)) / truth.mean())
        return np.mean(err)

    moving, moving_m2 = error(1.0, False), error(1.0, True)
    still, still_m2 = error(0.0, False), error(0.0, True)
    print(f"stratified maps: moving {moving:.4f} -> {moving_m2:.4f} with photon_m2; still {still:.5f} -> {still_m2:.5f}")
    assert moving_m2 < 0.5 * moving
    assert still_m2 <= 1.01 * still


@pytest.mark.parametrize("step,conserve,gate,lattice,sigma_normal", [
    (1, True, None, False, 32.0), (4, False, None, False, 32.0), (16, True, None, False, 32.0),
    (2, True, 0.1, False, 32.0), (8, True, None, True, 32.0), (16, False, None, True, 32.0),
    (1, True, None, False, 128.0), (2, True, 0.1, False, 128.0), (8, False, None, True, 128.0),
    (1, True, None, True, 128.0), (1, False, None, True, 128.0)])
def test_atrous_level_tiles_match_naive_twin(device, step, conserve, gate, lattice, sigma_normal):
    """The tiled level (:func:`launch_atrous`, SVGF's) over several blocks: tiles of each sub-lattice (step² of them), aprons that cross tiles and
    sub-lattices, a partial last tile and image sizes no multiple of the step, against the float64 twin; with
    ``lattice`` the level reads its packed input, guide and guide-pass terms in sub-lattice-major order. σ_n = 128
    (both denoisers' default) runs the level compiled for it (its normal term seven squarings, no logarithm); at step 1
    from a packed input (``lattice`` at step 1: packed first, no sub-lattice order) that is SVGF's first level, which
    blurs its own variance and has no guide pass."""
    rng = np.random.default_rng(23 + step)
    w, h = 45, 38
    g = plane(w, h)
    g["depth"][10:30, 12:33] = 1.3  # a depth edge
    g["depth"][3:6, 3:40] = 0.0  # no surface
    g["depth"][16:32, :32] = 0.0  # a whole tile of the step-1 level without a surface (skipped)
    n = g["normal"] + 0.1 * rng.standard_normal((h, w, 3)).astype(np.float32)
    g["normal"] = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
    color = rng.exponential(2.0, (h, w, 3)).astype(np.float32)
    color[g["depth"] <= 0] = 0.0
    variance = rng.exponential(1.0, (h, w)).astype(np.float32)
    variance[g["depth"] <= 0] = 0.0
    s = SVGFSettings(sigma_luminance=2.0, sigma_normal=sigma_normal, conserve_energy=conserve)
    dev = upload(dict(depth=g["depth"], normal=g["normal"], irradiance=color), device)
    slope = wp.array(depth_slope_naive(g["depth"]).astype(np.float32).reshape(-1), dtype=wp.float32, device=device)
    var_in = wp.array(variance.reshape(-1), dtype=wp.float32, device=device)
    c_out = wp.full(w * h, wp.vec3(-7.0), dtype=wp.vec3, device=device)  # every pixel must be written
    v_out = wp.full(w * h, -7.0, dtype=wp.float32, device=device)
    scratch = [wp.zeros(w * h, dtype=wp.vec4, device=device) for _ in range(3)]
    if lattice:  # pack first (a step-1 guide pass), then the level from the packed input
        from cisp_warp.denoise.kernels_atrous import lattice_size
        size = lattice_size(w, h, step)
        assert size > w * h or step == 1
        packed = [wp.zeros(w * h, dtype=wp.vec4, device=device) for _ in range(2)]
        launch_atrous(None, None, slope, w, h, 1, s.sigma_depth, s.sigma_normal, s.sigma_luminance, conserve,
                      scratch[0], unpacked=(dev["irradiance"], var_in, dev["depth"], dev["normal"]), pack_into=packed,
                      color_variance_out=scratch[1])
        aux, cv_lat, guide_lat = (wp.full(size, wp.vec4(7.0), dtype=wp.vec4, device=device) for _ in range(3))
        launch_atrous(packed[0], packed[1], slope, w, h, step, s.sigma_depth, s.sigma_normal, s.sigma_luminance,
                      conserve, aux, noise_target=gate, color_out=c_out, variance_out=v_out, lattice=(cv_lat, guide_lat))
        # the lattice buffers were used (step >= 8); at step 1 the level wrote its own guide terms, aux not at all
        assert np.allclose(cv_lat.numpy(), 7.0) == (step == 1) and np.allclose(aux.numpy(), 7.0) == (step == 1)
    else:
        launch_atrous(None, None, slope, w, h, step, s.sigma_depth, s.sigma_normal, s.sigma_luminance, conserve,
                      scratch[0], noise_target=gate, color_out=c_out, variance_out=v_out,
                      unpacked=(dev["irradiance"], var_in, dev["depth"], dev["normal"]), pack_into=scratch[1:])
    c_ref, v_ref = atrous_level_naive(color, variance, g["depth"], g["normal"], step,
                                      s.sigma_depth, s.sigma_normal, s.sigma_luminance, conserve, noise_target=gate)
    np.testing.assert_allclose(c_out.numpy().reshape(h, w, 3), c_ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(v_out.numpy().reshape(h, w), v_ref, rtol=1e-5, atol=1e-7)


def lattice_order(a, step, pad):
    """Rows of ``a`` (H x W x ...) in the sub-lattice-major order of ``step`` (:func:`lattice_index`), padded with
    ``pad`` to :func:`lattice_size` entries."""
    h, w = a.shape[:2]
    sub_h, sub_w = -(-h // step), -(-w // step)
    out = np.full((step * step * sub_h * sub_w,) + a.shape[2:], pad, dtype=a.dtype)
    y, x = np.mgrid[:h, :w]
    out[(((y % step) * step + x % step) * sub_h + y // step) * sub_w + x // step] = a
    return out


@pytest.mark.parametrize("step,conserve", [(4, True), (8, False), (2, True)])
def test_chained_levels_write_the_next_input(device, step, conserve):
    """A level (SVGF's, ungated) writing its packed output in the next level's sub-lattice-major order
    (``lattice_out``) and its Var densely (``variance_next``), and the next level taking them (``variance``: its
    guide pass reads that Var alone; ``input_lattice``: no copy of the input), give bit for bit what the dense output
    and the copying guide pass give, and both equal the float64 twin's two levels; at step 2 the next level (4) reads
    the dense output and the Var copy, no sub-lattice order."""
    from cisp_warp.denoise import kernels_atrous
    from cisp_warp.denoise.kernels_atrous import lattice_size
    rng = np.random.default_rng(71 + step)
    w, h = 45, 38
    g = plane(w, h)
    g["depth"][10:30, 12:33] = 1.3
    g["depth"][3:6, 3:40] = 0.0
    n = g["normal"] + 0.05 * rng.standard_normal((h, w, 3)).astype(np.float32)
    g["normal"] = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
    color = rng.exponential(2.0, (h, w, 3)).astype(np.float32)
    color[g["depth"] <= 0] = 0.0
    variance = rng.exponential(1.0, (h, w)).astype(np.float32)
    variance[g["depth"] <= 0] = 0.0
    s = SVGFSettings(sigma_luminance=2.0, conserve_energy=conserve)
    sig = (s.sigma_depth, s.sigma_normal, s.sigma_luminance, conserve)
    dev = upload(dict(depth=g["depth"], normal=g["normal"], irradiance=color), device)
    slope = wp.array(depth_slope_naive(g["depth"]).astype(np.float32).reshape(-1), dtype=wp.float32, device=device)
    var_in = wp.array(variance.reshape(-1), dtype=wp.float32, device=device)
    nxt = 2 * step
    size = max(lattice_size(w, h, nxt), w * h)
    aux = wp.zeros(size, dtype=wp.vec4, device=device)
    packed = [wp.zeros(w * h, dtype=wp.vec4, device=device) for _ in range(2)]
    launch_atrous(None, None, slope, w, h, 1, *sig, aux, unpacked=(dev["irradiance"], var_in, dev["depth"],
                  dev["normal"]), pack_into=packed, color_variance_out=wp.zeros(w * h, dtype=wp.vec4, device=device))
    lat = nxt >= kernels_atrous.LATTICE_STEP
    # the dense way: the level's packed output, the next level's guide pass copying it (and the guide) in its order
    dense = wp.zeros(w * h, dtype=wp.vec4, device=device)
    launch_atrous(packed[0], packed[1], slope, w, h, step, *sig, aux, color_variance_out=dense)
    outs = [(wp.full(w * h, wp.vec3(-7.0), dtype=wp.vec3, device=device),
             wp.full(w * h, -7.0, dtype=wp.float32, device=device)) for _ in range(2)]
    lattice = tuple(wp.zeros(size, dtype=wp.vec4, device=device) for _ in range(2)) if lat else None
    launch_atrous(dense, packed[1], slope, w, h, nxt, *sig, aux, color_out=outs[0][0], variance_out=outs[0][1],
                  lattice=lattice)
    # the chained way
    chained = wp.full(size, wp.vec4(7.0), dtype=wp.vec4, device=device)
    var_next = wp.full(w * h, 7.0, dtype=wp.float32, device=device)
    launch_atrous(packed[0], packed[1], slope, w, h, step, *sig, aux, color_variance_out=chained,
                  variance_next=var_next, lattice_out=nxt if lat else 0)
    d = dense.numpy().reshape(h, w, 4)
    c = chained.numpy()
    if lat:  # every point in its place, the padding untouched
        np.testing.assert_array_equal(c, lattice_order(d, nxt, 7.0))
    else:
        np.testing.assert_array_equal(c[:w * h], d.reshape(-1, 4))
    np.testing.assert_array_equal(var_next.numpy(), d[..., 3].reshape(-1))
    assert (d[..., 3] < 0).any() and (d[..., 3] > 0).any()  # pixels without a surface and with a variance
    guide_lat = wp.zeros(size, dtype=wp.vec4, device=device) if lat else None
    launch_atrous(chained, packed[1], slope, w, h, nxt, *sig, aux, color_out=outs[1][0], variance_out=outs[1][1],
                  lattice=(None, guide_lat) if lat else None, variance=var_next, input_lattice=lat)
    for a, b in zip(outs[0], outs[1]):
        np.testing.assert_array_equal(a.numpy(), b.numpy())
    c_ref, v_ref = color, variance
    for st in (step, nxt):
        c_ref, v_ref = atrous_level_naive(c_ref, v_ref, g["depth"], g["normal"], st, *sig)
    np.testing.assert_allclose(outs[1][0].numpy().reshape(h, w, 3), c_ref, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(outs[1][1].numpy().reshape(h, w), v_ref, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("run", [4, 8])
@pytest.mark.parametrize("w,h,lattice,copy_guide", [(45, 38, 0, 0), (41, 7, 0, 0), (44, 21, 8, 1), (43, 30, 16, 0),
                                                     (3, 5, 4, 1), (1, 2, 0, 0), (48, 17, 0, 0), (4, 9, 8, 1),
                                                     (12, 6, 4, 0)])
def test_guide_runs_equal_the_pixel_guide_pass(device, w, h, lattice, copy_guide, run):
    """SVGF's chained guide pass a run of 4 or 8 pixels a thread (:func:`atrous_guide_run`, section 73) writes
    what the pixel-a-thread pass (:func:`atrous_guide`, ``packed`` = 3) writes, bit for bit: the terms (0 without a
    surface; the image's edges; widths that are no multiple of the run), in the sub-lattice-major order where asked,
    and the guide's copy there; the rest of the buffers untouched. Widths that are a multiple of 4 take the
    16-byte loads (checked to be chosen)."""
    from cisp_warp.denoise.kernels_atrous import (ATROUS_GUIDE_RUN, atrous_guide, lattice_size, pair_scales,
                                                  runs_aligned, spare_outputs)
    rng = np.random.default_rng(73 + w + lattice)
    var = rng.exponential(1.0, (h, w)).astype(np.float32)
    var[rng.random((h, w)) < 0.3] = -1.0  # no surface
    var[rng.random((h, w)) < 0.1] = 0.0
    var[0, 0], var[-1, -1] = -1.0, 2.0
    slope = rng.random(h * w).astype(np.float32)
    guide = rng.standard_normal((2 * h * w, 4)).astype(np.float32)
    size = max(lattice_size(w, h, lattice) if lattice else 0, w * h)
    var_d = wp.array(var.reshape(-1), dtype=wp.float32, device=device)
    slope_d = wp.array(slope, dtype=wp.float32, device=device)
    guide_d = wp.array(guide, dtype=wp.vec4, device=device)
    parity = wp.array([1], dtype=wp.int32, device=device)
    depth_scale = pair_scales(0.7, 128.0, 4.0)[0]
    spare = spare_outputs(device)
    outs = []
    aligned = runs_aligned(w, var_d, slope_d)
    assert aligned == (w % 4 == 0)
    for fast in (False, True):
        aux = wp.full(size, wp.vec4(5.0), dtype=wp.vec4, device=device)
        guide_lat = wp.full(size, wp.vec4(9.0), dtype=wp.vec4, device=device)
        if fast:
            wp.launch(ATROUS_GUIDE_RUN[run], dim=(h, (w + run - 1) // run), device=device,
                      inputs=[var_d, slope_d, w, h, depth_scale, aux, lattice, guide_d, guide_lat, copy_guide, parity,
                              w * h, aligned])
        else:
            wp.launch(atrous_guide, dim=h * w, device=device,
                      inputs=[3, spare["vec4"], spare["vec3"], var_d, spare["float"], spare["vec3"], slope_d, w, h, 0,
                              0.0, depth_scale, 0.0, aux, 0, spare["vec4"], spare["vec4"], lattice, guide_d,
                              spare["vec4"], guide_lat, copy_guide, parity, w * h])
        outs.append((aux.numpy(), guide_lat.numpy()))
    np.testing.assert_array_equal(outs[0][0], outs[1][0])
    np.testing.assert_array_equal(outs[0][1], outs[1][1])
    terms = outs[1][0].view(np.float32).reshape(-1)[:2 * size].reshape(-1, 2)
    assert (terms[:, 1] > 0).any() and (terms == 0).all(axis=1).any()  # blurred variances, and pixels without a surface
    if lattice and copy_guide:
        assert (outs[1][1] != 9.0).any()


def test_chained_level_arguments_checked():
    """The chained levels' arguments are checked: one clear sentence each."""
    w, h = 20, 12
    z = {k: wp.zeros(w * h, dtype=t, device="cpu") for k, t in (("cv", wp.vec4), ("f", wp.float32))}
    args = (z["cv"], z["cv"], z["f"], w, h, 8, 0.5, 128.0, 4.0, True, wp.zeros(512, dtype=wp.vec4, device="cpu"))
    big = (wp.zeros(512, dtype=wp.vec4, device="cpu"),) * 2
    with pytest.raises(ValueError, match="ungated level with a packed input"):
        launch_atrous(*args, noise_target=0.1, variance=z["f"])
    with pytest.raises(ValueError, match="sub-lattice-major order needs variance"):
        launch_atrous(*args, lattice=big, input_lattice=True)
    with pytest.raises(ValueError, match="sub-lattice-major order needs variance"):
        launch_atrous(*args, lattice=big, variance=z["f"])
    with pytest.raises(ValueError, match="which is not given"):
        launch_atrous(*args, variance_next=z["f"])
    with pytest.raises(ValueError, match="power of two"):
        launch_atrous(*args, color_variance_out=z["cv"], lattice_out=12)
    with pytest.raises(ValueError, match="entries in the sub-lattice-major order"):
        launch_atrous(*args, color_variance_out=z["cv"], lattice_out=16)


@pytest.mark.parametrize("feedback,levels,sigma_normal", [(0, 3, 32.0), (2, 3, 32.0), (-1, 3, 32.0), (3, 5, 32.0),
                                                        (4, 6, 32.0), (3, 5, 128.0)])
def test_svgf_levels_match_naive_twin(device, feedback, levels, sigma_normal):
    """SVGF's chained levels (packed by reproject and filter_moments, ping-ponged packed, the last one unpacked, the
    feedback level writing the colour history; steps 8 and up read in sub-lattice-major order, the guide of steps 8
    and 16 written so by reproject, of step 32 copied by its guide pass) equal the float64 twin's levels applied to
    the same temporal result. Without feedback (the temporal result is the same then), over two frames: the second
    reads the other row of the history (its guide among them)."""
    rng = np.random.default_rng(31)
    w, h = 37, 29
    gs = [plane(w, h), plane(w, h)]
    gs[0]["depth"][8:20, 9:25] = 1.4
    gs[1]["depth"][10:24, 4:20] = 1.2  # the second frame's G-buffer differs from the first's (a wrong row shows)
    frames = [(gs[k], photon_map(rng, h, w, 0.3, [5.0, 3.0, 1.0])) for k in range(2 if feedback == -1 else 1)]
    g = frames[-1][0]
    base = SVGFSettings(sigma_luminance=2.0, sigma_normal=sigma_normal)
    temporal = SVGF(w, h, device, replace(base, atrous_levels=0, feedback_level=-1))
    out = wp.zeros(w * h, dtype=wp.vec3, device=device)
    for gk, e in frames:
        color = run_frame(temporal, gk, e, out).astype(np.float64)
    variance = temporal.variance.numpy().reshape(h, w).astype(np.float64)
    s = replace(base, atrous_levels=levels, feedback_level=feedback)
    svgf = SVGF(w, h, device, s)
    for gk, e in frames:
        res = run_frame(svgf, gk, e, out)
    hist = svgf.hist_color.numpy()[len(frames) % 2].reshape(h, w, 3)  # the row the last frame writes
    c_ref, v_ref = color, variance
    assert (svgf.lattice is not None) == (levels > 3)
    for level in range(levels):
        c_ref, v_ref = atrous_level_naive(c_ref, v_ref, g["depth"], g["normal"], 1 << level, s.sigma_depth,
                                          s.sigma_normal, s.sigma_luminance, s.conserve_energy)
        if level == feedback:
            np.testing.assert_allclose(hist, c_ref, rtol=1e-5, atol=1e-5)
    if feedback == -1:
        np.testing.assert_array_equal(hist, color.astype(np.float32))
    np.testing.assert_allclose(res, c_ref, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(svgf.variance.numpy().reshape(h, w), v_ref, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("conserve", [True, False])
def test_select_free_levels_equal_the_select_levels(device, monkeypatch, conserve):
    """Section 85: SVGF's σ_n = 128 levels without the pair weights' select on p's surface (``SELECT_FREE``, the
    default: a point without a surface gets the dead guide, whose weights come out 0 from their own arithmetic) give
    every output of SVGF's frame bit for bit as the levels with the select (its twin, ``SELECT_FREE = False``): 5
    levels (step 1 self-guided, 2 and 4 dense, 8 and 16 in sub-lattice-major order), three frames with motion off, a
    hole, a region without a surface between surfaces (every pair kind: both without, one without), a depth step,
    noisy normals, blocks without signal and blocks whose apron alone holds it. Fails if ``DEAD_SLOPE`` is 0 (the
    pairs of two points without a surface turn NaN and spread through W_q)."""
    from cisp_warp.denoise import kernels_atrous as ka
    rng = np.random.default_rng(85)
    w, h = 83, 51
    g = plane(w, h)
    g["depth"][20:35, 30:50] = 1.25  # a depth step
    g["depth"][5:12, 40:70] = 0.0  # no surface between surfaces
    g["tri_id"][5:12, 40:70] = -1
    n = g["normal"] + 0.05 * rng.standard_normal((h, w, 3)).astype(np.float32)
    g["normal"] = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
    maps = []
    for t in range(3):
        e = photon_map(rng, h, w, 0.25, [4.0, 2.0, 1.0])
        e[:, 56:] = 0.0  # a region without signal: its blocks skip (or filter only for their aprons)
        maps.append(e)
    s = SVGFSettings(sigma_luminance=2.0, conserve_energy=conserve, atrous_levels=5, feedback_level=1)
    assert ka.normal_squarings(s.sigma_normal) == ka.NORMAL_SQUARINGS  # the default σ_n runs the compiled pow form
    outputs = {}
    for free in (True, False):
        monkeypatch.setattr(ka, "SELECT_FREE", free)
        monkeypatch.setattr(ka, "FOLD_GUIDE2", free)  # both section 85 changes, or main's levels
        assert (ka.level_kernel(0, ka.NORMAL_SQUARINGS, 1, free) is ka.ATROUS_LEVEL_SELF_FREE) == free
        assert (ka.level_kernel(0, ka.NORMAL_SQUARINGS, 0, free) is ka.ATROUS_LEVEL_FREE) == free
        svgf = SVGF(w, h, device, s)
        out = wp.zeros(w * h, dtype=wp.vec3, device=device)
        seq = []
        for e in maps:
            seq.append(run_frame(svgf, g, e, out).copy())
            seq.append(svgf.variance.numpy().copy())
            seq.append(svgf.hist_color.numpy().copy())
        outputs[free] = seq
    assert any(np.any(a != 0) for a in outputs[True])
    for a, b in zip(outputs[True], outputs[False]):
        assert np.all(np.isfinite(a))
        np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))  # bit for bit, zeros' signs included


@pytest.mark.parametrize("w,h,conserve", [(83, 51, False), (7, 5, True)])  # odd sizes both; two more were cut for the suite's 5 minutes
def test_step2_level_makes_its_guide_terms_like_the_guide_pass(device, monkeypatch, w, h, conserve):
    """Section 85: SVGF's step-2 level from the step-1 level's packed output and dense Var (``variance``) blurs its
    own variance (``FOLD_GUIDE2``, the default) and writes bit for bit what the guide pass and the plain level write
    (``FOLD_GUIDE2 = False``, main's): the colour and variance, the packed output and the next level's Var copy,
    with and without ``SELECT_FREE``; ``aux`` (the guide pass's output) untouched; images smaller than a block, no
    multiple of the tile, holes and a region without a surface. Fails if the region's origin is off by a pixel or its
    Var is read from the wrong buffer (tried)."""
    from cisp_warp.denoise import kernels_atrous as ka
    rng = np.random.default_rng(850 + w)
    g = plane(w, h)
    g["depth"][h // 4:h // 2, w // 3:2 * w // 3] = 1.3
    g["depth"][1:3, w // 2:] = 0.0
    n = g["normal"] + 0.05 * rng.standard_normal((h, w, 3)).astype(np.float32)
    g["normal"] = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
    color = rng.exponential(2.0, (h, w, 3)).astype(np.float32) * (rng.random((h, w, 1)) < 0.5)
    color[g["depth"] <= 0] = 0.0
    variance = (rng.exponential(1.0, (h, w)) * (rng.random((h, w)) < 0.7)).astype(np.float32)
    variance[g["depth"] <= 0] = 0.0
    s = SVGFSettings(sigma_luminance=2.0, conserve_energy=conserve)
    sig = (s.sigma_depth, s.sigma_normal, s.sigma_luminance, conserve)
    dev = upload(dict(depth=g["depth"], normal=g["normal"], irradiance=color), device)
    slope = wp.array(depth_slope_naive(g["depth"]).astype(np.float32).reshape(-1), dtype=wp.float32, device=device)
    var_in = wp.array(variance.reshape(-1), dtype=wp.float32, device=device)
    packed = [wp.zeros(w * h, dtype=wp.vec4, device=device) for _ in range(2)]
    launch_atrous(None, None, slope, w, h, 1, *sig, wp.zeros(w * h, dtype=wp.vec4, device=device),
                  unpacked=(dev["irradiance"], var_in, dev["depth"], dev["normal"]), pack_into=packed,
                  color_variance_out=wp.zeros(w * h, dtype=wp.vec4, device=device))
    level1 = wp.zeros(w * h, dtype=wp.vec4, device=device)
    var1 = wp.zeros(w * h, dtype=wp.float32, device=device)
    launch_atrous(packed[0], packed[1], slope, w, h, 1, *sig, wp.zeros(w * h, dtype=wp.vec4, device=device),
                  color_variance_out=level1, variance_next=var1)
    assert (var1.numpy() < 0).any() and (var1.numpy() > 0).any()
    results = {}
    for fold in (False, True):
        for free in (False, True):
            monkeypatch.setattr(ka, "FOLD_GUIDE2", fold)
            monkeypatch.setattr(ka, "SELECT_FREE", free)
            aux = wp.full(w * h, wp.vec4(7.0), dtype=wp.vec4, device=device)
            outs = (wp.full(w * h, wp.vec4(-7.0), dtype=wp.vec4, device=device),
                    wp.full(w * h, -7.0, dtype=wp.float32, device=device))
            launch_atrous(level1, packed[1], slope, w, h, 2, *sig, aux, color_variance_out=outs[0],
                          variance_next=outs[1], variance=var1)
            assert np.all(aux.numpy() == 7.0) == fold  # no guide pass where the level makes its terms
            results[fold, free] = [o.numpy() for o in outs]
    ref = results[False, False]
    c_ref, v_ref = atrous_level_naive(color, variance, g["depth"], g["normal"], 1, *sig)
    c_ref, v_ref = atrous_level_naive(c_ref, v_ref, g["depth"], g["normal"], 2, *sig)
    surf = g["depth"].reshape(-1) > 0
    np.testing.assert_allclose(ref[0][surf, :3], c_ref.reshape(-1, 3)[surf], rtol=1e-5, atol=1e-5)
    for key, res in results.items():
        for a, b in zip(res, ref):
            np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32), err_msg=str(key))


def test_step2_level_cooperative_cpu_blocks(monkeypatch):
    """The step-2 level that blurs its own variance with real multi-lane CPU blocks: its region's load rounds (8
    loads a lane, 512 lanes) and the barriers around the blur."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    test_step2_level_makes_its_guide_terms_like_the_guide_pass("cpu", monkeypatch, 45, 38, True)


def test_atrous_fast_math_helpers(device):
    """The pair weight's ln cos (series above 0.5), atanh series and its CUDA intrinsics against numpy in float64."""
    from cisp_warp.denoise.kernels_atrous import (atanh_series, fast_div, fast_exp, fast_exp2, fast_rcp, fast_rsqrt,
                                                  log_cosine)

    @wp.kernel
    def helpers(c: wp.array(dtype=float), out: wp.array2d(dtype=float)):
        i = wp.tid()
        out[i, 0] = log_cosine(c[i])
        out[i, 1] = fast_exp(-30.0 * c[i])
        out[i, 2] = fast_div(c[i], 3.0)
        out[i, 3] = fast_rsqrt(c[i])
        out[i, 4] = fast_rcp(c[i])
        out[i, 5] = fast_exp2(-30.0 * c[i])
        out[i, 6] = atanh_series(-c[i] / 3.0)

    c = np.concatenate([np.linspace(1e-3, 1.0, 997), 1.0 - np.logspace(-7, -1, 50)]).astype(np.float32)
    out = wp.zeros((c.size, 7), dtype=float, device=device)
    wp.launch(helpers, dim=c.size, inputs=[wp.array(c, dtype=float, device=device)], outputs=[out], device=device)
    r = out.numpy().astype(np.float64)
    c64 = c.astype(np.float64)
    assert np.all(np.abs(r[:, 0] - np.log(c64)) <= 2e-9 + 3e-7 * np.abs(np.log(c64)))  # σ_n = 128: < 4e-5 ulp-scale
    np.testing.assert_allclose(r[:, 1], np.exp(-30.0 * c64), rtol=3e-6)
    np.testing.assert_allclose(r[:, 2], c64 / 3.0, rtol=1e-6)
    np.testing.assert_allclose(r[:, 3], 1.0 / np.sqrt(c64), rtol=1e-6)
    np.testing.assert_allclose(r[:, 4], 1.0 / c64, rtol=1e-6)
    np.testing.assert_allclose(r[:, 5], np.exp2(-30.0 * c64), rtol=3e-6)
    t = -c.astype(np.float32) / np.float32(3.0)  # t in [-1/3, 0), as the pair weight takes it
    np.testing.assert_allclose(r[:, 6], np.arctanh(t.astype(np.float64)), rtol=3e-7)  # float32 rounding


@pytest.mark.parametrize("radius", [1, 3])
def test_gather_tiles_match_per_pixel_twin(device, radius):
    """The tiled gather (neighbourhood read once into shared memory) against the per-pixel kernel
    ``gaussian_gather``: several blocks, partial tiles, holes and tri_id < 0; bitwise on the CPU."""
    from cisp_warp.denoise.gather import gaussian_gather

    rng = np.random.default_rng(7 + radius)
    w, h = 45, 19
    depth = (2.0 + 0.01 * rng.random((h, w))).astype(np.float32)
    depth[5:9, 3:30] = 0.0
    depth[10:, 20:] *= 1.3
    n = rng.normal(size=(h, w, 3)) * 0.1 + [0.0, 0.0, 1.0]
    normal = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
    tri = np.where(rng.random((h, w)) < 0.05, -1, 0).astype(np.int32)
    e = rng.exponential(1.0, (h, w, 3)).astype(np.float32)
    d = upload(dict(depth=depth, normal=normal, tri_id=tri, irradiance=e), device)
    args = [d["irradiance"], d["depth"], d["normal"], d["tri_id"]]
    gather = GaussianGather(w, h, device, radius=radius)
    ref = wp.zeros(w * h, dtype=wp.vec3, device=device)
    wp.launch(gaussian_gather, dim=(h, w), device=device,
              inputs=args + [w, h, radius, 1.0 / (2.0 * gather.sigma ** 2), gather.depth_tolerance,
                             gather.normal_tolerance], outputs=[ref])
    out = wp.full(w * h, wp.vec3(-1.0), dtype=wp.vec3, device=device)
    gather.apply(*args, out)
    if device == "cpu":
        np.testing.assert_array_equal(out.numpy(), ref.numpy())
    else:
        np.testing.assert_allclose(out.numpy(), ref.numpy(), rtol=1e-6, atol=1e-7)


def test_atrous_level_in_place_matches_naive_twin(device):
    """Outputs aliasing the inputs (in place): the level packs its input first and still equals the twin."""
    rng = np.random.default_rng(41)
    w, h = 40, 21
    g = plane(w, h)
    color = rng.exponential(2.0, (h, w, 3)).astype(np.float32)
    color[g["depth"] <= 0] = 0.0
    variance = rng.exponential(1.0, (h, w)).astype(np.float32)
    s = SVGFSettings()
    dev = upload(dict(depth=g["depth"], normal=g["normal"], irradiance=color), device)
    slope = wp.array(depth_slope_naive(g["depth"]).astype(np.float32).reshape(-1), dtype=wp.float32, device=device)
    var = wp.array(variance.reshape(-1), dtype=wp.float32, device=device)
    scratch = [wp.zeros(w * h, dtype=wp.vec4, device=device) for _ in range(3)]
    launch_atrous_level(dev["irradiance"], var, dev["depth"], dev["normal"], slope, w, h, 2, s.sigma_depth,
                        s.sigma_normal, s.sigma_luminance, True, *scratch, wp.zeros(w * h, dtype=wp.float32, device=device),
                        dev["irradiance"], var)
    c_ref, v_ref = atrous_level_naive(color, variance, g["depth"], g["normal"], 2, s.sigma_depth, s.sigma_normal,
                                      s.sigma_luminance, True)
    np.testing.assert_allclose(dev["irradiance"].numpy().reshape(h, w, 3), c_ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(var.numpy().reshape(h, w), v_ref, rtol=1e-5, atol=1e-7)


def test_atrous_level_cooperative_cpu_blocks(monkeypatch):
    """The level with real multi-lane blocks on the CPU (cooperative fibers): the barriers between the shared
    tables' phases are where a race would show; equals the twin like the one-lane CPU block."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    test_atrous_level_tiles_match_naive_twin("cpu", 2, True, None, False, 32.0)
    test_atrous_level_tiles_match_naive_twin("cpu", 8, True, None, True, 32.0)
    test_atrous_level_tiles_match_naive_twin("cpu", 2, True, None, False, 128.0)
    test_atrous_level_tiles_match_naive_twin("cpu", 1, True, None, True, 128.0)  # the step-1 level's own guide terms
    test_atrous_level_signal_in_the_apron_only_is_filtered("cpu", None)  # the two barriers' flags across lanes
    test_atrous_level_signal_free_block_skips_its_weights("cpu")
    test_atrous_levels_chained_over_signal_free_blocks_match_naive_twin("cpu", 0, None)


@pytest.mark.parametrize("radius", [0, 1])
def test_caustic_motion_matches_naive_twin(device, radius):
    """The motion the history is fetched by (caustic flow where significant, else the surface's) against its twin:
    random motion, flows with and without photons, some under and some over the test's threshold."""
    rng = np.random.default_rng(4)
    motion = rng.normal(0.0, 1.0, (H, W, 2)).astype(np.float32)
    count = rng.integers(0, 4, (H, W)).astype(np.float32)
    d = motion + rng.normal(0.0, 0.6, (H, W, 2))
    flow = np.concatenate([d * count[..., None], (0.1 * rng.random((H, W)) * count)[..., None], count[..., None]],
                          -1).astype(np.float32)
    s = CausticSettings(caustic_flow=True, flow_radius=radius)
    den = CausticDenoiser(W, H, device, s)
    wp.launch(K.caustic_motion, dim=W * H, device=device,
              inputs=[wp.array(motion.reshape(-1, 2), dtype=wp.vec2, device=device),
                      wp.array(flow.reshape(-1, 4), dtype=wp.vec4, device=device), W, H, radius,
                      s.flow_sigmas ** 2], outputs=[den.motion_used, den.flow_used])
    got = den.motion_used.numpy().reshape(H, W, 2)
    want, used = caustic_motion_naive(motion, flow, radius, s.flow_sigmas)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(den.flow_used.numpy().reshape(H, W) > 0, used)
    assert 0.1 < used.mean() < 0.9  # both kinds of pixel were compared


@pytest.mark.parametrize("speed", [2.0, 3.0])
def test_caustic_flow_translating_caustic_converges_like_a_still_one(device, speed):
    """A caustic moving ``speed`` pixels a frame over a still floor (motion vectors zero), its displacement given
    exactly by the caustic flow: with the history uncapped along the flow (``flow_history`` 64) it follows the
    caustic, and after 20 frames the error is within 1.25x of the same caustic held still (the stability goal;
    measured 0.94-0.96x), while without the flow (the history stale every frame) it is far worse; the default cap
    (``flow_history`` 2 along the flow, for the residual of a real flow) lies between. Measured where
    the caustic has been on the image for every frame (a pixel's history cannot be older than the time since its
    caustic came in at the left edge). Whole pixels a frame: at a fractional displacement the history is resampled
    every frame and Catmull-Rom's low pass compounds over a long history (docs/perf_notes.md section 35)."""
    w, frames = 100, 20
    g = plane(w, H, hole=False)
    cols = np.arange(w) >= speed * frames + 2

    def error(shift_per_frame, settings):
        rng = np.random.default_rng(23)
        den = CausticDenoiser(w, H, device, settings)
        out = wp.zeros(w * H, dtype=wp.vec3, device=device)
        err = []
        for t in range(frames):
            truth = caustic_pattern(w, H, shift=shift_per_frame * t)
            e = poisson_map(rng, truth, 0.5)
            flow = uniform_flow((shift_per_frame, 0.0), H, w) if t > 0 else np.zeros((H, w, 4), np.float32)
            res = run_frame(den, g, e, out, poisson_m2(e, 0.5), flow)[..., 1]
            if t >= frames - 4:
                err.append(np.sqrt(np.mean((res - truth)[:, cols] ** 2)) / truth[:, cols].mean())
        return np.mean(err), np.median(history(den)[:, cols])

    uncapped = CausticSettings(caustic_flow=True, flow_history=64.0)
    still, _ = error(0.0, uncapped)
    moving, n = error(speed, uncapped)
    capped, n_capped = error(speed, CausticSettings(caustic_flow=True))
    stale, _ = error(speed, CausticSettings(caustic_flow=False))
    print(f"caustic moving {speed} px a frame: error with the flow {moving:.4f} (history {n:.1f} frames), capped "
          f"{capped:.4f} ({n_capped:.1f} frames), without {stale:.4f}, held still {still:.4f}")
    assert n > 15.0
    assert moving <= 1.25 * still
    assert moving < capped < 0.7 * stale
    assert 2.5 < n_capped < 3.5  # flow_history 2: α = 1/3, n = 3


def test_caustic_flow_constant_stays_constant(device):
    """A constant irradiance stays exactly constant whatever the caustic flow says (1.3 pixels, off the image at
    the edges), and the accumulated total follows the input's: nothing is made or lost by fetching elsewhere."""
    g = plane()
    den = CausticDenoiser(W, H, device, CausticSettings(caustic_flow=True))
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    e = np.where(g["depth"][..., None] > 0, np.float32(5.0), np.float32(0.0)) * np.ones(3, np.float32)
    for t in range(6):
        res = run_frame(den, g, e, out, None, uniform_flow((1.3, -0.7)))
    surf = g["depth"] > 0
    np.testing.assert_allclose(res[surf], 5.0, rtol=1e-5)
    assert np.all(res[~surf] == 0.0)
    assert np.any(np.abs(den.motion_used.numpy().reshape(H, W, 2) - (-1.3, 0.7)).sum(-1)[surf] < 1e-6)


def test_caustic_flow_conserves_energy(device):
    """A translating sparse caustic followed by the flow: every à-trous level keeps the accumulated total, and the
    accumulated total follows the current frame's true total (within its noise), not the stale history's."""
    rng = np.random.default_rng(9)
    g = plane(hole=False)
    den = CausticDenoiser(W, H, device, CausticSettings(caustic_flow=True))
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    inner = np.arange(W) >= 6
    for t in range(14):
        truth = caustic_pattern(shift=2.0 * t)
        e = poisson_map(rng, truth, 2.0)
        res = run_frame(den, g, e, out, None, uniform_flow((2.0, 0.0)) if t else np.zeros((H, W, 4), np.float32))
        integrated = den.integrated.numpy().reshape(H, W, 3)
        np.testing.assert_allclose(res.reshape(-1, 3).sum(0), integrated.reshape(-1, 3).sum(0), rtol=1e-5)
    np.testing.assert_allclose(integrated[:, inner, 1].sum(), truth[:, inner].sum(), rtol=0.03)


def test_caustic_flow_disocclusion_resets(device):
    """Where the caustic flow points at another surface (a box in front of the plane) or off the image, the
    history is not fetched (depth/normal tests as for the surface's motion): those pixels restart at one frame,
    the others keep theirs (up to the cap along the flow)."""
    rng = np.random.default_rng(5)
    g = plane(hole=False)
    g["depth"][8:16, 10:20] = 1.2  # a box: 2-3 m plane around it
    den = CausticDenoiser(W, H, device, CausticSettings(caustic_flow=True))
    out = wp.zeros(W * H, dtype=wp.vec3, device=device)
    truth = caustic_pattern()
    for _ in range(6):
        run_frame(den, g, poisson_map(rng, truth, 0.5), out)
    flow = uniform_flow((-3.0, 0.0), count=6.0, s2=0.01)  # the caustic came from 3 pixels to the right
    run_frame(den, g, poisson_map(rng, caustic_pattern(shift=-3.0), 0.5), out, None, flow)
    n = history(den)
    into_box = np.zeros((H, W), bool)
    into_box[8:16, 7:10] = True  # plane pixels whose history would lie on the box
    off_image = np.zeros((H, W), bool)
    off_image[:, W - 3:] = True
    np.testing.assert_allclose(n[into_box], 1.0, rtol=1e-6)
    np.testing.assert_allclose(n[off_image & ~into_box], 1.0, rtol=1e-6)
    rest = ~into_box & ~off_image
    rest[8:16, 10:23] = False  # the box itself and the plane whose history lay on the box
    assert np.median(n[rest]) == pytest.approx(3.0)  # kept, at the cap along the flow (flow_history 2: α = 1/3)


def test_caustic_with_flow_matches_naive_twin(device):
    """Three frames with a caustic flow (significant in part of the image, pointing onto a box's depth edge and off
    the image in places) and camera motion elsewhere, against the float64 twin."""
    rng = np.random.default_rng(29)
    w, h = 35, 21
    s = CausticSettings(caustic_flow=True, atrous_levels=3, noise_target=0.1)
    den = CausticDenoiser(w, h, device, s)
    out = wp.zeros(w * h, dtype=wp.vec3, device=device)
    hist = None
    for t in range(3):
        truth = caustic_pattern(w, h, shift=1.7 * t)
        g = plane(w, h)
        g["depth"][4:9, 6:11] = 1.2
        g["motion"][:] = (0.3 * (t > 0), -0.2 * (t > 0))
        flow = uniform_flow((1.7, 0.0), h, w, count=3.0, s2=0.05)
        flow[:, : w // 3, :] = 0.0  # no photons: the surface's motion there
        flow[h // 2:, :, 2] = 100.0  # too uncertain: the surface's motion too
        e = poisson_map(rng, truth, 4.0)
        e[g["depth"] <= 0] = 0.0
        res = run_frame(den, g, e, out, None, flow)
        ref, hist = caustic_frame_naive(e, g["depth"], g["normal"], g["motion"], hist, s, None, flow)
        np.testing.assert_allclose(history(den), hist["frames"], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(res, ref, rtol=1e-5, atol=1e-5 * truth.max())
    assert np.any(hist["frames"] > 2.5)


def _tiled_level(device, g, color, variance, step, gate, conserve=True):
    """One tiled level (:func:`launch_atrous`, unpacked input) and its float64 twin: (colour, Var) of each."""
    h, w = g["depth"].shape
    s = SVGFSettings(sigma_luminance=2.0, sigma_normal=32.0, conserve_energy=conserve)
    dev = upload(dict(depth=g["depth"], normal=g["normal"], irradiance=color), device)
    slope = wp.array(depth_slope_naive(g["depth"]).astype(np.float32).reshape(-1), dtype=wp.float32, device=device)
    var_in = wp.array(variance.astype(np.float32).reshape(-1), dtype=wp.float32, device=device)
    c_out = wp.full(w * h, wp.vec3(-7.0), dtype=wp.vec3, device=device)  # every pixel must be written
    v_out = wp.full(w * h, -7.0, dtype=wp.float32, device=device)
    scratch = [wp.zeros(w * h, dtype=wp.vec4, device=device) for _ in range(3)]
    launch_atrous(None, None, slope, w, h, step, s.sigma_depth, s.sigma_normal, s.sigma_luminance, conserve,
                  scratch[0], noise_target=gate, color_out=c_out, variance_out=v_out,
                  unpacked=(dev["irradiance"], var_in, dev["depth"], dev["normal"]), pack_into=scratch[1:])
    c_ref, v_ref = atrous_level_naive(color, variance, g["depth"], g["normal"], step, s.sigma_depth, s.sigma_normal,
                                      s.sigma_luminance, conserve, noise_target=gate)
    return c_out.numpy().reshape(h, w, 3), v_out.numpy().reshape(h, w), c_ref, v_ref


def _signal_region_frame(rng, w, h, signal):
    """A plane with a depth edge and a hole, a noisy photon-map-like colour and variance where ``signal`` (H, W
    bool), exactly 0 elsewhere (the walls no photon reaches)."""
    g = plane(w, h)
    g["depth"][4:14, 40:60] = 1.3  # a depth edge across the tile border at x = 32 .. 63 / 64
    color = rng.exponential(2.0, (h, w, 3)).astype(np.float32) * signal[..., None]
    variance = (rng.exponential(1.0, (h, w)) * signal).astype(np.float32)
    color[g["depth"] <= 0] = 0.0
    variance[g["depth"] <= 0] = 0.0
    return g, color, variance


@pytest.mark.parametrize("step,gate,conserve", [(1, None, True), (1, 0.1, True), (2, None, False), (4, None, True),
                                                (2, 0.1, True)])
def test_atrous_level_signal_free_blocks_match_naive_twin(device, step, gate, conserve):
    """Blocks whose tile and apron of 2 hold no signal (colour 0, Var 0) skip the pair weights and write their
    zeros: next to blocks with signal, across tile borders and sub-lattices, the output equals the twin; at step 1
    the first tile column (x < 32) has none, the second signal from x = 52 (its own pixels), the third all."""
    rng = np.random.default_rng(71 + step)
    w, h = 72, 20
    x = np.arange(w)[None, :].repeat(h, 0)
    signal = (x >= 52) | ((x >= 36) & (x < 40) & (np.arange(h)[:, None] > 9))
    g, color, variance = _signal_region_frame(rng, w, h, signal)
    c, v, c_ref, v_ref = _tiled_level(device, g, color, variance, step, gate, conserve)
    np.testing.assert_allclose(c, c_ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(v, v_ref, rtol=1e-5, atol=1e-7)
    far = 36 - 2 * step  # no tap of x < far reaches the signal
    assert np.all(c[:, :far] == 0.0) and np.all(v[:, :far] == 0.0)
    assert c[:, 32:].max() > 0.0


@pytest.mark.parametrize("gate", [None, 0.1])
def test_atrous_level_signal_in_the_apron_only_is_filtered(device, gate):
    """A tile (x < 32, step 1) whose only signal lies in its apron of 2 (x = 32, 33) is filtered: its pixels
    x = 30, 31 take that signal through their taps (a block skipped for a signal-free tile would leave them 0).
    (gated, x = 31: x = 30's gate is closed). Signal two pixels further (x = 34, 35: in the apron of 4 the weight
    sums read, not the taps') leaves the tile 0."""
    rng = np.random.default_rng(5)
    w, h = 72, 20
    x = np.arange(w)[None, :].repeat(h, 0)
    g, color, variance = _signal_region_frame(rng, w, h, (x == 32) | (x == 33))
    c, v, c_ref, v_ref = _tiled_level(device, g, color, variance, 1, gate)
    np.testing.assert_allclose(c, c_ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(v, v_ref, rtol=1e-5, atol=1e-7)
    first = 31 if gate else 30  # gated, x = 30's own 3x3 neighbourhood has no signal: R = 0, it keeps its 0
    assert c_ref[4:, first:32].min() > 0.0 and c[4:, first:32].min() > 0.0  # below the hole
    assert np.all(c[:, :30] == 0.0)
    g, color, variance = _signal_region_frame(rng, w, h, (x == 34) | (x == 35))
    c, v, c_ref, v_ref = _tiled_level(device, g, color, variance, 1, gate)
    np.testing.assert_allclose(c, c_ref, rtol=1e-5, atol=1e-6)
    assert np.all(c[:, :32] == 0.0) and np.all(c_ref[:, :32] == 0.0) and np.all(v[:, :32] == 0.0)


def test_atrous_level_signal_free_block_skips_its_weights(device):
    """The skip runs (on the CPU's one-lane blocks too): a NaN normal inside a signal-free tile (x < 32, step 1),
    more than 4 pixels from any other tile, would make that block's pair weights NaN and its zeros NaN
    (0 · NaN) if they were evaluated; skipped, the tile writes exact zeros, and the other tiles equal the twin."""
    rng = np.random.default_rng(9)
    w, h = 72, 20
    x = np.arange(w)[None, :].repeat(h, 0)
    g, color, variance = _signal_region_frame(rng, w, h, x >= 40)
    g["normal"][8, 12] = np.nan
    c, v, c_ref, v_ref = _tiled_level(device, g, color, variance, 1, None)
    assert np.all(c[:, :32] == 0.0) and np.all(v[:, :32] == 0.0)
    np.testing.assert_allclose(c[:, 32:], c_ref[:, 32:], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(v[:, 32:], v_ref[:, 32:], rtol=1e-5, atol=1e-7)


def _two_levels(device, g, color, variance, gate):
    """Levels of steps 1 and 2 chained as SVGF and the caustics denoiser chain them (packed); returns the second's
    packed output (H, W, 4), its public colour and Var and the twins' colour and Var."""
    h, w = g["depth"].shape
    s = SVGFSettings(sigma_luminance=2.0, sigma_normal=32.0)
    dev = upload(dict(depth=g["depth"], normal=g["normal"], irradiance=color), device)
    slope = wp.array(depth_slope_naive(g["depth"]).astype(np.float32).reshape(-1), dtype=wp.float32, device=device)
    var_in = wp.array(variance.astype(np.float32).reshape(-1), dtype=wp.float32, device=device)
    aux, packed, guide, mid = (wp.zeros(w * h, dtype=wp.vec4, device=device) for _ in range(4))
    out = wp.full(w * h, wp.vec4(-7.0), dtype=wp.vec4, device=device)
    c_out = wp.full(w * h, wp.vec3(-7.0), dtype=wp.vec3, device=device)
    v_out = wp.full(w * h, -7.0, dtype=wp.float32, device=device)
    launch_atrous(None, None, slope, w, h, 1, s.sigma_depth, s.sigma_normal, s.sigma_luminance, True, aux,
                  noise_target=gate, color_variance_out=mid, unpacked=(dev["irradiance"], var_in, dev["depth"],
                                                                       dev["normal"]),
                  pack_into=(packed, guide))
    launch_atrous(mid, guide, slope, w, h, 2, s.sigma_depth, s.sigma_normal, s.sigma_luminance, True, aux,
                  noise_target=gate, color_variance_out=out)
    launch_atrous(mid, guide, slope, w, h, 2, s.sigma_depth, s.sigma_normal, s.sigma_luminance, True, aux,
                  noise_target=gate, color_out=c_out, variance_out=v_out)
    c1, v1 = atrous_level_naive(color, variance, g["depth"], g["normal"], 1, s.sigma_depth, s.sigma_normal,
                                s.sigma_luminance, True, noise_target=gate)
    c2, v2 = atrous_level_naive(c1, v1, g["depth"], g["normal"], 2, s.sigma_depth, s.sigma_normal,
                                s.sigma_luminance, True, noise_target=gate)
    return out.numpy().reshape(h, w, 4), c_out.numpy().reshape(h, w, 3), v_out.numpy().reshape(h, w), c2, v2


@pytest.mark.parametrize("axis,gate", [(1, None), (0, None), (1, 0.1)])
def test_atrous_levels_chained_over_signal_free_blocks_match_naive_twin(device, axis, gate):
    """Two chained levels over signal-free blocks: the first level's second tile along ``axis`` (pixels 32-63 along
    1, 16-31 along 0) has no signal in its tile or apron (the input's starts at 66 / 34) and writes its zeros, its
    third tile spreads the signal to 64 / 32; a step-2 tile (pixels up to 63 / 31, apron up to 67 / 35) whose only
    signal is that spread is filtered: its last pixels take it, and the whole output equals the twin."""
    rng = np.random.default_rng(13 + axis)
    w, h = (100, 20) if axis == 1 else (40, 50)
    coord = np.indices((h, w))[axis]
    edge = 66 if axis == 1 else 34
    g, color, variance = _signal_region_frame(rng, w, h, coord >= edge)
    packed, c, v, c_ref, v_ref = _two_levels(device, g, color, variance, gate)
    np.testing.assert_allclose(c, c_ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(v, v_ref, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(packed[..., :3], c_ref, rtol=1e-5, atol=1e-6)
    last = (slice(None), slice(62, 64)) if axis == 1 else (slice(30, 32), slice(None))
    if gate is None:  # gated, those pixels' own gates are closed (their 3x3 neighbourhoods hold little signal)
        live = c_ref[last][(g["depth"][last] > 0)]
        assert live.max() > 0.0 and c[last][(g["depth"][last] > 0)].max() > 0.0


def test_pair_items_cover_the_pair_rows_and_spread_over_the_banks():
    """The pair phase's items in :func:`kernels_atrous.fill_weights`' order (``ODD_PITCH``, section 83; mirrored here
    in Python: the twin tests above check the kernel's values): every item of the pair rows once, and each 8 lanes'
    first points in 8 different 16-byte banks (``u`` mod 8), which with the even pitch's row-major items they are
    not (every other bank twice)."""
    from cisp_warp.denoise import kernels_atrous as ka

    def items(odd):
        pitch, runs = ka.GUIDE_X + (5 if odd else 4), ka.GUIDE_X // ka.RUN
        out = []
        for k in range(ka.PAIR_ROWS * runs):
            i, m = divmod(k, runs)
            if odd:
                pair_row, r = divmod(k, 2 * runs)
                i, m = 2 * pair_row + (r // 4) % 2, 4 * (r // 8) + r % 4
            out.append(i * pitch + 2 * m + 2)
        return pitch, out

    for odd in (False, True):
        pitch, us = items(odd)
        assert sorted(us) == sorted(i * pitch + 2 * m + 2 for i in range(ka.PAIR_ROWS) for m in range(ka.GUIDE_X // 2))
        groups = [len({u % 8 for u in us[g:g + 8]}) for g in range(0, len(us), 8)]
        assert (min(groups) == 8) == odd and max(groups) == (8 if odd else 4)
    assert ka.GUIDE_PITCH == ka.GUIDE_X + (5 if ka.ODD_PITCH else 4)
