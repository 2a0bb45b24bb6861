"""Tracing photons grouped by their predicted march (not traced, reflected, refracted) and texel order changes only
the order of the threads: every photon is traced as without the sort, and the groups predict what the trace does."""

import numpy as np
import pytest
import warp as wp

from cisp_warp.photons import PhotonSettings
from cisp_warp.photons import common as C
from cisp_warp.photons.base import SORT_PASS_BITS, PhotonPass, morton_sort_bits
from cisp_warp.photons.cisp import CISP
from cisp_warp.raster.light_maps import CascadeState
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.stability_scenes import wavy_water


def frame(device, method, sort):
    settings = RenderSettings(rsm_size=64, method=method, denoiser="none",
                              photons=PhotonSettings(photons=4_000, seed=5, sort_photons=sort))
    r = Renderer(wavy_water(width=32, height=24), settings, device=device)
    # the sequential program (the CPU's default; CUDA's is the concurrent one, whose views leave their order and
    # outcome records in their lanes' own scratch banks): these tests read the pass's scratch back after the frame
    r.set_concurrent(False)
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


@pytest.mark.parametrize("fixed", [True, False])
def test_sort_groups_predict_the_trace(device, monkeypatch, fixed):
    """The order is a permutation, its group keys ascend, texel (Morton) order holds inside each group, and the
    groups predict the trace: every photon keyed 'not traced' is not traced (no outcome record), every other is.
    Both texel orders: fixed (Morton codes of the points before the frame's rotation, sorted once) and per frame."""
    monkeypatch.setattr(PhotonPass, "FIXED_ORDER", fixed)
    monkeypatch.setattr(CISP, "record_outcomes", True)  # FOLDED_OUTCOMES writes the records only if asked
    r = frame(device, "cisp", True)
    p = r.photons
    n = p.photons_per_view(p.lights[0])
    traced = p.outcome.numpy()[:n, 3] >= 0  # outcome records are per thread: a final entry after the bounce
    # every view's order of the same frame again (rebuilt, the same), so that the scratch holds the last one's, the view
    # whose trace wrote the outcome records: the CPU yields the active view alone, CUDA every view (here an inactive
    # one first), and the per-frame twin's orders differ from view to view
    *_, b = p.rsm_batches(r.frame - 1)
    keys = p._sort_keys.numpy()[:n].copy()  # march group per texel-order thread
    order = p._grouped.numpy()[:n].copy()
    assert np.array_equal(np.sort(order), np.arange(n))
    table, stride, orders = p.texel_order(b.lights, b.view_index, b.rsm, n, b.stream)
    active = int(b.lights.states.numpy()[b.view_index]["active_views"])
    base = (min(max(1, active), orders) - 1) * stride
    texel_order = table.numpy()[base : base + n].copy()
    assert np.array_equal(np.sort(texel_order), np.arange(n))
    group_of = np.empty(n, np.int32)
    group_of[texel_order] = keys
    group = group_of[order]
    assert np.all(np.diff(group) >= 0)
    assert (group == int(C.SORT_NOT_TRACED)).any() and (group == int(C.SORT_REFRACTED)).any()
    assert not traced[group == int(C.SORT_NOT_TRACED)].any()
    assert traced[group != int(C.SORT_NOT_TRACED)].all()
    # texel order inside each group: the Morton keys of the photons, recomputed, ascend within a group
    mkeys = wp.zeros(n, dtype=wp.int32, device=device)
    index = wp.zeros(n, dtype=wp.int32, device=device)
    if fixed:  # the points before the rotation, every key bit
        wp.launch(C.photon_texel_keys, dim=n, device=device, inputs=[b.rsm.width, b.rsm.height, n, 30, mkeys, index])
        morton = mkeys.numpy()[order]
    else:  # this frame's points, the sorted top bits
        wp.launch(C.photon_sort_keys, dim=n, device=device, inputs=[
            b.lights.views, b.lights.states, b.view_index, b.light_photons, p.inputs.randoms, b.stream, mkeys, index])
        begin, _ = morton_sort_bits(max(b.rsm.width, b.rsm.height))
        morton = mkeys.numpy()[order] >> begin
    for g in np.unique(group):
        assert np.all(np.diff(morton[group == g]) >= 0)


