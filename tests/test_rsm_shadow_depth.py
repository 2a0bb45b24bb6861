"""The fitted RSM views (cascades and pilots) keep no shadow depth (perf_notes section 87): nothing of a frame reads it,
so its resolves skip the 4 B a texel (``LightMaps.SKIP_UNREAD_SHADOW_DEPTH``). The tests prove the skip changes
nothing (every other map, AOV and the ledger bit for bit) and fail as soon as some code reads a skipped map."""
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import warp as wp

from cisp_warp.photons import PhotonSettings
from cisp_warp.raster.light_maps import LightMaps
from cisp_warp.raster.rasterizer import RSMView
from cisp_warp.render import Renderer, RenderSettings

#: the functions that may touch a view's ``shadow_depth`` without reading its texels: the resolve's launch (a write),
#: the AOVs' copy (``_Buffers.numpy``, empty arrays skipped) and the keep/has helpers
_NOT_READERS = {"_render_rsm", "numpy", "has_shadow_depth", "keep_shadow_depth"}


class _SpiedRSMView(RSMView):
    """An RSMView whose ``shadow_depth`` records the function that fetched it (its caller's name)."""

    touched: list

    @property
    def shadow_depth(self):
        caller = sys._getframe(1).f_code.co_name
        a = self.__dict__["_spied_shadow_depth"]
        self.touched.append(caller)
        if a.shape[0] == 0 and caller not in _NOT_READERS and caller != "test_no_frame_reads_a_skipped_shadow_depth":
            # raised here, before a kernel launched with the empty array reads out of it
            raise AssertionError(f"{self.view.name}'s shadow depth is skipped but read by {caller}")
        return a

    @shadow_depth.setter
    def shadow_depth(self, value):
        self.__dict__["_spied_shadow_depth"] = value


def _spy(r: RSMView) -> list:
    r.__dict__["_spied_shadow_depth"] = r.__dict__.pop("shadow_depth")
    r.__class__ = _SpiedRSMView
    r.touched = []
    return r.touched


def _pool(device, method="cisp", size=(48, 27), **photons) -> Renderer:
    from cisp_warp.usd import load_usd

    path = Path(__file__).resolve().parents[1] / "scenes_usd" / "pool.usda"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stage = load_usd(path, width=size[0], height=size[1], device=device)
    return Renderer(stage, RenderSettings(width=size[0], height=size[1], rsm_size=64, method=method, denoiser="svgf",
                                          photons=PhotonSettings(photons=6000, seed=3, **photons)), device=device)


#: the photon order (``sort_photons``) is left out: it reorders the same views' photons and reads no map of its own
CASES = [("cisp", {}, False), ("cisp", {}, True), ("sspm", {}, False), ("cisp", dict(splat="wavefront"), False), ("cisp", dict(splat="wavefront", wavefront_grid="mesh"), False),
         ("caustics_map", {}, False)]


@pytest.mark.parametrize("method,photons,concurrent", CASES)
def test_no_frame_reads_a_skipped_shadow_depth(device, method, photons, concurrent):
    """Two pool frames (a fitted sun and spot with their split shadow maps, or whole views for the caustics map) with
    every RSM and pilot view's ``shadow_depth`` spied on: a view that keeps none (the fitted ones, unless the mesh
    wavefront asks for them) is touched by nothing but its resolve's launch and the AOVs' copy; the views that keep
    it are whole views (read by ``shadow_maps`` where the light has no shadow map) or the mesh wavefront's. Fails as
    soon as a kernel's launch, a tool or a pass fetches a skipped map."""
    r = _pool(device, method, **photons)
    if concurrent:
        r.set_concurrent(True)
    spied = [(lm, v, _spy(v)) for lm in r.lights for v in lm.rsm + lm.pilot]
    for _ in range(2):
        r.render_frame()
    r.aovs()
    mesh = photons.get("wavefront_grid") == "mesh"
    launched = 0
    for lm, v, touched in spied:
        touched = list(touched)  # (the checks below fetch it too)
        kept = v.has_shadow_depth
        if lm.fitted:
            assert kept == (mesh and any(v is c for c in lm.rsm)), v.view.name
        else:
            assert kept, v.view.name  # whole views: shadow_maps may read them
        if not kept:
            assert v.shadow_depth.shape[0] == 0
            readers = set(touched) - _NOT_READERS
            assert not readers, f"{v.view.name}'s shadow depth is skipped but read by {sorted(readers)}"
            launched += "_render_rsm" in touched
    if method != "caustics_map":
        assert launched >= 2  # the spy sees the skipped views' resolves launched (the 2 pilots at least)


def _frames(device, skip: bool, monkeypatch, method: str, **photons) -> dict[str, np.ndarray]:
    monkeypatch.setattr(LightMaps, "SKIP_UNREAD_SHADOW_DEPTH", skip)
    r = _pool(device, method, **photons)
    for _ in range(2):
        r.render_frame()
    out = {k: np.asarray(v) for k, v in r.aovs().items()}
    for lm in r.lights:  # the pilots' maps too (not AOVs)
        for v in lm.pilot:
            out.update(v.numpy("pilot_" + v.view.name + "_"))
    out["ledger"] = r.photons.read_ledger().values
    return out


@pytest.mark.parametrize("method", ["cisp", "sspm"])
def test_skipped_shadow_depth_is_main_frame(device, method, monkeypatch):
    """The frame with the fitted views' shadow depth skipped against main's (every view keeps and writes it): every
    AOV, every pilot map and the ledger bit for bit on the CPU (to 1e-5 of their maximum on a GPU, whose atomics add
    in any order); the only arrays main has and the skip has not are the fitted views' shadow depths."""
    skip = _frames(device, True, monkeypatch, method)
    main = _frames(device, False, monkeypatch, method)
    gone = set(main) - set(skip)
    assert gone and all(k.endswith("shadow_depth") for k in gone) and not set(skip) - set(main)
    exact = wp.get_device(device).is_cpu
    for k in skip:
        if exact:
            np.testing.assert_array_equal(skip[k], main[k], err_msg=k)
        else:
            scale = max(float(np.abs(main[k]).max()), 1e-30)
            np.testing.assert_allclose(skip[k], main[k], rtol=0, atol=1e-5 * scale, err_msg=k)


def test_keep_shadow_depth_writes_the_nearer_layer(device):
    """A fitted cascade asked to keep its shadow depth (``LightMaps.keep_shadow_depth``) writes it from the next
    resolve on: the specular depth where the layer has a surface, else the opaque depth (as whole views do)."""
    r = _pool(device)
    r.render_frame()
    for lm in r.lights:
        lm.keep_shadow_depth()
    r.render_frame()
    checked = 0
    for lm in r.lights:
        for v, a in zip(lm.rsm, lm.active):
            assert v.has_shadow_depth
            if not a:
                continue
            spec, opaque = v.specular.depth.numpy(), v.opaque_depth.numpy()
            np.testing.assert_array_equal(v.shadow_depth.numpy(), np.where(spec > 0, spec, opaque))
            checked += int((spec > 0).any() and ((spec == 0) & (opaque > 0)).any())
    assert checked >= 1
