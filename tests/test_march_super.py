"""The composite's three-level bounded march (``march.screen_march_super_plain``: super cells of BOUNDS_SUPER texels
above the coarse and fine cells, ``march.super_bounds``; docs/perf_notes.md section 72) against the naive march:
the same status, end point and step count, bit for bit on the CPU; and its super cells' bounds against numpy."""

import numpy as np
import pytest
import warp as wp

from cisp_warp.photons.cisp import build_bounds
from cisp_warp.photons.march import (BOUNDS_COARSE, BOUNDS_SUPER, WORK_TESTS, bounds_shape, bounds_size,
                                     counted_marches, counted_super_march, screen_march_bounded_plain,
                                     screen_march_naive_plain, screen_march_super_plain, super_bounds, super_shape)
from cisp_warp.raster.views import View, ViewParams

from test_march import compare, random_depth

_counted_bounded = counted_marches(False)[2]
_counted_super = counted_super_march()


@wp.kernel
def march_super(view: ViewParams, depth: wp.array(dtype=wp.float32), origins: wp.array(dtype=wp.vec3),
                dirs: wp.array(dtype=wp.vec3), max_steps: int, bounds: wp.array(dtype=wp.vec2),
                supers: wp.array(dtype=wp.vec2), fast: wp.array(dtype=wp.vec3), bounded: wp.array(dtype=wp.vec3),
                naive: wp.array(dtype=wp.vec3), work: wp.array(dtype=wp.vec2i)):
    i = wp.tid()
    s, t, n = screen_march_super_plain(view, depth, bounds, supers, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    fast[i] = wp.vec3(float(s), t, float(n))
    s, t, n = screen_march_bounded_plain(view, depth, bounds, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    bounded[i] = wp.vec3(float(s), t, float(n))
    s, t, n = screen_march_naive_plain(view, depth, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    naive[i] = wp.vec3(float(s), t, float(n))
    s2, t2, w2 = _counted_bounded(view, depth, bounds, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    s3, t3, w3 = _counted_super(view, depth, bounds, supers, origins[i], dirs[i], 50.0, max_steps, 0.02, 0.02)
    work[i] = wp.vec2i(w2, w3)


def _rays(rng, view, w, h, n, orthographic):
    """Origins in front of the surfaces, inside the view; directions mostly away from the eye, some towards it."""
    px, py = rng.uniform(0, w, n), rng.uniform(0, h, n)
    z = rng.uniform(0.5, 3.0, n)
    if orthographic:
        o = np.stack([(px - w / 2) / view.fx, -(py - h / 2) / view.fy, -z], 1)
    else:
        o = np.stack([(px - w / 2) / view.fx * z, -(py - h / 2) / view.fy * z, -z], 1)
    d = rng.normal(size=(n, 3))
    d[:, 2] = -np.abs(d[:, 2]) * rng.choice([1.0, -0.3], n, p=[0.85, 0.15])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d


@pytest.mark.parametrize("orthographic", [False, True], ids=["perspective", "orthographic"])
@pytest.mark.parametrize("max_steps", [2048, 40], ids=["steps2048", "steps40"])
def test_super_march_equals_the_naive_march(device, rng, orthographic, max_steps):
    """Every ray ends where the naive march ends it (status, end point, steps), through a depth buffer of several
    super cells that is not a multiple of any cell, with holes; and the super level does skip: fewer cell tests and
    steps in all than the two-level march on rays that cross a clear region."""
    w, h, n = 300, 200, 3000
    f = 40.0 if orthographic else 160.0
    view = View(np.eye(4), w, h, near=0.1, far=100.0, fx=f, fy=f, orthographic=orthographic)
    o, d = _rays(rng, view, w, h, n, orthographic)
    front = random_depth(rng, w, h)
    front[: w * 60] = np.where(front[: w * 60] > 0.0, 40.0, 0.0)  # a far band with holes: the super cells' proofs
    depth = wp.array(front, device=device)
    bounds = wp.zeros(bounds_size(w, h), dtype=wp.vec2, device=device)
    build_bounds(depth, w, h, 0.02, 0.02, bounds, device)
    sx, sy = super_shape(w, h)
    supers = wp.zeros(sx * sy, dtype=wp.vec2, device=device)
    wp.launch(super_bounds, dim=sx * sy, device=device, inputs=[bounds, w, h, supers])
    args = [wp.array(a.astype(np.float32), dtype=wp.vec3, device=device) for a in (o, d)]
    fast, bounded, naive = (wp.zeros(n, dtype=wp.vec3, device=device) for _ in range(3))
    work = wp.zeros(n, dtype=wp.vec2i, device=device)
    wp.launch(march_super, dim=n, device=device,
              inputs=[view.params(), depth, *args, max_steps, bounds, supers, fast, bounded, naive, work])
    v = naive.numpy()
    assert (v[:, 0] == 2).sum() > (10 if max_steps == 40 else -1)  # rays cut short by max_steps too
    compare(fast.numpy(), v, device, max_steps)
    compare(bounded.numpy(), v, device, max_steps)
    if max_steps > 7:
        wk = work.numpy().astype(np.int64)
        cost = wk // WORK_TESTS + wk % WORK_TESTS  # cell tests + pixel steps
        assert cost[:, 1].sum() < 0.9 * cost[:, 0].sum(), cost.sum(0)


def test_super_bounds_are_the_coarse_cells_min_and_max(device, rng):
    """A super cell holds the nearest and farthest bound of the coarse cells it covers, edges included."""
    w, h = 300, 200
    depth = wp.array(random_depth(rng, w, h), device=device)
    bounds = wp.zeros(bounds_size(w, h), dtype=wp.vec2, device=device)
    build_bounds(depth, w, h, 0.02, 0.02, bounds, device)
    sx, sy = super_shape(w, h)
    supers = wp.zeros(sx * sy, dtype=wp.vec2, device=device)
    wp.launch(super_bounds, dim=sx * sy, device=device, inputs=[bounds, w, h, supers])
    fx, fy = bounds_shape(w, h, 8)
    cx, cy = bounds_shape(w, h, BOUNDS_COARSE)
    coarse = bounds.numpy()[fx * fy:].reshape(cy, cx, 2)
    r = BOUNDS_SUPER // int(BOUNDS_COARSE)
    got = supers.numpy().reshape(sy, sx, 2)
    for j in range(sy):
        for i in range(sx):
            blk = coarse[j * r:(j + 1) * r, i * r:(i + 1) * r]
            assert got[j, i, 0] == blk[..., 0].min() and got[j, i, 1] == blk[..., 1].max(), (i, j)
    assert (sx, sy) == (3, 2)


def test_the_composite_is_the_same_without_the_super_cells_proofs(monkeypatch):
    """The pool's composite (one-stream ``composite`` and concurrent ``composite_march``) with the frame's super
    bounds and with super bounds that prove nothing (every super cell (0, BIG_DEPTH): the two-level march plus a
    failing test): every output bit for bit, with reflected rays found, missed and handed on."""
    from cisp_warp import shade
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.usd import load_usd

    from cisp_warp.raster.kernels import BIG_DEPTH

    scene = load_usd("scenes_usd/pool.usda", width=320, height=180)  # 3 x 2 super cells
    r = Renderer(scene, RenderSettings(rsm_size=64, method="cisp", denoiser="svgf", hidden_rays="both",
                                       photons=PhotonSettings(photons=2000, seed=3)), device="cpu")
    launch = wp.launch
    checked = []

    def both(kernel, dim, inputs=(), **kw):
        if kernel not in shade.composite_kernels(bool(r.view.orthographic)):
            return launch(kernel, dim, inputs=inputs, **kw)
        inputs = list(inputs)
        k = [a.label for a in kernel.adj.args].index("super_bounds")
        assert inputs[k] is r.super_bounds
        idx = [i for i, a in enumerate(inputs) if isinstance(a, wp.array)]
        before = {i: inputs[i].numpy().copy() for i in idx}
        launch(kernel, dim, inputs=inputs, **kw)
        fast = {i: inputs[i].numpy().copy() for i in idx}
        for i in idx:
            inputs[i].assign(before[i])
        inputs[k] = wp.array(np.tile(np.float32([0.0, BIG_DEPTH]), (r.super_bounds.shape[0], 1)), dtype=wp.vec2,
                             device="cpu")
        launch(kernel, dim, inputs=inputs, **kw)
        for i in idx:
            if i != k:
                assert inputs[i].numpy().tobytes() == fast[i].tobytes(), (kernel.key, kernel.adj.args[i].label)
                inputs[i].assign(fast[i])
        missed = fast[[a.label for a in kernel.adj.args].index("missed")]
        checked.append((kernel.key, int(np.count_nonzero(missed & shade.MISSED_REFLECTED))))

    monkeypatch.setattr(wp, "launch", both)
    for concurrent in (False, True):
        r.set_concurrent(concurrent)
        r.render_frame()
    assert len(checked) == 2 and all(m > 0 for _, m in checked), checked
    assert r.super_bounds.numpy()[:, 0].min() > 0.0  # built: the nearest surface of every super cell, none empty