def test_few_blocks_group_as_one_a_tile(device):
    """The partition launched with fewer blocks than tiles (each block over every grid-th tile, as on CUDA) writes
    the same keys and grouped order as one block a tile."""
    r = frame(device, "cisp", True)
    p = r.photons
    *_, b = p.rsm_batches(r.frame - 1)  # the last view: the active one (CUDA yields the inactive first view too)
    n = p.photons_per_view(p.lights[0])  # its photons (CUDA launches more slots, and the ones past them are not written)
    assert n <= b.slots
    want = [a.numpy()[:n].copy() for a in (p._grouped, p._sort_keys)]
    assert (want[1] == int(C.SORT_REFRACTED)).any()
    p._grouped.fill_(-7)
    p._sort_keys.fill_(-7)
    p.group_max_blocks = 3
    *_, b = p.rsm_batches(r.frame - 1)
    got = [a.numpy()[:n] for a in (p._grouped, p._sort_keys)]
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_ballot_partition_is_the_tile_twin(device, monkeypatch):
    """The group partition with warp ballots (``PhotonPass.BALLOT_GROUPS``, CUDA: blocks of 256 over many tiles) writes
    the same keys, block counts and grouped order as Warp's tile sum and scan (the twin), every view of a frame."""
    got = {}
    for ballot in (True, False):
        monkeypatch.setattr(PhotonPass, "BALLOT_GROUPS", ballot)
        r = frame(device, "cisp", True)
        p = r.photons
        got[ballot] = [(a.numpy().copy(), c.numpy().copy(), k.numpy().copy())
                       for b in p.rsm_batches(r.frame - 1)
                       for a, c, k in [(p._grouped, p._group_counts, p._sort_keys)]]
    assert len(got[True]) == len(got[False]) >= 1
    for new, twin in zip(got[True], got[False]):
        for a, b in zip(new, twin):
            np.testing.assert_array_equal(a, b)
    assert any((k == int(C.SORT_REFRACTED)).any() for _, _, k in got[True])


@pytest.mark.parametrize("method", ["cisp", "sspm"])
def test_fixed_order_traces_as_the_frame_order(device, monkeypatch, method):
    """The fixed texel order (sorted once) and the per-frame sort (its twin) trace the same photons: the same
    ledger to float64 rounding and photon map to float32 rounding of the order of the adds, two frames."""
    runs = []
    for fixed in (True, False):
        monkeypatch.setattr(PhotonPass, "FIXED_ORDER", fixed)
        r = frame(device, method, True)
        r.render_frame()
        runs.append(r)
    a, b = runs[0].photons.read_ledger(), runs[1].photons.read_ledger()
    np.testing.assert_allclose(a.values, b.values, rtol=1e-9, atol=1e-12 * b["sampled"].max())
    m_a, m_b = runs[0].photons.photon_map.numpy(), runs[1].photons.photon_map.numpy()
    np.testing.assert_allclose(m_a, m_b, rtol=1e-5, atol=1e-6 * m_b.max())
    assert not np.array_equal(runs[0].photons._grouped.numpy(), runs[1].photons._grouped.numpy())


def _r2_texels(k: np.ndarray, scramble: tuple[int, int], w: int, h: int):
    """Texel (i, j) of R2 points k rotated by ``scramble`` (uint32 fixed point), as r2_point and the kernels place them."""
    out = []
    for a, s, size in ((C.R2_A1, scramble[0], w), (C.R2_A2, scramble[1], h)):
        a = int(getattr(a, "value", a))
        u = ((k.astype(np.uint64) * np.uint64(a) + np.uint64(s)) & np.uint64(0xFFFFFFFF)) / 2.0**32
        out.append(np.minimum((u * size).astype(np.int64), size - 1))
    return out


def _spread(x: np.ndarray) -> np.ndarray:
    """common._spread_bits on arrays."""
    x = x & 0x7FFF
    for shift, mask in ((8, 0x00FF00FF), (4, 0x0F0F0F0F), (2, 0x33333333), (1, 0x55555555)):
        x = (x | (x << shift)) & mask
    return x


