"""The energy ledger is summed per block (Warp tiles), not by one atomic per photon and entry: the sums must not
depend on how photons are grouped into blocks, and the per-block maximum of ``max_luminance`` must be the max."""

import numpy as np
import pytest
import warp as wp

from cisp_warp.photons import PhotonSettings
from cisp_warp.photons import common as C
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.stability_scenes import wavy_water


def ledger_with_block(device, method, block):
    settings = RenderSettings(rsm_size=64, method=method, denoiser="none",
                              photons=PhotonSettings(photons=5_000, seed=7, reference_photons=10_000))
    r = Renderer(wavy_water(width=32, height=24), settings, device=device)
    r.photons.ledger_block = block
    r.render_frame()
    return r.photons.read_ledger(), r.photons.photon_map.numpy()


@pytest.mark.parametrize("method", ["cisp", "sspm", "caustics_map", "reference"])
def test_ledger_does_not_depend_on_the_block_size(device, method, monkeypatch):
    """Blocks of 1 (a float64 add per photon, in photon order) against blocks of 32 threads whose tallies are
    tile-summed first, with a partial last block (5000 photons): the same figures to 1e-12, closing."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)  # real multi-thread blocks on the CPU too
    one, map_one = ledger_with_block(device, method, 1)
    many, map_many = ledger_with_block(device, method, 32)
    assert one["sampled"].sum() > 0 and one["stored"].sum() > 0
    np.testing.assert_allclose(many.values, one.values, rtol=1e-12, atol=1e-12 * one["sampled"].max())
    assert many.closure() < 1e-12
    np.testing.assert_allclose(map_many, map_one, rtol=1e-5, atol=1e-6 * map_one.max())


def test_max_luminance_is_the_maximum(device, rng, monkeypatch):
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    n = 3 * 64 * C.MAX_LUM_TEXELS + 17  # a partial last block
    flux = rng.random((n, 3), dtype=np.float32)
    lum = flux @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    for block in (1, 64):
        out = wp.zeros(1, dtype=wp.float32, device=device)
        blocks = -(-n // (block * C.MAX_LUM_TEXELS))
        wp.launch_tiled(C.max_luminance, dim=blocks, block_dim=block, device=device,
                        inputs=[wp.array(flux, dtype=wp.vec3, device=device), n, out])
        np.testing.assert_allclose(out.numpy()[0], lum.max(), rtol=1e-6)
