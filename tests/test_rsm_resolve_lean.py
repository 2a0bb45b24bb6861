"""perf_notes section 87. The fitted RSM views (cascades and pilots) keep no shadow depth: nothing of a frame reads it,
so its resolves skip the 4 B a texel (``LightMaps.SKIP_UNREAD_SHADOW_DEPTH``). The tests prove the skip changes
nothing (every other map, AOV and the ledger bit for bit) and fail as soon as some code reads a skipped map. And
``resolve_rsm_view_prefetch`` (a round's keys loaded up front, ``kernels.RESOLVE_RSM_PREFETCH``) against its twin
``resolve_rsm_view``: every buffer bit for bit."""
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


CASES = [("cisp", {}, False), ("cisp", {}, True), ("sspm", {}, False), ("cisp", dict(sort_photons=True), False),
         ("cisp", dict(splat="wavefront"), False), ("cisp", dict(splat="wavefront", wavefront_grid="mesh"), False),
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


@pytest.mark.parametrize("size", [48, 70])
def test_prefetched_rsm_resolve_is_its_twin(device, size, monkeypatch):
    """``resolve_rsm_view_prefetch`` against ``resolve_rsm_view`` (both fused, the same light poses): every buffer of
    every view (both layers' maps, shadow depth, opaque triangle, the depth bounds, and both visibility buffers left
    clear) bit for bit, with and without the kept surface and texel maps: a spot moved between two frames, a point
    light's six faces, a distant light, views that are not a multiple of a coarse cell (70)."""
    import math

    from cisp_warp.raster import kernels as RK
    from cisp_warp.scene import Camera, DeviceScene, Light, LightKind
    from cisp_warp.scene.model import look_at_matrix
    from test_raster import _rsm_frame, box_room, make_scene

    cam = Camera(look_at_matrix((0.2, 0.3, 0.9), (0.0, -0.5, 0.0)), width=16, height=16)
    spots = [Light(LightKind.SPOT, "spot", intensity=3.0, position=p, direction=d, cone_angle=math.radians(40),
                   cone_softness=0.3) for p, d in (((0.0, 0.9, 0.0), (0, -1, 0)), ((0.5, 0.6, -0.3), (-0.3, -1, 0.2)))]
    cases = [(box_room(), spots), (box_room(), [Light(LightKind.POINT, "bulb", intensity=2.0, position=(0.1, 0.2, 0.0))]),
             (box_room()[1:], [Light(LightKind.DISTANT, "sun", intensity=500.0, direction=(0.3, -1.0, 0.1))])]
    for parts, frames in cases:
        ds = DeviceScene(make_scene(parts, cam, frames[:1]), device)
        for surface, texel_maps in ((False, False), (True, True)):
            got = {}
            for prefetch in (True, False):
                monkeypatch.setattr(RK, "RESOLVE_RSM_PREFETCH", prefetch)
                got[prefetch] = _rsm_frame(ds, frames[0], size, True, frames, surface=surface, texel_maps=texel_maps)
            assert got[True].keys() == got[False].keys()
            for k in got[True]:
                np.testing.assert_array_equal(got[True][k], got[False][k], err_msg=f"{frames[0].name} {k}")
            assert (got[True]["0_specular_tri_id"] >= 0).any() and (got[True]["0_opaque_depth"] > 0).any()
            assert all((v == RK.EMPTY_KEY_VALUE).all() for k, v in got[True].items() if k.endswith("visibility"))


def test_prefetched_resolve_pool_frames(device, monkeypatch):
    """Two pool frames (fitted views, every default) with the prefetching resolve and with its twin: every AOV, pilot
    map and the ledger bit for bit on the CPU (to 1e-5 of their maximum on a GPU)."""
    from cisp_warp.raster import kernels as RK

    got = {}
    for prefetch in (True, False):
        monkeypatch.setattr(RK, "RESOLVE_RSM_PREFETCH", prefetch)
        got[prefetch] = _frames(device, True, monkeypatch, "cisp")
    assert got[True].keys() == got[False].keys()
    exact = wp.get_device(device).is_cpu
    for k in got[True]:
        if exact:
            np.testing.assert_array_equal(got[True][k], got[False][k], err_msg=k)
        else:
            scale = max(float(np.abs(got[False][k]).max()), 1e-30)
            np.testing.assert_allclose(got[True][k], got[False][k], rtol=0, atol=1e-5 * scale, err_msg=k)
