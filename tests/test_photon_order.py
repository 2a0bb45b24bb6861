"""Tracing photons grouped by their predicted march (not traced, reflected, refracted) and texel order changes only
the order of the threads: every photon is traced as without the sort, and the groups predict what the trace does."""

import numpy as np
import pytest
import warp as wp

from cisp_warp.photons import PhotonSettings
from cisp_warp.photons import common as C
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
    group, order = p._sort_keys.numpy()[:n].copy(), p._order.numpy()[:n].copy()
    assert np.array_equal(np.sort(order), np.arange(n))
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
    morton = keys.numpy()[order]
    for g in np.unique(group):
        assert np.all(np.diff(morton[group == g]) >= 0)
