"""The energy ledger is summed per block (Warp tiles), not by one atomic per photon and entry: the sums must not
depend on how photons are grouped into blocks, and the per-block maximum of ``max_luminance`` must be the max."""

import numpy as np
import pytest
import warp as wp

from cisp_warp.photons import PhotonSettings
from cisp_warp.photons import common as C
from cisp_warp.raster.light_maps import CascadeState, _state
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.stability_scenes import wavy_water


def ledger_with_block(device, method, block, stripes=None, outcome_blocks=None):
    """The ledger and photon map of one frame with photon blocks of ``block`` threads, a ledger of ``stripes``
    stripes and at most ``outcome_blocks`` blocks in the outcome pass (None: the device's defaults)."""
    settings = RenderSettings(rsm_size=64, method=method, denoiser="none",
                              photons=PhotonSettings(photons=5_000, seed=7, reference_photons=10_000))
    r = Renderer(wavy_water(width=32, height=24), settings, device=device)
    p = r.photons
    p.ledger_block = block
    if stripes is not None:
        p.ledger_stripes = stripes
        p.ledger_rows = wp.zeros(stripes * C.LEDGER_ROW, dtype=wp.vec3d, device=p.device)
    if outcome_blocks is not None:
        p.outcome_max_blocks = outcome_blocks
    r.render_frame()
    return p.read_ledger(), p.photon_map.numpy()


@pytest.mark.parametrize("method", ["cisp", "sspm", "caustics_map", "reference"])
def test_ledger_does_not_depend_on_the_block_size(device, method, monkeypatch):
    """Blocks of 1 (a float64 add per photon, in photon order, one stripe) against blocks of 32 threads whose
    tallies are tile-summed first, with a partial last block (5000 photons), added to 5 ledger stripes, and an
    outcome pass of 3 blocks whose threads each sum every 96th record (the CUDA layout): the same figures to 1e-12,
    closing."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)  # real multi-thread blocks on the CPU too
    one, map_one = ledger_with_block(device, method, 1, stripes=1, outcome_blocks=1 << 30)
    many, map_many = ledger_with_block(device, method, 32, stripes=5, outcome_blocks=3)
    assert one["sampled"].sum() > 0 and one["stored"].sum() > 0
    np.testing.assert_allclose(many.values, one.values, rtol=1e-12, atol=1e-12 * one["sampled"].max())
    assert many.closure() < 1e-12
    np.testing.assert_allclose(map_many, map_one, rtol=1e-5, atol=1e-6 * map_one.max())


@pytest.mark.parametrize("block", [96, 128])
def test_emission_reduction_of_whole_warps(device, block, monkeypatch):
    """``cisp``'s emission entries summed over blocks of whole warps (on CUDA ``kernels_cisp._emission_reduce``: a
    reduce-scatter of 18 doubles per warp, the warps' sums in shared memory, 18 float64 atomics; 128 threads is
    the frame's block, 96 three warps) against blocks of 1 (Warp's tile sum, each photon's values added in photon
    order): every entry to 1e-12 and closing; on the CPU both are the tile path (fibers)."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    one, _ = ledger_with_block(device, "cisp", 1, stripes=1)
    many, _ = ledger_with_block(device, "cisp", block, stripes=3)
    assert one["sampled"].sum() > 0 and one["refracted"].sum() > 0
    np.testing.assert_allclose(many.values, one.values, rtol=1e-12, atol=1e-12 * one["sampled"].max())
    assert many.closure() < 1e-12


def test_outcome_pass_sums_every_record(device, rng, monkeypatch):
    """ledger_add_outcomes against numpy: records of every final entry (and codes outside the mask, which it must
    leave out), summed by 3 blocks of 32 threads into 4 stripes, then folded: float64 sums to 1e-12. The records
    come in two runs of slots of which the last 5 of each lie past the view's photon count (stale records of a
    fixed-size launch): those must be left out too."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    n = 3 * 32 * 7 + 13
    finals = [e for e in range(C.LEDGER_ENTRIES) if (int(C.FINAL_ENTRIES) >> e) & 1]
    codes = rng.choice(finals + [-1], size=n)
    power = rng.random((n, 3), dtype=np.float32)
    mask = C.entry_mask(*finals[:-1])  # the last final entry is left out of the mask
    records = np.concatenate([power, codes[:, None].astype(np.float32)], axis=1)
    run = n // 2  # n is odd: the last record lies in a third, partial run
    live = np.arange(n) % run < run - 5
    states = wp.array([_state(True, 1)], dtype=CascadeState, device=device)
    stripes = wp.zeros(4 * C.LEDGER_ROW, dtype=wp.vec3d, device=device)
    ledger = wp.zeros(C.LEDGER_ENTRIES, dtype=wp.vec3d, device=device)
    block = 32 if wp.get_device(device).is_cpu else 64
    blocks = 3
    wp.launch_tiled(C.ledger_add_outcomes, dim=blocks, block_dim=block, device=device,
                    inputs=[wp.array(records, dtype=wp.vec4, device=device), n, blocks * block, mask, stripes, states, 0,
                            run - 5, run])
    wp.launch_tiled(C.ledger_fold, dim=C.LEDGER_ENTRIES, block_dim=4 if wp.get_device(device).is_cuda else 1,
                    device=device, inputs=[stripes, ledger])
    expect = np.zeros((C.LEDGER_ENTRIES, 3))
    for e in finals[:-1]:
        expect[e] = power[(codes == e) & live].astype(np.float64).sum(axis=0)
    np.testing.assert_allclose(ledger.numpy(), expect, rtol=1e-12)
    assert not stripes.numpy().any()  # folded stripes are zero again


def test_max_luminance_is_the_maximum(device, rng, monkeypatch):
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    """The max over the texels with a specular surface of their flux's luminance (a perspective view's flux: the
    light's intensity × the texel's solid angle, random), the texels without one left out even where their solid
    angle is the largest."""
    from cisp_warp.raster import ViewParams
    from cisp_warp.raster.kernels import TexelEmission

    n = 3 * 64 * C.MAX_LUM_TEXELS + 17  # a partial last block
    rgb = np.array([2.0, 1.0, 0.5], np.float32)
    sa = rng.random(n, dtype=np.float32)
    tri = np.where(rng.random(n) < 0.3, -1, 0).astype(np.int32)
    tri[np.argmax(sa)] = -1  # the largest solid angle has no specular surface
    lum = (sa[:, None] * rgb[None, :]) @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    e = TexelEmission()
    e.light_rgb = wp.vec3(*rgb)
    e.texel_solid_angle = wp.array(sa, dtype=wp.float32, device=device)
    views = wp.array([ViewParams()], dtype=ViewParams, device=device)  # perspective (orthographic 0)
    for block in (1, 64):
        out = wp.zeros(1, dtype=wp.float32, device=device)
        blocks = -(-n // (block * C.MAX_LUM_TEXELS))
        wp.launch_tiled(C.max_luminance, dim=blocks, block_dim=block, device=device,
                        inputs=[views, 0, wp.array(tri, dtype=wp.int32, device=device), e, n, out])
        np.testing.assert_allclose(out.numpy()[0], lum[tri >= 0].max(), rtol=1e-6)
        assert out.numpy()[0] < lum.max()
