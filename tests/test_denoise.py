"""Tests of the denoise pass: SVGF (constant, energy, disocclusion, motion, naive twin) and the Gaussian gather.

G-buffers are built by hand in numpy: a tilted plane (depth linear in x, one normal), optionally a
box in front of it and a corner with no surface. Sizes are tiny; generators are seeded.
"""

from dataclasses import fields, replace

import numpy as np
import pytest
import warp as wp

from cisp_warp.denoise import SVGF, GaussianGather, SVGFSettings, launch_atrous_level
from cisp_warp.denoise.naive import atrous_level_naive, depth_slope_naive

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


def run_frame(svgf, g_np, irradiance, out):
    g = upload(dict(g_np, irradiance=irradiance.astype(np.float32)), svgf.device)
    svgf.denoise(g["irradiance"], g["depth"], g["normal"], g["motion"], g["tri_id"], out)
    return out.numpy().reshape(svgf.height, svgf.width, 3)


def history(svgf):
    return svgf.history_length.numpy().reshape(svgf.height, svgf.width)


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
    weight_sum = wp.zeros(w * h, dtype=wp.float32, device=device)
    c_out = wp.zeros(w * h, dtype=wp.vec3, device=device)
    v_out = wp.zeros(w * h, dtype=wp.float32, device=device)
    launch_atrous_level(dev["irradiance"], var_in, dev["depth"], dev["normal"], slope, w, h, step, s.sigma_depth,
                        s.sigma_normal, s.sigma_luminance, conserve, guide_a, guide_b, weight_sum, c_out, v_out,
                        noise_target=gate)
    c_ref, v_ref = atrous_level_naive(color, variance, g["depth"], g["normal"], step,
                                      s.sigma_depth, s.sigma_normal, s.sigma_luminance, conserve, noise_target=gate)
    if gate is not None:  # the gate really splits the image: some pixels kept, some filtered
        radius = guide_b.numpy()[:, 3].reshape(h, w)[g["depth"] > 0]
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
