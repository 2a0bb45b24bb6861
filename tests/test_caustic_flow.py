"""The caustic flow (cisp_warp/photons/caustic_flow.py): its kernels against their numpy twin, and what it says on the
stability suite's cases at a tiny size: the camera's motion for a still caustic under a pan, no significant motion
for a still one, the caustic's own where the sun turns."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import warp as wp

from cisp_warp import evaluation as E
from cisp_warp.denoise.naive import caustic_motion_naive
from cisp_warp.photons import caustic_flow as F
from cisp_warp.stability_scenes import case

W, H = 48, 36


def test_flow_kernels_match_naive_twin(device):
    """finalize_cells + splat_flow against flow_naive: cells with and without a last frame (shifted about the image
    centre then), some under MIN_CELL_PHOTONS, records with and without a cell, several records a pixel."""
    rng = np.random.default_rng(3)
    n_cells, n_rec, w, h = 50, 400, 12, 9
    prev = np.zeros((n_cells, 4), np.float32)
    prev[:, 0], prev[:, 1] = rng.uniform(0, w, n_cells), rng.uniform(0, h, n_cells)
    prev[:, 2] = rng.uniform(0.0, 0.5, n_cells)
    prev[:, 3] = rng.integers(0, 9, n_cells)
    prev[prev[:, 3] == 0] = 0.0
    counts = rng.integers(0, 9, n_cells).astype(np.float32)
    d = rng.normal(0.0, 0.7, (n_cells, 2))
    sums = np.zeros((n_cells, 4), np.float32)
    sums[:, 0], sums[:, 1] = d[:, 0] * counts, d[:, 1] * counts
    sums[:, 2] = (d ** 2).sum(1) * counts + rng.uniform(0.0, 0.4, n_cells) * counts
    sums[:, 3] = counts
    records = np.stack([rng.integers(0, n_cells + 1, n_rec), rng.integers(0, w * h, n_rec)], 1).astype(np.int32)
    cells = wp.array(np.stack([prev, sums]), dtype=wp.vec4, device=device)  # parity 0: row 0 the last frame
    parity = wp.zeros(1, dtype=wp.int32, device=device)
    rec = wp.array(records, dtype=wp.vec2i, device=device)
    flow = wp.zeros(w * h, dtype=wp.vec4, device=device)
    wp.launch(F.finalize_cells, dim=n_cells, device=device, inputs=[cells, parity, w, h])
    wp.launch(F.splat_flow, dim=n_rec, device=device, inputs=[rec, cells, parity, flow])
    want = F.flow_naive(records, sums, prev, w, h)
    np.testing.assert_allclose(flow.numpy(), want, rtol=1e-4, atol=1e-4)
    assert (want[:, 3] > 0).sum() > 20 and (want[:, 3] == 0).sum() > 10


def play(name, frames=4, photons=20_000, size=(W, H), rsm=64):
    """The case at ``size`` (cisp, the caustics denoiser with the caustic flow): per frame after the first, the flow,
    the surface's motion and the motion the history was fetched by, (H, W, ...) each."""
    c = case(name)
    w, h = size
    s = E.render_settings(E.Config("cisp", photons, "caustic", "point", "rsm"), rsm)
    s = dataclasses.replace(s, caustic=dataclasses.replace(s.caustic, caustic_flow=True))
    r = E.Renderer(c.scene_at(0, w, h), s, device="cpu")
    out = []
    for f in range(frames):
        if f > 0:
            E.advance(r, c.scene_at(f, w, h))
        r.render_frame()
        if f > 0:
            out.append((r.photons.flow.flow.numpy().reshape(h, w, 4).astype(np.float64),
                        r.gbuffer.motion.numpy().reshape(h, w, 2).astype(np.float64),
                        r.denoiser.motion_used.numpy().reshape(h, w, 2).copy()))  # CPU: views of memory reused
    return r, out


