"""The composite's kernels and the hidden rays' trace compiled for the camera's projection (``shade.projected_composite``,
``shade_hidden.projected_hidden``; docs/perf_notes.md section 56) against the run-time kernels, their twins: every
launch a frame makes replayed on the same inputs, bit for bit, for a perspective and an orthographic camera and both
programs (the one-stream ``composite`` + ``trace_hidden``, the concurrent ``composite_march`` + ``trace_hidden_rays``);
the other projection's kernel on the same inputs must differ (the constant is what the kernel computes with)."""

import math
from dataclasses import replace

import numpy as np
import pytest
import warp as wp

from cisp_warp import shade, shade_hidden
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.usd import load_usd


def _pool(orthographic: bool) -> Renderer:
    scene = load_usd("scenes_usd/pool.usda", width=48, height=27)
    if orthographic:  # the same pose, the extent the perspective view has at the distance of the world's origin
        c = scene.camera
        dist = float(np.linalg.norm(c.to_world[:3, 3]))
        scene.camera = replace(c, orthographic=True, ortho_height=2.0 * dist * math.tan(0.5 * c.fov_y))
    return Renderer(scene, RenderSettings(rsm_size=64, method="cisp", denoiser="svgf", hidden_rays="both",
                                          photons=PhotonSettings(photons=4000, seed=3)), device="cpu")


def _arrays(inputs) -> list[int]:
    return [i for i, a in enumerate(inputs) if isinstance(a, wp.array)]


@pytest.mark.parametrize("orthographic", [False, True])
def test_the_composite_compiled_per_projection_equals_the_run_time_one(orthographic, monkeypatch):
    proj = int(orthographic)
    monkeypatch.setattr(shade_hidden.HiddenSurfaces, "STRIDED", False)  # the strided trace: test_shade_strided.py
    twin_of, other_of = {}, {}
    for o in (0, 1):
        fast = shade.projected_composite(o) + shade_hidden.projected_hidden(o)
        slow = (shade.composite, shade.composite_march, shade_hidden.trace_hidden, shade_hidden.trace_hidden_rays)
        wrong = shade.projected_composite(1 - o) + shade_hidden.projected_hidden(1 - o)
        twin_of.update(zip(fast, slow))
        other_of.update(zip(fast, wrong))
    launch = wp.launch
    seen, differs, missed = set(), set(), []

    def both(kernel, dim, inputs=(), **kw):
        if kernel in (shade.composite, shade.composite_march, shade_hidden.trace_hidden, shade_hidden.trace_hidden_rays):
            raise AssertionError(f"{kernel.key} launched: the frame should launch the projected kernel")
        if kernel not in twin_of:
            return launch(kernel, dim, inputs=inputs, **kw)
        assert kernel in (shade.projected_composite(proj) + shade_hidden.projected_hidden(proj)), kernel.key
        idx = _arrays(inputs)
        before = {i: inputs[i].numpy().copy() for i in idx}
        launch(kernel, dim, inputs=inputs, **kw)
        fast = {i: inputs[i].numpy().copy() for i in idx}
        for i in idx:
            inputs[i].assign(before[i])
        launch(twin_of[kernel], dim, inputs=inputs, **kw)
        for i in idx:
            assert inputs[i].numpy().tobytes() == fast[i].tobytes(), (kernel.key, kernel.adj.args[i].label)
        for i in idx:
            inputs[i].assign(before[i])
        launch(other_of[kernel], dim, inputs=inputs, **kw)  # the other projection compiled: must not pass
        if any(inputs[i].numpy().tobytes() != fast[i].tobytes() for i in idx):
            differs.add(twin_of[kernel])
        for i in idx:
            inputs[i].assign(fast[i])
        seen.add(twin_of[kernel])
        if kernel.key.startswith("trace_hidden"):
            missed.append(int(np.count_nonzero(inputs[[a.label for a in kernel.adj.args].index("missed")].numpy())))

    monkeypatch.setattr(wp, "launch", both)
    for concurrent in (False, True):
        r = _pool(orthographic)
        assert bool(r.view.orthographic) == orthographic
        r.set_concurrent(concurrent)
        r.render_frame()
        assert np.isfinite(r.final.numpy()).all()
    assert seen == {shade.composite, shade.composite_march, shade_hidden.trace_hidden, shade_hidden.trace_hidden_rays}
    assert differs == seen  # every kernel computes with its compiled projection
    assert min(missed) > 0  # the hidden trace had rays to follow in both programs


def test_the_run_time_kernels_are_launched_without_projected(monkeypatch):
    """``shade.PROJECTED`` and ``HiddenSurfaces.PROJECTED`` off: the frame launches the run-time kernels."""
    monkeypatch.setattr(shade, "PROJECTED", False)
    monkeypatch.setattr(shade_hidden.HiddenSurfaces, "PROJECTED", False)
    launch = wp.launch
    seen = set()

    def record(kernel, dim, inputs=(), **kw):
        seen.add(kernel)
        return launch(kernel, dim, inputs=inputs, **kw)

    monkeypatch.setattr(wp, "launch", record)
    r = _pool(False)
    r.render_frame()
    assert {shade.composite, shade_hidden.trace_hidden} <= seen
    assert not seen & set(shade.projected_composite(0) + shade_hidden.projected_hidden(0))