def test_fixed_order_is_a_texel_order(device):
    """The fixed order holds every photon index below the slots once, by the Morton code of its texel before the
    frame's rotation (all key bits); after a frame's rotation a warp's 32 points stay as close as a per-frame sort
    of the rotated points keeps them, except the warps the wrap-around cuts in two (each half still together): a
    few percent, about twice a warp's extent over the view's side."""
    r = frame(device, "cisp", True)
    p = r.photons
    for slots, w, h, counts in ((3_001, 48, 40, (3_001, 1_500)), (100_000, 512, 512, (100_000,))):
        table = p._fixed_texel_order(slots, w, h, counts).numpy()
        assert table.shape == (len(counts) * slots,)
        for i, n in enumerate(counts):
            order = table[i * slots : (i + 1) * slots]
            assert np.array_equal(np.sort(order), np.arange(slots))
            assert np.array_equal(np.sort(order[:n]), np.arange(n))  # the photons first, the slots past them after
            assert np.array_equal(np.sort(order[n:]), np.arange(n, slots))
            keys = wp.zeros(slots, dtype=wp.int32, device=device)
            index = wp.zeros(slots, dtype=wp.int32, device=device)
            wp.launch(C.photon_texel_keys, dim=slots, device=device, inputs=[w, h, n, 30, keys, index])
            assert np.all(np.diff(keys.numpy()[order[:n]]) >= 0)
            assert np.all(keys.numpy()[order[n:]] >= 1 << 30)
            assert np.array_equal(index.numpy(), np.arange(slots))
        assert p._fixed_texel_order(slots, w, h, counts) is p._fixed_texel_order(slots, w, h, counts)  # sorted once
    k = np.arange(slots)
    for scramble in ((0x9E3779B9, 0x7F4A7C15), (123456789, 987654321)):
        i, j = _r2_texels(k, scramble, w, h)
        code = _spread(i) | (_spread(j) << 1)
        extents = []
        for o in (order, np.argsort(code, kind="stable")):  # fixed, and this frame's points sorted
            o = o[: slots // 32 * 32]
            extents.append(np.maximum(np.ptp(i[o].reshape(-1, 32), 1), np.ptp(j[o].reshape(-1, 32), 1)))
        fixed, sorted_now = extents
        assert np.median(fixed) <= np.median(sorted_now) + 2
        cut = np.mean(fixed > w / 4)
        assert cut <= 3 * np.median(fixed) / w, cut


@pytest.mark.parametrize("ballot", [1, 0])
@pytest.mark.parametrize("block, grid", [(1, None), (32, None), (32, 2), (64, 2)])
def test_group_partition_is_a_stable_sort(device, rng, monkeypatch, block, grid, ballot):
    """photon_group_keys' block counts, their scan and photon_group_scatter give the stable sort of the photons by
    group (numpy's stable argsort), in blocks of one thread and in CPU blocks of 32 with a partial last block, all
    four groups (slots past the photon count last, left unwritten) and a padded tail; an inactive view writes nothing.
    On CUDA blocks of 32 and 64 with ``ballot`` run the warp-ballot ranks (two warps: the rows of the warps before;
    2 blocks over 6 or 3 tiles: the rounds' alternating rows); the CPU takes the tile scan either way."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    n = 5 * 32 + 11
    groups = rng.integers(0, C.SORT_GROUPS, n).astype(np.int32)
    order_in = rng.permutation(n).astype(np.int32)
    blocks = -(-n // block)
    grid = grid or blocks  # fewer blocks than tiles: each block takes every grid-th tile
    keys = wp.array(groups, dtype=wp.int32, device=device)
    order = wp.array(order_in, dtype=wp.int32, device=device)
    offsets = wp.array(np.zeros(C.SORT_GROUPS * blocks, np.int32), device=device)
    counts = np.zeros((C.SORT_GROUPS, blocks), np.int32)
    for b in range(blocks):
        counts[:, b] = np.bincount(groups[b * block:(b + 1) * block], minlength=C.SORT_GROUPS)
    scan = np.concatenate([[0], np.cumsum(counts.reshape(-1))[:-1]]).astype(np.int32)
    offsets.assign(scan)
    states = np.zeros(2, dtype=CascadeState.numpy_dtype())
    states["active"] = (1, 0)
    states["active_views"] = 1
    states = wp.array(states, dtype=CascadeState, device=device)
    out = wp.full(n + 7, -1, dtype=wp.int32, device=device)
    wp.launch_tiled(C.photon_group_scatter, dim=grid, block_dim=block, device=device,
                    inputs=[states, 0, n, keys, order, 0, 1, n, offsets, out, grid, ballot])
    want = order_in[np.argsort(groups, kind="stable")]
    last = np.sort(groups, kind="stable") == int(C.SORT_GROUP_LAST)
    want[last] = -1  # the last group (slots past the photon count) is not written: no kernel reads it
    np.testing.assert_array_equal(out.numpy()[:n], want)
    assert np.all(out.numpy()[n:] == -1)
    out.fill_(-1)  # an inactive view writes nothing
    wp.launch_tiled(C.photon_group_scatter, dim=grid, block_dim=block, device=device,
                    inputs=[states, 1, n, keys, order, 0, 1, n, offsets, out, grid, ballot])
    assert np.all(out.numpy() == -1)


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
