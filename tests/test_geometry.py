"""Photon geometry: exact per-photon origin and normal (the surface under the sample point, not the texel),
and light views fitted to what the camera sees (cascades), with the energy ledger closing."""

import numpy as np
import pytest
from scipy.ndimage import uniform_filter

from cisp_warp import analytic
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.scene.device import triangle_neighbors


def naive_neighbors(indices):
    """Dictionary twin of :func:`triangle_neighbors`."""
    tri = np.asarray(indices).reshape(-1, 3)
    edges = {}
    for t, (a, b, c) in enumerate(tri):
        for corner, e in enumerate(((b, c), (c, a), (a, b))):
            edges.setdefault(tuple(sorted(int(v) for v in e)), []).append((t, corner))
    out = np.full((len(tri), 3), -1)
    for users in edges.values():
        if len(users) == 2:
            (t0, c0), (t1, c1) = users
            out[t0, c0], out[t1, c1] = t1, t0
    return out


def test_triangle_neighbors_match_naive_twin(rng):
    scene = analytic.wavy_water(grid=9)
    np.testing.assert_array_equal(triangle_neighbors(scene.indices), naive_neighbors(scene.indices))
    # a fan with a non-manifold edge (three triangles on edge 0-1) leaves that edge unconnected
    fan = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [2, 1, 5]])
    np.testing.assert_array_equal(triangle_neighbors(fan), naive_neighbors(fan))
    perm = rng.permutation(len(scene.indices))
    np.testing.assert_array_equal(triangle_neighbors(scene.indices[perm]), naive_neighbors(scene.indices[perm]))


def render(device, method, rsm, photons, seed, fit="scene", **kw):
    scene = analytic.wavy_water(width=32, height=32, grid=64, **kw)
    r = Renderer(scene, RenderSettings(rsm_size=rsm, method=method, denoiser="none",
                                       photons=PhotonSettings(photons=photons, seed=seed)), device=device)
    r.render_frame()
    return r, r.aovs(include_rsm=False)["photon_map"][..., 0].astype(np.float64)


def rel_rmse(a, b):
    a, b = uniform_filter(a, 3), uniform_filter(b, 3)
    return float(np.sqrt(((a - b) ** 2).mean()) / b.mean())


@pytest.mark.parametrize("method", ["sspm", "cisp"])
def test_converged_caustic_does_not_depend_on_rsm_size(device, method):
    """Wavy water (a 3 cm triangle grid) seen close up. With one normal per texel, a coarse RSM draws a
    lattice of its texels into the folded caustic (relative RMSE 0.51 against noise 0.019 here); with each
    photon's own surface normal it agrees with a finer RSM within the photon noise (measured between two
    seeds of the fine RSM). sspm: 6 cm texels (two triangles each) against 1.5 cm. cisp also marches the
    coarse RSM's depth, which moves its end points a little (its own error, 1.6× the noise at 3 cm
    texels): 3 cm against 1.5 cm."""
    photons = 1_500_000
    _, coarse = render(device, method, 32 if method == "sspm" else 64, photons, seed=1)
    r, fine = render(device, method, 128, photons, seed=2)
    _, fine2 = render(device, method, 128, photons, seed=3)
    noise = rel_rmse(fine2, fine)
    err = rel_rmse(coarse, fine)
    assert fine.mean() > 0 and r.photons.read_ledger().closure() < 1e-5
    limit = 1.5 if method == "sspm" else 2.2
    assert err < limit * noise, f"RSM 32² vs 128²: {err:.3f}, noise {noise:.3f}"
