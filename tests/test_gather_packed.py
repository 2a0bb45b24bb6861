"""The concurrent program's gather reading SVGF's last level's output in place (``Renderer.GATHER_PACKED``,
``SVGF.denoise(defer=True)``, ``SVGF.packed_color``; docs/perf_notes.md section 80) against its twin, the output unpacked
into ``caustic_irradiance`` every frame (``unpack_level``) and read there: whole CPU frames bit for bit, the history
the next frame reads included, and the caustic AOV and SVGF's variance unpacked on demand."""

import numpy as np
import pytest

from cisp_warp import shade_hidden
from cisp_warp.denoise.svgf import SVGF
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.usd import load_usd


def _frames(packed: bool, gathered: bool, monkeypatch, frames: int = 3) -> dict:
    monkeypatch.setattr(Renderer, "GATHER_PACKED", packed)
    monkeypatch.setattr(shade_hidden.HiddenSurfaces, "GATHERED", gathered)
    s = load_usd("scenes_usd/pool.usda", width=48, height=32)
    r = Renderer(s, RenderSettings(rsm_size=64, method="cisp", denoiser="svgf", hidden_rays="both",
                                   photons=PhotonSettings(photons=4000, seed=5)), device="cpu")
    r.set_concurrent(True)
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


@pytest.mark.parametrize("gathered", [True, False])
def test_the_packed_gather_equals_the_unpacked_one(gathered, monkeypatch):
    """Three pool frames of the concurrent program (folded hidden gather, or ``shade.composite_gather`` apart): every
    frame's image, the caustic AOV and SVGF's variance read after the frame, its parity and colour history are the
    twin's bit for bit; the packed colour view holds the AOV's values; the caustic is not black (the test would pass
    trivially on a frame without caustics)."""
    twin = _frames(False, gathered, monkeypatch)
    fast = _frames(True, gathered, monkeypatch)
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
