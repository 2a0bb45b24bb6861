"""Tracing photons grouped by their predicted march (not traced, reflected, refracted) and texel order changes only
the order of the threads: every photon is traced as without the sort, and the groups predict what the trace does."""

import numpy as np
import pytest
import warp as wp

from cisp_warp.photons import PhotonSettings
from cisp_warp.photons import common as C
from cisp_warp.photons.base import SORT_PASS_BITS, morton_sort_bits
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.stability_scenes import wavy_water


def frame(device, method, sort):
    settings = RenderSettings(rsm_size=64, method=method, denoiser="none",
                              photons=PhotonSettings(photons=4_000, seed=5, sort_photons=sort))
    r = Renderer(wavy_water(width=32, height=24), settings, device=device)
    r.render_frame()
    return r


@pytest.mark.parametrize("method", ["cisp", "sspm"])
def test_sorted_photons_trace_as_unsorted(device, method):
    """The same ledger (to float64 rounding) and photon map (to float32 rounding of the order of the adds)."""
    on, off = frame(device, method, True), frame(device, method, False)
    a, b = on.photons.read_ledger(), off.photons.read_ledger()
    np.testing.assert_allclose(a.values, b.values, rtol=1e-9, atol=1e-12 * b["sampled"].max())
    assert a.closure() < 1e-9
    m_on, m_off = on.photons.photon_map.numpy(), off.photons.photon_map.numpy()
    np.testing.assert_allclose(m_on, m_off, rtol=1e-5, atol=1e-6 * m_off.max())


def test_sort_groups_predict_the_trace(device):
    """The order is a permutation, its group keys ascend, texel (Morton) order holds inside each group, and the
    groups predict the trace: every photon keyed 'not traced' is not traced (no outcome record), every other is."""
    r = frame(device, "cisp", True)
    p = r.photons
    n = p.photons_per_view(p.lights[0])
    texel_order, keys = p._order.numpy()[:n].copy(), p._sort_keys.numpy()[:n].copy()  # keys: per texel-order thread
    order = p._grouped.numpy()[:n].copy()
    assert np.array_equal(np.sort(order), np.arange(n))
    group_of = np.empty(n, np.int32)
    group_of[texel_order] = keys
    group = group_of[order]
    assert np.all(np.diff(group) >= 0)
    traced = p.outcome.numpy()[:n, 3] >= 0  # outcome records are per thread: a final entry after the bounce
    assert (group == int(C.SORT_NOT_TRACED)).any() and (group == int(C.SORT_REFRACTED)).any()
    assert not traced[group == int(C.SORT_NOT_TRACED)].any()
    assert traced[group != int(C.SORT_NOT_TRACED)].all()
    # texel order inside each group: the Morton keys of the photons, recomputed, ascend within a group
    b = next(p.rsm_batches(r.frame - 1))
    keys = wp.zeros(n, dtype=wp.int32, device=device)
    index = wp.zeros(n, dtype=wp.int32, device=device)
    wp.launch(C.photon_sort_keys, dim=n, device=device, inputs=[
        b.lights.views, b.lights.states, b.view_index, b.light_photons, p.inputs.randoms, b.stream, keys, index])
    begin, _ = morton_sort_bits(max(b.rsm.width, b.rsm.height))
    morton = keys.numpy()[order] >> begin
    for g in np.unique(group):
        assert np.all(np.diff(morton[group == g]) >= 0)


@pytest.mark.parametrize("block", [1, 32])
def test_group_partition_is_a_stable_sort(device, rng, monkeypatch, block):
    """photon_group_keys' block counts, their scan and photon_group_scatter give the stable sort of the photons by
    group (numpy's stable argsort), in blocks of one thread and in CPU blocks of 32 with a partial last block, all
    four groups (slots past the photon count last) and a padded tail; the counts are the groups' counts per block."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    n = 5 * 32 + 11
    groups = rng.integers(0, C.SORT_GROUPS, n).astype(np.int32)
    order_in = rng.permutation(n).astype(np.int32)
    blocks = -(-n // block)
    keys = wp.array(groups, dtype=wp.int32, device=device)
    order = wp.array(order_in, dtype=wp.int32, device=device)
    offsets = wp.array(np.zeros(C.SORT_GROUPS * blocks, np.int32), device=device)
    counts = np.zeros((C.SORT_GROUPS, blocks), np.int32)
    for b in range(blocks):
        counts[:, b] = np.bincount(groups[b * block:(b + 1) * block], minlength=C.SORT_GROUPS)
    scan = np.concatenate([[0], np.cumsum(counts.reshape(-1))[:-1]]).astype(np.int32)
    offsets.assign(scan)
    out = wp.full(n + 7, -1, dtype=wp.int32, device=device)
    wp.launch_tiled(C.photon_group_scatter, dim=blocks, block_dim=block, device=device,
                    inputs=[keys, order, n, offsets, out])
    np.testing.assert_array_equal(out.numpy()[:n], order_in[np.argsort(groups, kind="stable")])
    assert np.all(out.numpy()[n:] == -1)


def test_morton_sort_takes_an_even_number_of_passes():
    """The Morton sort's key bits: the top bits of the texel code, in an even number of radix passes (an odd number
    leaves the sort's result in the scratch half, copied back by two device copies), at most one pass of bits left
    out, none for views whose whole code fits one or two passes."""
    for side in (2, 16, 64, 100, 256, 1000, 1024, 2048, 3000, 4096, 8192, 16384):
        begin, end = morton_sort_bits(side)
        assert end == 2 * (side - 1).bit_length()
        passes = -(-(end - begin) // SORT_PASS_BITS)
        assert passes == 1 or passes % 2 == 0
        assert begin <= SORT_PASS_BITS and (end > 2 * SORT_PASS_BITS or begin == 0)
