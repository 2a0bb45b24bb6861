"""The screen-space march that reads several depth samples ahead (``screen_march``) against its one step at a time
twin (``screen_march_naive``): the same status, end point and step count for random rays through random depth
buffers, perspective and orthographic."""

import numpy as np
import pytest
import warp as wp

from cisp_warp.photons.cisp import build_bounds
from cisp_warp.photons.march import (WORK_TESTS, _cell_skipped, _ray_depth, bounded_march, bounds_size, counted_marches,
                                     screen_march,
                                     screen_march_bounded, screen_march_bounded_partial,
                                     screen_march_bounded_partial_plain, screen_march_bounded_plain,
                                     screen_march_naive, screen_march_naive_plain, screen_march_plain)
from cisp_warp.raster.views import View, ViewParams


@wp.kernel
def march_both(view: ViewParams, depth: wp.array(dtype=wp.float32), origins: wp.array(dtype=wp.vec3),
               dirs: wp.array(dtype=wp.vec3), max_steps: int,
               bounds: wp.array(dtype=wp.vec2), fast: wp.array(dtype=wp.vec3), bounded: wp.array(dtype=wp.vec3),
               naive: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    s, t, n = screen_march(view, depth, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    fast[i] = wp.vec3(float(s), t, float(n))
    s, t, n = screen_march_bounded(view, depth, bounds, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    bounded[i] = wp.vec3(float(s), t, float(n))
    s, t, n = screen_march_naive(view, depth, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    naive[i] = wp.vec3(float(s), t, float(n))


@wp.kernel
def march_plain(view: ViewParams, depth: wp.array(dtype=wp.float32), origins: wp.array(dtype=wp.vec3),
                dirs: wp.array(dtype=wp.vec3), max_steps: int,
                bounds: wp.array(dtype=wp.vec2), fast: wp.array(dtype=wp.vec3), bounded: wp.array(dtype=wp.vec3),
                naive: wp.array(dtype=wp.vec3)):
    """The marches compiled for a plain depth buffer (no back-face layer code)."""
    i = wp.tid()
    s, t, n = screen_march_plain(view, depth, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    fast[i] = wp.vec3(float(s), t, float(n))
    s, t, n = screen_march_bounded_plain(view, depth, bounds, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    bounded[i] = wp.vec3(float(s), t, float(n))
    s, t, n = screen_march_naive_plain(view, depth, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    naive[i] = wp.vec3(float(s), t, float(n))


def random_depth(rng, w, h):
    """Planes at random depths and slopes, with holes (0 = no surface) and thin slabs: hits, misses, passes behind."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    z = 4.0 + 0.01 * x + 0.005 * y
    for _ in range(6):
        x0, y0 = rng.integers(0, w), rng.integers(0, h)
        rw, rh = rng.integers(2, w // 2), rng.integers(2, h // 2)
        z[y0:y0 + rh, x0:x0 + rw] = rng.uniform(1.0, 6.0) + rng.uniform(-0.02, 0.02) * x[y0:y0 + rh, x0:x0 + rw]
    z[rng.random((h, w)) < 0.02] = 0.0
    return z.reshape(-1)


def back_layer(rng, front):
    """A back-face layer behind ``front`` (``GBuffer.depth_layers``' second half): on most pixels a back face from a
    hair (below the least thickness ``surface_far`` keeps) to 0.2 m behind, on the rest none (0)."""
    back = front + rng.choice([1e-4, 0.005, 0.03, 0.2], front.size) * rng.random(front.size)
    back[(rng.random(front.size) < 0.3) | (front <= 0.0)] = 0.0
    return back.astype(np.float32)


@pytest.mark.parametrize("orthographic", [False, True], ids=["perspective", "orthographic"])
@pytest.mark.parametrize("max_steps", [2048, 7], ids=["steps2048", "steps7"])
@pytest.mark.parametrize("layers", [1, 2], ids=["front", "back_layer"])
def test_fast_marches_equal_the_naive_march(device, rng, orthographic, max_steps, layers):
    """The batched march and the march that skips cells by their depth bounds end every ray where the naive
    march ends it: same status, end point and step count; with a back-face layer behind the depth too (its bounds
    built from the front depths and the constant thickness)."""
    w, h, n = 150, 100, 2000  # not multiples of the cells
    view = View(np.eye(4), w, h, near=0.1, far=100.0, fx=20.0 if orthographic else 80.0,
                fy=20.0 if orthographic else 80.0, orthographic=orthographic)
    # origins in front of the surfaces, inside the view; directions mostly away from the eye (-z), some towards it
    px, py = rng.uniform(0, w, n), rng.uniform(0, h, n)
    z = rng.uniform(0.5, 3.0, n)
    if orthographic:
        o = np.stack([(px - w / 2) / view.fx, -(py - h / 2) / view.fy, -z], 1)
    else:
        o = np.stack([(px - w / 2) / view.fx * z, -(py - h / 2) / view.fy * z, -z], 1)
    d = rng.normal(size=(n, 3))
    d[:, 2] = -np.abs(d[:, 2]) * rng.choice([1.0, -0.3], n, p=[0.85, 0.15])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    args = [wp.array(a.astype(np.float32), dtype=wp.vec3, device=device) for a in (o, d)]
    fast, bounded, naive = (wp.zeros(n, dtype=wp.vec3, device=device) for _ in range(3))
    front = random_depth(rng, w, h)
    depth = wp.array(front if layers == 1 else np.concatenate([front, back_layer(rng, front)]), device=device)
    bounds = wp.zeros(bounds_size(w, h), dtype=wp.vec2, device=device)
    build_bounds(depth, w, h, 0.02, 0.02, bounds, device)
    wp.launch(march_both, dim=n, device=device,
              inputs=[view.params(), depth, *args, max_steps, bounds, fast, bounded, naive])
    v = naive.numpy()
    for f in (fast.numpy(), bounded.numpy()):
        compare(f, v, device, max_steps)
    if layers == 1:
        # the marches compiled without the layer's code: the same as the general ones on a plain buffer, bit for bit
        # (one body, the layer's code dropped at compile time), and their fast twins equal their naive one
        plain = [wp.zeros(n, dtype=wp.vec3, device=device) for _ in range(3)]
        wp.launch(march_plain, dim=n, device=device, inputs=[view.params(), depth, *args, max_steps, bounds, *plain])
        plain = [a.numpy() for a in plain]
        for f in plain[:2]:
            compare(f, plain[2], device, max_steps)
        if wp.get_device(device).is_cpu:
            for f, g in zip(plain, (fast.numpy(), bounded.numpy(), v)):
                np.testing.assert_array_equal(f, g)
    if layers == 2:
        # the layer only brings surfaces' far sides nearer: a ray that hits with it hits without it, no later; and
        # some rays end in an object's hidden half instead (MARCH_HIDDEN), or hit later (they passed behind a thin one)
        f1 = wp.zeros(n, dtype=wp.vec3, device=device)
        wp.launch(march_both, dim=n, device=device, inputs=[view.params(), wp.array(front, device=device), *args,
                                                           max_steps, bounds, f1, f1, f1])
        v1 = f1.numpy()
        hit = v[:, 0] == 0
        assert np.all(v1[hit, 0] == 0) and np.all(v1[hit, 2] <= v[hit, 2])
        assert (v[:, 0] == 3).sum() >= (10 if max_steps > 7 else 1)
        assert (v1[:, 0] == 3).sum() == 0  # never without a back-face layer


def compare(f, v, device, max_steps):
    for status in range(3):  # hit, exit and (with 7 steps) out-of-steps all occur (and hidden with a back layer)
        assert (v[:, 0] == status).sum() > (10 if status != 2 or max_steps == 7 else -1)
    if wp.get_device(device).is_cpu:
        np.testing.assert_array_equal(f, v)
    else:  # CUDA may contract the two code shapes' multiply-adds differently: a crossing can move by a rounding
        same = (f[:, 0] == v[:, 0]) & (f[:, 2] == v[:, 2])
        assert same.mean() > 0.999
        np.testing.assert_allclose(f[same, 1], v[same, 1], rtol=1e-5, atol=1e-6)


def test_bounds_of_an_inactive_view_are_kept(device, rng):
    """``build_bounds`` with the view array: an active view gets the bounds built without it; an inactive one
    (``far`` = 0, a fitted cascade that emits nothing this frame) returns at once and keeps the old bounds."""
    w, h = 70, 45
    depth = wp.array(random_depth(rng, w, h), device=device)
    want = wp.zeros(bounds_size(w, h), dtype=wp.vec2, device=device)
    build_bounds(depth, w, h, 0.02, 0.02, want, device)
    views = [View(np.eye(4), w, h, near=0.1, far=far, fx=50.0, fy=50.0).params() for far in (100.0, 0.0)]
    views = wp.array(views, dtype=ViewParams, device=device)
    got = wp.zeros(bounds_size(w, h), dtype=wp.vec2, device=device)
    build_bounds(depth, w, h, 0.02, 0.02, got, device, views, 0)
    np.testing.assert_array_equal(got.numpy(), want.numpy())
    stale = np.full((bounds_size(w, h), 2), 7.0, np.float32)
    got.assign(stale)
    build_bounds(depth, w, h, 0.02, 0.02, got, device, views, 1)
    np.testing.assert_array_equal(got.numpy(), stale)


@wp.kernel
def march_points(view: ViewParams, depth: wp.array(dtype=wp.float32), origins: wp.array(dtype=wp.vec3),
                 dirs: wp.array(dtype=wp.vec3), bounds: wp.array(dtype=wp.vec2), out: wp.array(dtype=wp.vec4),
                 twin: wp.array(dtype=wp.vec2)):
    i = wp.tid()
    s, t, n = screen_march_bounded(view, depth, bounds, origins[i], dirs[i], 50.0, 2048, 0.02, 0.02)
    p = origins[i] + dirs[i] * t
    out[i] = wp.vec4(p[0], p[1], p[2], float(s))
    s2, t2, n2 = screen_march_naive(view, depth, origins[i], dirs[i], 50.0, 2048, 0.02, 0.02)
    twin[i] = wp.vec2(float(s2), t2)  # the naive twin's status and distance


@pytest.mark.parametrize("orthographic", [False, True], ids=["perspective", "orthographic"])
def test_crossing_lies_on_a_plane_of_constant_depth(device, rng, orthographic):
    """Rays near the view axis advance far in depth over one step; their crossing with a plane of constant depth
    (a floor under a spot light) must lie on it. Eq. 2 in linear depth put a perspective view's crossings short of
    the plane (a ray from depth 0.5 over one step to 50 ended near depth 0.52 instead of 2); in 1/depth, where the
    ray's depth is affine in screen space, they lie on it to rounding."""
    w = h = 64
    view = View(np.eye(4), w, h, near=0.1, far=100.0, fx=64.0 if not orthographic else 16.0,
                fy=64.0 if not orthographic else 16.0, orthographic=orthographic)
    n = 500
    z0 = rng.uniform(0.3, 1.5, n)
    lateral = rng.uniform(-0.2, 0.2, (n, 2))  # directions within ~11° of the axis: a few pixels or less
    o = np.stack([rng.uniform(-0.1, 0.1, n), rng.uniform(-0.1, 0.1, n), -z0], 1)
    d = np.concatenate([lateral, -np.ones((n, 1))], 1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    depth = wp.array(np.full(w * h, 2.0, np.float32), device=device)
    bounds = wp.zeros(bounds_size(w, h), dtype=wp.vec2, device=device)
    build_bounds(depth, w, h, 0.02, 0.02, bounds, device)
    out = wp.zeros(n, dtype=wp.vec4, device=device)
    twin = wp.zeros(n, dtype=wp.vec2, device=device)
    origins = wp.array(o.astype(np.float32), dtype=wp.vec3, device=device)
    wp.launch(march_points, dim=n, device=device, inputs=[view.params(), depth, origins,
              wp.array(d.astype(np.float32), dtype=wp.vec3, device=device), bounds, out, twin])
    r, tw = out.numpy(), twin.numpy()
    # the bounded march against its naive twin: bit for bit on the CPU; on CUDA the same statuses, the distances to
    # a rounding (the two code shapes' multiply-adds may be contracted differently, as in compare above)
    assert np.array_equal(r[:, 3], tw[:, 0])
    t = np.linalg.norm(r[:, :3] - o.astype(np.float32), axis=1)
    if wp.get_device(device).is_cpu:
        want = o.astype(np.float32) + d.astype(np.float32) * tw[:, 1:2]
        np.testing.assert_array_equal(r[:, :3], want.astype(np.float32))
    else:
        np.testing.assert_allclose(t, tw[:, 1], rtol=1e-5, atol=1e-6)
    hit = r[:, 3] == 0
    assert hit.mean() > 0.95
    np.testing.assert_allclose(-r[hit, 2], 2.0, atol=2e-4)


@wp.kernel
def cell_tests(z: wp.array(dtype=wp.vec2), s: wp.array(dtype=wp.vec2), b: wp.array(dtype=wp.vec2),
               out: wp.array(dtype=wp.vec2i)):
    i = wp.tid()
    z0 = z[i][0]
    z1 = z[i][1]
    k0 = 1.0 / z0  # as _screen_segment's perspective reciprocals
    k1 = 1.0 / z1
    # the depths the marches step with: z0 at the segment's start, _ray_depth after it
    za = wp.where(s[i][0] == 0.0, z0, _ray_depth(0, z0, z1, k0, k1, s[i][0]))
    zb = _ray_depth(0, z0, z1, k0, k1, s[i][1])
    depth_skip = wp.max(za, zb) < b[i][0] or wp.min(za, zb) > b[i][1]
    out[i] = wp.vec2i(int(_cell_skipped(0, z0, z1, k0, k1, s[i][0], s[i][1], b[i])), int(depth_skip))


def test_perspective_cell_skip_is_a_proof(device, rng):
    """``_cell_skipped`` tests a perspective view's cells in inverse depth, without the ray's divisions: every skip
    it allows, the depth test on the depths the march steps with allows too (the march then ends where the naive one
    does), also for bounds a few ulps from the ray's depth at either end, where a product test without its margin
    skips wrongly; and it still skips where the depths clear the bounds by more than 1e-5."""
    n = 200000
    z0 = rng.uniform(0.2, 40.0, n).astype(np.float32)
    z1 = np.where(rng.random(n) < 0.5, z0 * rng.uniform(0.02, 1.0, n), z0 * rng.uniform(1.0, 50.0, n)).astype(np.float32)
    s_prev = np.where(rng.random(n) < 0.2, 0.0, rng.uniform(0.0, 1.0, n)).astype(np.float32)
    s_last = np.minimum(s_prev + rng.uniform(0.0, 0.3, n), 1.0).astype(np.float32)
    k0, k1 = np.float32(1.0) / z0, np.float32(1.0) / z1
    za = np.where(s_prev == 0.0, z0, np.float32(1.0) / (k0 + (k1 - k0) * s_prev)).astype(np.float32)
    zb = (np.float32(1.0) / (k0 + (k1 - k0) * s_last)).astype(np.float32)
    lo, hi = np.minimum(za, zb), np.maximum(za, zb)
    # bounds within 8 ulps of the ray's depth at its nearer or farther end, or anywhere near it
    ulps = rng.integers(-8, 9, (n, 2)).astype(np.float32) * np.float32(2.0 ** -23)
    near = np.where(rng.random(n) < 0.5, hi * (1 + ulps[:, 0]), hi * rng.uniform(0.5, 1.5, n)).astype(np.float32)
    far = np.where(rng.random(n) < 0.5, lo * (1 + ulps[:, 1]), lo * rng.uniform(0.5, 1.5, n)).astype(np.float32)
    near, far = np.where(rng.random(n) < 0.5, near, np.float32(0.0)), np.where(rng.random(n) < 0.5, far, np.float32(1e30))
    b = np.stack([near, far], 1).astype(np.float32)
    out = wp.zeros(n, dtype=wp.vec2i, device=device)
    wp.launch(cell_tests, dim=n, device=device, inputs=[wp.array(np.stack([z0, z1], 1), dtype=wp.vec2, device=device),
              wp.array(np.stack([s_prev, s_last], 1), dtype=wp.vec2, device=device),
              wp.array(b, dtype=wp.vec2, device=device), out])
    skip, depth_skip = out.numpy().T.astype(bool)
    assert depth_skip.sum() > n // 10 and skip.sum() > n // 10
    assert not np.any(skip & ~depth_skip), "a cell skipped that the depth test does not prove hitless"
    clear = (hi < near * (1 - 1e-5)) | (lo > far * (1 + 1e-5))
    assert clear.sum() > n // 20 and np.all(skip[clear])
    # the cases are sharp: a product test without the margin would skip unproven cells among them (float32, numpy)
    w = [(k0 + (k1 - k0) * s).astype(np.float32) for s in (s_prev, s_last)]
    bare = ((near * np.minimum(*w)).astype(np.float32) > 1) | ((far * np.maximum(*w)).astype(np.float32) < 1)
    assert np.any(bare & ~depth_skip)


_counted_bounded = counted_marches(False)[2]
_counted_partial = counted_marches(False, 2)[2]
_partial_fine_plain = bounded_march(False, 1)  # the fine cells' prefixes only
_partial_pair_plain = bounded_march(False, 3)  # with the 2x2 coarse cells' level


@wp.kernel
def march_partial(view: ViewParams, depth: wp.array(dtype=wp.float32), origins: wp.array(dtype=wp.vec3),
                  dirs: wp.array(dtype=wp.vec3), max_steps: int, bounds: wp.array(dtype=wp.vec2),
                  layered: wp.array(dtype=wp.vec3), plain: wp.array(dtype=wp.vec3), fine: wp.array(dtype=wp.vec3),
                  pair: wp.array(dtype=wp.vec3), work: wp.array(dtype=wp.vec4)):
    """The bounded marches that skip the failed cells' proven prefixes (general and plain; the plain one with the fine
    cells' prefixes only), and the counted plain marches' work without and with them."""
    i = wp.tid()
    s, t, n = screen_march_bounded_partial(view, depth, bounds, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    layered[i] = wp.vec3(float(s), t, float(n))
    s, t, n = screen_march_bounded_partial_plain(view, depth, bounds, origins[i], dirs[i], 50.0, max_steps, 0.02,
                                                 0.02)
    plain[i] = wp.vec3(float(s), t, float(n))
    s, t, n = _partial_fine_plain(view, depth, bounds, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    fine[i] = wp.vec3(float(s), t, float(n))
    s, t, n = _partial_pair_plain(view, depth, bounds, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    pair[i] = wp.vec3(float(s), t, float(n))
    s, t, w0 = _counted_bounded(view, depth, bounds, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    s, t, w1 = _counted_partial(view, depth, bounds, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    work[i] = wp.vec4(float(w0 / WORK_TESTS), float(w0 % WORK_TESTS), float(w1 / WORK_TESTS), float(w1 % WORK_TESTS))


@pytest.mark.parametrize("orthographic", [False, True], ids=["perspective", "orthographic"])
@pytest.mark.parametrize("max_steps", [2048, 7], ids=["steps2048", "steps7"])
@pytest.mark.parametrize("layers", [1, 2], ids=["front", "back_layer"])
def test_partial_skips_equal_the_naive_march(device, rng, orthographic, max_steps, layers):
    """The bounded march that also skips the proven prefix of a cell whose test failed (``partial``,
    docs/perf_notes.md section 74) ends every ray where the naive march ends it (status, end point, step count; bit
    for bit on the CPU), with and without a back-face layer; and it walks fewer pixel steps than the bounded march
    (the prefixes are skipped, not only proven)."""
    w, h, n = 150, 100, 2000
    view = View(np.eye(4), w, h, near=0.1, far=100.0, fx=20.0 if orthographic else 80.0,
                fy=20.0 if orthographic else 80.0, orthographic=orthographic)
    px, py = rng.uniform(0, w, n), rng.uniform(0, h, n)
    z = rng.uniform(0.5, 3.0, n)
    if orthographic:
        o = np.stack([(px - w / 2) / view.fx, -(py - h / 2) / view.fy, -z], 1)
    else:
        o = np.stack([(px - w / 2) / view.fx * z, -(py - h / 2) / view.fy * z, -z], 1)
    d = rng.normal(size=(n, 3))
    d[:, 2] = -np.abs(d[:, 2]) * rng.choice([1.0, -0.3], n, p=[0.85, 0.15])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    args = [wp.array(a.astype(np.float32), dtype=wp.vec3, device=device) for a in (o, d)]
    front = random_depth(rng, w, h)
    depth = wp.array(front if layers == 1 else np.concatenate([front, back_layer(rng, front)]), device=device)
    bounds = wp.zeros(bounds_size(w, h), dtype=wp.vec2, device=device)
    build_bounds(depth, w, h, 0.02, 0.02, bounds, device)
    naive, bounded = (wp.zeros(n, dtype=wp.vec3, device=device) for _ in range(2))
    wp.launch(march_both, dim=n, device=device,
              inputs=[view.params(), depth, *args, max_steps, bounds, naive, bounded, naive])
    layered, plain, fine, pair = (wp.zeros(n, dtype=wp.vec3, device=device) for _ in range(4))
    work = wp.zeros(n, dtype=wp.vec4, device=device)
    wp.launch(march_partial, dim=n, device=device,
              inputs=[view.params(), depth, *args, max_steps, bounds, layered, plain, fine, pair, work])
    v = naive.numpy()
    compare(layered.numpy(), v, device, max_steps)
    if layers == 1:  # the plain march on a plain buffer
        compare(plain.numpy(), v, device, max_steps)
        compare(fine.numpy(), v, device, max_steps)
        compare(pair.numpy(), v, device, max_steps)
    c = work.numpy()
    # pixel steps: never more, and fewer over the rays (the prefixes' steps are what it saves)
    assert np.all(c[:, 3] <= c[:, 1])
    assert c[:, 3].sum() < (0.97 if max_steps > 7 else 1.0) * c[:, 1].sum()