@pytest.mark.parametrize("name", ["camera_pan", "grazing_light"])
def test_flow_of_a_still_caustic_is_the_surface_motion(name):
    """A still caustic, under a camera pan or not: where photons landed in cells seen both frames, the caustic flow
    is the camera's motion vectors within its own noise (pooled 3 x 3), and the denoiser takes it for the surface's
    motion at nearly every pixel (the test's false alarms: e^(−9/2) = 1.1% nominal)."""
    r, frames = play(name)
    for flow, motion, used in frames:
        known = flow[..., 3] >= 8
        mean = flow[..., :2] / np.maximum(flow[..., 3:], 1)
        err = np.hypot(*(mean - motion)[known].T)
        sd = np.sqrt(flow[..., 2][known] / flow[..., 3][known])
        assert known.sum() > 50
        assert np.median(err / sd) < 1.0  # within its own noise
        if name == "camera_pan":
            assert np.median(np.hypot(*motion[known].T)) > 0.2  # the pan moved the image
        took_flow = np.any(np.abs(used - motion) > 1e-6, -1)
        assert took_flow[flow[..., 3] > 0].mean() < 0.05


def test_flow_follows_a_turning_sun():
    """The sun turns 3° a frame over still water: the caustic moves over the still floor (about 0.4 pixels a frame at
    96 x 72), and the flow says so where the photons land (it differs from the surface's zero motion beyond its noise
    at most of them), and agrees with its naive recomputation from the splat (the denoiser's motion)."""
    r, frames = play("moving_light", photons=100_000, size=(96, 72), rsm=128)
    s = r.denoiser.settings
    for flow, motion, used in frames:
        lit = flow[..., 3] > 0
        assert np.abs(motion).max() < 1e-4  # the camera still (its motion vectors rounding only)
        took_flow = np.any(np.abs(used - motion) > 1e-6, -1)
        assert took_flow[lit].mean() > 0.5
        np.testing.assert_allclose(used, caustic_motion_naive(motion, flow, s.flow_radius, s.flow_sigmas)[0], atol=1e-4)


def test_trace_without_the_flow_code_equals_the_flow_kernel():
    """``kernels_cisp.trace_photons`` (the caustic flow's code left out at compile time, the pass's kernel without a
    flow) against ``trace_photons_flow`` on each launch's own inputs, frames of the turning sun with a flow kept:
    outcome records, landings, photon map, its second moment, the hidden map and the ledger bit for bit the same;
    the flow's cells and records are written by the flow's kernel only. And each pass launches the kernel it needs."""
    from cisp_warp.photons import kernels_cisp as K

    c = case("moving_light")
    s = E.render_settings(E.Config("cisp", 20_000, "caustic", "point", "rsm"), 64)
    off = dataclasses.replace(s, caustic=dataclasses.replace(s.caustic, caustic_flow=False))
    assert E.Renderer(c.scene_at(0, W, H), off, device="cpu").photons.trace_kernel() is K.trace_photons
    s = dataclasses.replace(s, caustic=dataclasses.replace(s.caustic, caustic_flow=True))
    r = E.Renderer(c.scene_at(0, W, H), s, device="cpu")
    p = r.photons
    assert p.trace_kernel() is K.trace_photons_flow
    assert p.trace_kernel(True) is K.projected_trace(True, 1, 0)  # the sun's, compiled for its projection
    p.PROJECTED = False  # the kernels that read the projections at run time (test_cisp checks the projected ones)
    p.record_hits = True
    at = {a.label: i for i, a in enumerate(K.trace_photons.adj.args)}
    assert [a.label for a in K.trace_photons_flow.adj.args] == list(at)
    outputs = ("photon_map", "photon_m2", "ledger", "hits", "outcome", "hidden_flux", "flow_cells", "flow_records")
    launch = p.launch_photons
    compared = []

    def both(kernel, n, inputs):
        if kernel is not K.trace_photons_flow:
            return launch(kernel, n, inputs)
        before = {o: inputs[at[o]].numpy().copy() for o in outputs}
        launch(K.trace_photons_flow, n, inputs)
        flowed = {o: inputs[at[o]].numpy().copy() for o in outputs}
        for o in outputs[:6]:
            inputs[at[o]].assign(before[o])
        launch(K.trace_photons, n, inputs)
        plain = {o: inputs[at[o]].numpy() for o in outputs}
        for o in outputs[:6]:
            assert np.array_equal(plain[o], flowed[o]), o
        for o in outputs[6:]:  # the plain kernel leaves the flow's state as the flow's kernel wrote it
            assert np.array_equal(plain[o], flowed[o]), o
        compared.append(int((flowed["flow_records"] != before["flow_records"]).any(-1).sum()))

    p.launch_photons = both
    for f in range(3):
        if f > 0:
            E.advance(r, c.scene_at(f, W, H))
        r.render_frame()
    assert len(compared) >= 3 and min(compared) > 100  # the flow's kernel did record landings each launch
