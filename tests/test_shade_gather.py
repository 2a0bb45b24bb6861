"""The concurrent program's gather with the hidden hits' shading folded in (``shade_hidden.composite_gather_hidden``,
``HiddenSurfaces.gather``; docs/perf_notes.md section 76) against its twin, ``shade.composite_gather`` followed by
``hidden_direct`` per shadow map and ``hidden_caustic`` per light: bit for bit on the CPU, on a pool frame whose every
water pixel is given random hidden hits (so that each shadow map's and each light's term is added on many pixels),
and on whole frames of both programs, where too many shadow maps fall back to the twin's launches."""

import numpy as np
import pytest
import warp as wp

from cisp_warp import shade, shade_hidden
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.usd import load_usd

HIDDEN = shade_hidden.HIDDEN_REFRACTED | shade_hidden.HIDDEN_REFLECTED


def _renderer(scene="pool", method="cisp", hidden_rays="both", width=48, height=32) -> Renderer:
    s = load_usd(f"scenes_usd/{scene}.usda", width=width, height=height)
    return Renderer(s, RenderSettings(rsm_size=64, method=method, denoiser="svgf", hidden_rays=hidden_rays,
                                      photons=PhotonSettings(photons=4000, seed=5)), device="cpu")


def test_the_folded_gather_equals_gather_then_hidden_kernels():
    """Every water pixel of a concurrent pool frame (sun and spot: two shadow maps, two lights' landed photons) gets
    random HIDDEN bits and hits on random opaque triangles; the folded kernel's ``final`` equals composite_gather's
    followed by the per-pixel hidden_direct and hidden_caustic launches, bit for bit, and every map's and light's
    term changes pixels (a term dropped or added twice would show)."""
    r = _renderer()
    r.set_concurrent(True)
    r.render_frame()
    g, h, cs = r.gbuffer, r.hidden, r.composite_split
    r._march_composite()  # the gather's inputs again (the frame's gather overwrote composite_march's partial sums)
    partial = r.final.numpy().copy()
    n = g.width * g.height
    rng = np.random.default_rng(11)
    hits = cs.hits.numpy()
    water = hits[:, 0] >= -1
    missed = h.missed.numpy() & ~HIDDEN
    kinds = [0, int(shade_hidden.HIDDEN_REFRACTED), int(shade_hidden.HIDDEN_REFLECTED), int(HIDDEN)]
    missed[water] |= rng.choice(kinds, int(water.sum()))
    h.missed.assign(missed.astype(np.int32))
    faces = h.layer.face_to_tri.numpy()
    tri = faces[rng.integers(0, len(faces), 2 * n)] + 1
    h.hidden_tri.assign((tri * rng.choice([-1, 1], 2 * n)).astype(np.int32))
    h.hidden_uvw.assign(np.concatenate([rng.random((2 * n, 2)) * 0.5, rng.random((2 * n, 1))], axis=1)
                        .astype(np.float32))
    flux = r.photons.hidden
    maps = shade_hidden.shadow_map_args(r.lights)
    assert len(maps) == 2 and len(r.lights) == 2 and (missed & HIDDEN != 0).sum() > 20
    gather = [g.depth, g.albedo, r.direct.irradiance, r.caustic_irradiance, r.sky_irradiance, cs.hits, cs.weights,
              h.missed, cs.hidden_sum]
    tail = [h.missed, h.hidden_tri, h.hidden_uvw]

    def twin(n_maps=2, n_lights=2):
        final = wp.array(partial, dtype=wp.vec3, device="cpu")
        wp.launch(shade.composite_gather, dim=n, device="cpu", inputs=gather + [1, final, 0, None])
        for args in maps[:n_maps]:
            wp.launch(shade_hidden.hidden_direct, dim=n, device="cpu", inputs=args + [h.layer] + tail + [final])
        for li in range(n_lights):
            wp.launch(shade_hidden.hidden_caustic, dim=n, device="cpu", inputs=[
                flux.views[li], flux.flux[li], *flux.shape[li], flux.gather, h.layer] + tail + [final])
        return final.numpy()

    final = wp.array(partial, dtype=wp.vec3, device="cpu")
    assert h.gather(g, r.direct.irradiance, r.caustic_irradiance, r.sky_irradiance, cs, r.lights, final, flux)
    folded = final.numpy()
    expect = twin()
    assert folded.tobytes() == expect.tobytes()
    for n_maps, n_lights in ((1, 2), (2, 1), (0, 2), (2, 0)):  # each term changes the image
        assert (twin(n_maps, n_lights) != expect).any(axis=1).sum() > 5, (n_maps, n_lights)
    assert not (expect != twin(0, 0))[(missed & HIDDEN) == 0].any()  # and only where a hit is hidden


@pytest.mark.parametrize("scene,method,hidden_rays", [
    ("pool", "cisp", "both"), ("cornell_flooded", "cisp", "refracted"), ("pool", "none", "refracted")])
def test_frames_with_the_folded_gather_are_the_sequential_ones(scene, method, hidden_rays, monkeypatch):
    """Whole frames (two each): the concurrent program with the folded gather, with the twin's launches
    (``GATHERED`` False), and with more shadow maps than the folded kernel takes (the twin's launches again) give the
    sequential program's image bit for bit; the folded one launches no hidden_direct or hidden_caustic."""
    calls = []
    shade_hits = shade_hidden.HiddenSurfaces.shade_hits
    monkeypatch.setattr(shade_hidden.HiddenSurfaces, "shade_hits",
                        lambda self, *a, **k: (calls.append(1), shade_hits(self, *a, **k)))
    out = {}
    for mode in ("sequential", "folded", "apart", "too many maps"):
        monkeypatch.setattr(shade_hidden.HiddenSurfaces, "GATHERED", mode != "apart")
        monkeypatch.setattr(shade_hidden, "GATHER_MAPS", 0 if mode == "too many maps" else 2)
        r = _renderer(scene, method, hidden_rays)
        r.set_concurrent(mode != "sequential")
        calls.clear()
        for _ in range(2):
            r.render_frame()
        out[mode] = r.final.numpy().copy()
        assert len(calls) == (0 if mode == "folded" else 2), mode  # sequential: by HiddenSurfaces.render
    assert (r.hidden.missed.numpy() & HIDDEN != 0).sum() > 0  # hidden hits shaded
    packed = shade_hidden.hidden_lights(r.lights, getattr(r.photons, "hidden", None))
    assert packed is None  # GATHER_MAPS 0 (the last mode)
    for mode in ("folded", "apart", "too many maps"):
        assert out[mode].tobytes() == out["sequential"].tobytes(), mode
