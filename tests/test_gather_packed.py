"""The concurrent program's gather reading SVGF's last level's output in place (``Renderer.GATHER_PACKED``,
``SVGF.denoise(defer=True)``, ``SVGF.packed_color``; the sequential program's ``surface_radiance`` likewise;
docs/perf_notes.md section 80) against its twin, the output unpacked
into ``caustic_irradiance`` every frame (``unpack_level``) and read there: whole CPU frames bit for bit, the history
the next frame reads included, and the caustic AOV and SVGF's variance unpacked on demand."""

import numpy as np
import pytest
import warp as wp

from cisp_warp import analytic, shade_hidden
from cisp_warp.denoise.svgf import SVGF
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.usd import load_usd


def _frames(packed: bool, gathered: bool, monkeypatch, frames: int = 3, concurrent: bool = True) -> dict:
    monkeypatch.setattr(Renderer, "GATHER_PACKED", packed)
    monkeypatch.setattr(shade_hidden.HiddenSurfaces, "GATHERED", gathered)
    s = load_usd("scenes_usd/pool.usda", width=48, height=32)
    r = Renderer(s, RenderSettings(rsm_size=64, method="cisp", denoiser="svgf", hidden_rays="both",
                                   photons=PhotonSettings(photons=4000, seed=5)), device="cpu")
    r.set_concurrent(concurrent)
    assert isinstance(r.denoiser, SVGF) and r.denoiser.defers
    out = {}
    for f in range(frames):
        r.render_frame()
        # packed: nothing unpacked in the frame (the dense buffer still holds frame 0's zeros, then the last read)
        assert (r.denoiser.deferred is not None) == packed
        if f == 0:
            assert (np.abs(r._caustic.numpy()).max() == 0.0) == packed
        out[f"final{f}"] = r.final.numpy().copy()
        if f == 1:  # read one frame, not the other: the next frame must not depend on whether it was read
            out["caustics1"] = r.caustic_irradiance.numpy().copy()
            assert r.denoiser.deferred is None
    out["caustics"] = r.aovs(include_rsm=False)["caustics"]
    out["variance"] = r.denoiser.variance.numpy().copy()
    out["parity"] = r.denoiser.parity.numpy().copy()
    out["hist_color"] = r.denoiser.hist_color.numpy().copy()
    out["packed"] = r.denoiser.packed_color.numpy().copy()
    return out


@pytest.mark.parametrize("gathered,concurrent", [(True, True), (False, True), (True, False)])
def test_the_packed_gather_equals_the_unpacked_one(gathered, concurrent, monkeypatch):
    """Three pool frames of the concurrent program (folded hidden gather, or ``shade.composite_gather`` apart) and of
    the sequential one (``shade.surface_radiance`` reads the packed output): every
    frame's image, the caustic AOV and SVGF's variance read after the frame, its parity and colour history are the
    twin's bit for bit; the packed colour view holds the AOV's values; the caustic is not black (the test would pass
    trivially on a frame without caustics)."""
    twin = _frames(False, gathered, monkeypatch, concurrent=concurrent)
    fast = _frames(True, gathered, monkeypatch, concurrent=concurrent)
    for k in twin:
        if k != "packed":
            assert fast[k].tobytes() == twin[k].tobytes(), k
    assert fast["packed"].tobytes() == fast["caustics"].reshape(-1, 3).tobytes()
    assert fast["caustics"].max() > 0.0 and fast["variance"].max() > 0.0


def test_a_deferred_svgf_frame_unpacks_to_the_same_output(monkeypatch):
    """``SVGF.denoise(defer=True)`` leaves ``out`` alone and the parity unflipped; ``unpack`` then writes what the
    undeferred frame writes (``out``, the variance), once."""
    twin = _frames(False, True, monkeypatch, frames=1)
    monkeypatch.setattr(Renderer, "GATHER_PACKED", True)
    s = load_usd("scenes_usd/pool.usda", width=48, height=32)
    r = Renderer(s, RenderSettings(rsm_size=64, method="cisp", denoiser="svgf", hidden_rays="both",
                                   photons=PhotonSettings(photons=4000, seed=5)), device="cpu")
    r.set_concurrent(True)
    r.render_frame()
    d = r.denoiser
    assert d.deferred is not None and int(d.parity.numpy()[0]) == int(twin["parity"][0])  # the gather flipped it
    d.unpack()
    assert d.deferred is None
    assert r._caustic.numpy().tobytes() == twin["caustics"].reshape(-1, 3).tobytes()
    assert d.filtered_variance.numpy().tobytes() == twin["variance"].tobytes()


@pytest.mark.skipif(not wp.is_cuda_available(), reason="CUDA graphs need a GPU")
def test_graph_replays_leave_the_output_packed_and_unpack_on_demand(monkeypatch):
    """CUDA, frames replayed from one graph: each replay leaves SVGF's output packed again (``deferred`` set after it,
    the graph capturing no unpack), and the caustic AOV read after some frames (not others) and the image match the
    twin's frames launched from Python, to the float atomics' order."""
    out = {}
    for packed in (False, True):
        monkeypatch.setattr(Renderer, "GATHER_PACKED", packed)
        r = Renderer(analytic.wavy_water(width=32, height=24, grid=32),
                     RenderSettings(rsm_size=64, method="cisp", denoiser="svgf", photons=20_000), device="cuda:0")
        frames = []
        for f in range(5):
            r.render_frame(graph=packed)
            assert (r.denoiser.deferred is not None) == packed
            if f % 2 == 0:
                frames.append((r.final.numpy().astype(np.float64), r.caustic_irradiance.numpy().astype(np.float64)))
        assert r.graph_captures == (1 if packed else 0)
        out[packed] = frames
    for (fa, ca), (fb, cb) in zip(out[False], out[True]):
        assert np.abs(fa - fb).mean() <= 1e-4 * np.abs(fa).mean() + 1e-12
        assert np.abs(ca - cb).mean() <= 1e-4 * np.abs(ca).mean() + 1e-12
    assert np.abs(out[True][-1][1]).max() > 0.0
