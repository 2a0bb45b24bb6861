"""The hidden rays' trace strided (``shade_hidden.strided_hidden``: a thread per ``PIXELS_PER_THREAD`` pixels, their
``missed`` words read together; docs/perf_notes.md section 67) against the per-pixel kernels compiled for the same
projection (``projected_hidden``), its twins, and likewise ``hidden_direct_strided`` / ``hidden_caustic_strided``
against ``hidden_direct`` / ``hidden_caustic``: every such launch a pool frame makes replayed on the same inputs, bit for
bit, for a perspective and an orthographic camera and both programs, on an image whose pixel count is not a multiple
of ``PIXELS_PER_THREAD`` (the last thread's pixels past the image must be left alone); the pool's own view (its
water in the middle rows: the first and last slices of pixels have no rays) and one narrowed to its water (rays in
every slice, the last thread's included)."""

import math
from dataclasses import replace

import numpy as np
import pytest
import warp as wp

from cisp_warp import shade_hidden
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.usd import load_usd


def _pool(camera: str) -> Renderer:
    scene = load_usd("scenes_usd/pool.usda", width=47, height=27)
    if camera == "narrow":  # the pool's view narrowed to its water: every thread's every pixel has rays to trace
        scene.camera = replace(scene.camera, fov_y=scene.camera.fov_y / 6.0)
    if camera == "orthographic":  # the same pose, the extent the perspective view has at the distance of the world's origin
        c = scene.camera
        dist = float(np.linalg.norm(c.to_world[:3, 3]))
        scene.camera = replace(c, orthographic=True, ortho_height=2.0 * dist * math.tan(0.5 * c.fov_y))
    return Renderer(scene, RenderSettings(rsm_size=64, method="cisp", denoiser="svgf", hidden_rays="both",
                                          photons=PhotonSettings(photons=4000, seed=3)), device="cpu")


def test_strided_threads():
    assert shade_hidden.PIXELS_PER_THREAD > 1
    assert shade_hidden.strided_threads(47 * 27) == math.ceil(47 * 27 / shade_hidden.PIXELS_PER_THREAD)
    assert (47 * 27) % shade_hidden.PIXELS_PER_THREAD != 0  # the test image leaves the last thread short


@pytest.mark.parametrize("camera", ["perspective", "orthographic", "narrow"])
def test_the_strided_trace_equals_the_per_pixel_one(camera):
    proj = int(camera == "orthographic")
    strided = shade_hidden.strided_hidden(proj)
    twin_of = dict(zip(strided, shade_hidden.projected_hidden(proj)))
    twin_of[shade_hidden.hidden_direct_strided] = shade_hidden.hidden_direct
    twin_of[shade_hidden.hidden_caustic_strided] = shade_hidden.hidden_caustic
    launch = wp.launch
    seen, traced = set(), []

    def both(kernel, dim, inputs=(), **kw):
        if kernel in twin_of.values():
            raise AssertionError(f"{kernel.key} launched: the frame should launch the strided kernel")
        if kernel not in twin_of:
            return launch(kernel, dim, inputs=inputs, **kw)
        pixels, threads = inputs[-2], inputs[-1]
        assert dim == threads == shade_hidden.strided_threads(pixels)
        idx = [i for i, a in enumerate(inputs) if isinstance(a, wp.array)]
        before = {i: inputs[i].numpy().copy() for i in idx}
        launch(kernel, dim, inputs=inputs, **kw)
        fast = {i: inputs[i].numpy().copy() for i in idx}
        for i in idx:
            inputs[i].assign(before[i])
        launch(twin_of[kernel], pixels, inputs=list(inputs[:-2]), **kw)
        for i in idx:
            assert inputs[i].numpy().tobytes() == fast[i].tobytes(), (kernel.key, kernel.adj.args[i].label)
        m = inputs[[a.label for a in kernel.adj.args].index("missed")].numpy()
        hidden = shade_hidden.HIDDEN_REFRACTED | shade_hidden.HIDDEN_REFLECTED
        slices = np.bincount(np.nonzero(m)[0] // threads, minlength=shade_hidden.PIXELS_PER_THREAD)
        traced.append((int(np.count_nonzero(m)), int(np.count_nonzero(m & hidden)), int(slices.min())))
        seen.add(kernel)

    wp.launch = both
    try:
        for concurrent in (False, True):
            r = _pool(camera)
            r.set_concurrent(concurrent)
            for _ in range(2):
                r.render_frame()
            assert np.isfinite(r.final.numpy()).all()
    finally:
        wp.launch = launch
    assert seen == set(twin_of)  # both programs' traces, the direct light and the caustic at hidden hits ran strided
    assert min(t[0] for t in traced) > 0 and min(t[1] for t in traced) > 0  # rays traced, hidden hits among them
    if camera == "narrow":
        assert min(t[2] for t in traced) > 0  # in every slice of pixels



def test_the_strided_direct_and_caustic_cover_every_slice():
    """The pool's hidden hits lie in a few slices of pixels and mostly in the water's shadow: here every pixel is given
    a hidden hit on a random opaque triangle (either ray, both or none), so that the direct light and the caustic of
    the strided kernels are compared with the per-pixel ones in every slice, the last thread's included."""
    r = _pool("perspective")
    r.render_frame()
    h, g = r.hidden, r.gbuffer
    n = g.width * g.height
    threads = shade_hidden.strided_threads(n)
    rng = np.random.default_rng(7)
    faces = h.layer.face_to_tri.numpy()
    tri = faces[rng.integers(0, len(faces), 2 * n)] + 1
    uv = rng.random((2 * n, 2)) * 0.5
    h.hidden_tri.assign((tri * rng.choice([-1, 1], 2 * n)).astype(np.int32))
    h.hidden_uvw.assign(np.concatenate([uv, rng.random((2 * n, 1))], axis=1).astype(np.float32))
    missed = rng.choice([0, shade_hidden.HIDDEN_REFRACTED, shade_hidden.HIDDEN_REFLECTED,
                         shade_hidden.HIDDEN_REFRACTED | shade_hidden.HIDDEN_REFLECTED], n).astype(np.int32)
    h.missed.assign(missed)
    flux = r.photons.hidden
    calls = [(shade_hidden.hidden_direct, shade_hidden.hidden_direct_strided, args + [h.layer])
             for args in shade_hidden.shadow_map_args(r.lights)]
    calls += [(shade_hidden.hidden_caustic, shade_hidden.hidden_caustic_strided,
               [flux.views[li], flux.flux[li], *flux.shape[li], flux.gather, h.layer]) for li in range(len(r.lights))]
    lit = np.zeros(n, bool)
    for pixel_kernel, strided_kernel, head in calls:
        out = []
        for kernel, dim, tail in ((pixel_kernel, n, []), (strided_kernel, threads, [n, threads])):
            final = wp.zeros(n, dtype=wp.vec3, device="cpu")
            wp.launch(kernel, dim=dim, device="cpu",
                      inputs=head + [h.missed, h.hidden_tri, h.hidden_uvw, final] + tail)
            out.append(final.numpy())
        assert out[1].tobytes() == out[0].tobytes(), pixel_kernel.key
        lit |= out[0].any(axis=1)
    per_slice = np.bincount(np.nonzero(lit)[0] // threads, minlength=shade_hidden.PIXELS_PER_THREAD)
    assert per_slice.min() > 0, per_slice  # light added in every slice
    assert lit[(shade_hidden.PIXELS_PER_THREAD - 1) * threads:].any() and not lit[missed == 0].any()
