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


def _cisp_frame(device, block: int, folded: bool, monkeypatch):
    """One ``cisp`` frame of the wavy water with photon blocks of ``block`` threads (3 ledger stripes) and the
    trace's final entries added by its epilogue (``folded``) or by the outcome pass: the ledger, the photon map and
    the outcome records (written with ``record_outcomes`` either way)."""
    from cisp_warp.photons.base import PhotonPass

    monkeypatch.setattr(PhotonPass, "FOLDED_OUTCOMES", folded)
    settings = RenderSettings(rsm_size=64, method="cisp", denoiser="none",
                              photons=PhotonSettings(photons=5_000, seed=7, sort_photons=False))
    r = Renderer(wavy_water(width=32, height=24), settings, device=device)
    r.set_concurrent(False)  # the records of one program's views (the concurrent one keeps them per lane)
    p = r.photons
    p.record_outcomes = True
    p.ledger_block = block
    p.ledger_stripes = 3
    p.ledger_rows = wp.zeros(3 * C.LEDGER_ROW, dtype=wp.vec3d, device=p.device)
    r.render_frame()
    return p.read_ledger(), p.photon_map.numpy(), p.outcome.numpy()[: p.photons_per_view(p.lights[0])]


@pytest.mark.parametrize("block", [1, 32])  # 128 dropped for the suite's 5 minutes: 32 already spans whole warps
def test_folded_outcomes_are_the_outcome_pass(device, block, monkeypatch):
    """``cisp``'s final entries added by the trace's epilogue (``kernels_cisp.final_add``: on CUDA the emission's
    reduce-scatter over six entries, 18 doubles; elsewhere a tile sum) against the twin, the outcome records added
    by ``ledger_add_outcomes`` after the trace: every entry to 1e-12 (only the order of the adds differs; on the CPU
    with blocks of one thread, the same adds in the same order: bit for bit), closing, with power in every entry a
    photon reaches here; the photon map and the records bit for bit the same (the trace is the same)."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    folded, map_f, rec_f = _cisp_frame(device, block, True, monkeypatch)
    twin, map_t, rec_t = _cisp_frame(device, block, False, monkeypatch)
    assert twin["stored"].sum() > 0 and twin["lost_camera_view"].sum() + twin["occluded"].sum() > 0
    np.testing.assert_allclose(folded.values, twin.values, rtol=1e-12, atol=1e-12 * twin["sampled"].max())
    if wp.get_device(device).is_cpu and block == 1:
        assert folded.values.tobytes() == twin.values.tobytes()
    assert folded.closure() < 1e-12
    np.testing.assert_array_equal(rec_f, rec_t)
    if wp.get_device(device).is_cpu:
        np.testing.assert_array_equal(map_f, map_t)
    else:  # the photon map's float32 atomics add in any order
        np.testing.assert_allclose(map_f, map_t, rtol=1e-5, atol=1e-6 * map_t.max())


@pytest.mark.parametrize("fast", [1 | int(C.OUTCOME_WIDE), 1, int(C.OUTCOME_WIDE), 0])
@pytest.mark.parametrize("runs", ["several", "one"])
def test_outcome_pass_sums_every_record(device, rng, monkeypatch, runs, fast):
    """ledger_add_outcomes against numpy: records of every final entry (and codes outside the mask, which it must
    leave out), summed by 3 blocks of 32 threads into 4 stripes, then folded: float64 sums to 1e-12. The records
    come in two runs of slots (and a partial third) of which the last 5 of each lie past the view's photon count
    (stale records of a fixed-size launch): those must be left out too; or in one run (the records no more than a
    run's slots: the pass then skips the division by the run), its last 5 past the count. Both block sums: the warp
    reduce-scatter (``fast`` bit 0, CUDA; the CPU keeps the tiles) and the two tile sums (the twin); the records in
    16-byte loads (bit 1, ``OUTCOME_WIDE``, CUDA; the CPU's plain loads) and in 4-byte ones; an inactive view adds
    nothing."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    n = 3 * 32 * 7 + 13
    finals = [e for e in range(C.LEDGER_ENTRIES) if (int(C.FINAL_ENTRIES) >> e) & 1]
    codes = rng.choice(finals + [-1], size=n)
    power = rng.random((n, 3), dtype=np.float32)
    mask = C.entry_mask(*finals[:-1])  # the last final entry is left out of the mask
    records = np.concatenate([power, codes[:, None].astype(np.float32)], axis=1)
    run = n // 2 if runs == "several" else n  # n is odd: the last record lies in a third, partial run
    live = np.arange(n) % run < run - 5
    states = wp.array([_state(True, 1)], dtype=CascadeState, device=device)
    stripes = wp.zeros(4 * C.LEDGER_ROW, dtype=wp.vec3d, device=device)
    ledger = wp.zeros(C.LEDGER_ENTRIES, dtype=wp.vec3d, device=device)
    block = 32 if wp.get_device(device).is_cpu else 64
    blocks = 3
    wp.launch_tiled(C.ledger_add_outcomes, dim=blocks, block_dim=block, device=device,
                    inputs=[wp.array(records, dtype=wp.vec4, device=device), n, blocks * block, mask, stripes, states, 0,
                            run - 5, run, fast])
    inactive = wp.array([_state(False, 1)], dtype=CascadeState, device=device)
    wp.launch_tiled(C.ledger_add_outcomes, dim=blocks, block_dim=block, device=device,
                    inputs=[wp.array(records, dtype=wp.vec4, device=device), n, blocks * block, mask, stripes, inactive,
                            0, run - 5, run, fast])
    wp.launch_tiled(C.ledger_fold, dim=C.LEDGER_ENTRIES, block_dim=4 if wp.get_device(device).is_cuda else 1,
                    device=device, inputs=[stripes, ledger])
    expect = np.zeros((C.LEDGER_ENTRIES, 3))
    for e in finals[:-1]:
        expect[e] = power[(codes == e) & live].astype(np.float64).sum(axis=0)
    np.testing.assert_allclose(ledger.numpy(), expect, rtol=1e-12)
    assert not stripes.numpy().any()  # folded stripes are zero again


@pytest.mark.parametrize("fast", [1 | int(C.OUTCOME_WIDE), 1, 0])
@pytest.mark.parametrize("runs", ["several", "one"])
def test_six_entry_outcome_pass_is_the_twin(device, rng, monkeypatch, runs, fast):
    """ledger_add_outcomes6 (CISP's six final entries, ``PhotonPass.OUTCOMES6``) against the twin
    (ledger_add_outcomes with the same mask) and numpy: records of every final entry and -1 (the entries outside 4-9
    must add nothing), stale records past the view's photons in each run, 3 blocks of 32 (CPU) or 64 threads into 4
    stripes: the same ledger bit for bit (the same sums in the same order; on CUDA to 1e-12: the block sums' order of
    warps may differ) and numpy's to 1e-12; an inactive view adds nothing."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    n = 3 * 32 * 7 + 13
    finals = [e for e in range(C.LEDGER_ENTRIES) if (int(C.FINAL_ENTRIES) >> e) & 1]
    codes = rng.choice(finals + [-1], size=n)
    power = rng.random((n, 3), dtype=np.float32)
    mask = int(C.FINAL6_ENTRIES)
    records = wp.array(np.concatenate([power, codes[:, None].astype(np.float32)], axis=1), dtype=wp.vec4, device=device)
    run = n // 2 if runs == "several" else n
    live = np.arange(n) % run < run - 5
    block = 32 if wp.get_device(device).is_cpu else 64
    blocks = 3
    got = {}
    for kernel in (C.ledger_add_outcomes6, C.ledger_add_outcomes):
        stripes = wp.zeros(4 * C.LEDGER_ROW, dtype=wp.vec3d, device=device)
        ledger = wp.zeros(C.LEDGER_ENTRIES, dtype=wp.vec3d, device=device)
        for active in (True, False):
            states = wp.array([_state(active, 1)], dtype=CascadeState, device=device)
            wp.launch_tiled(kernel, dim=blocks, block_dim=block, device=device,
                            inputs=[records, n, blocks * block, mask, stripes, states, 0, run - 5, run, fast])
        wp.launch_tiled(C.ledger_fold, dim=C.LEDGER_ENTRIES, block_dim=4 if wp.get_device(device).is_cuda else 1,
                        device=device, inputs=[stripes, ledger])
        got[kernel] = ledger.numpy()
    expect = np.zeros((C.LEDGER_ENTRIES, 3))
    for e in range(4, 10):
        expect[e] = power[(codes == e) & live].astype(np.float64).sum(axis=0)
    np.testing.assert_allclose(got[C.ledger_add_outcomes6], expect, rtol=1e-12)
    if wp.get_device(device).is_cpu:
        assert got[C.ledger_add_outcomes6].tobytes() == got[C.ledger_add_outcomes].tobytes()
    else:
        np.testing.assert_allclose(got[C.ledger_add_outcomes6], got[C.ledger_add_outcomes], rtol=1e-12)
    assert expect[4:10].all()


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


@pytest.mark.parametrize("block", [1, 32])
def test_pilot_texel_pass_is_max_luminance_and_book_outside_window(device, rng, monkeypatch, block):
    """``pilot_texel_pass`` (a fitted light's pilot in one launch) against its twins ``max_luminance`` and
    ``book_outside_window``: the same maximum, bit for bit, and the same bookings (the striped ledger bit for bit at
    the same block size) for an unturned window cutting texels, a turned one, and an empty one (every texel
    outside); texels without a specular surface book nothing and are left out of the maximum even where their solid
    angle is the largest; a partial last block."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    from cisp_warp.raster import ViewParams
    from cisp_warp.raster.kernels import TexelEmission

    if wp.get_device(device).is_cuda:
        block = max(block, 32)
    width, height = 40, 37
    n = width * height
    sa = rng.random(n, dtype=np.float32)
    tri = np.where(rng.random(n) < 0.3, -1, 0).astype(np.int32)
    tri[np.argmax(sa)] = -1
    e = TexelEmission()
    e.light_rgb = wp.vec3(2.0, 1.0, 0.5)
    e.texel_solid_angle = wp.array(sa, dtype=wp.float32, device=device)
    views = wp.array([ViewParams(), ViewParams(), ViewParams()], dtype=ViewParams, device=device)
    windows = wp.array(np.array([[3.5, 2.25, 30.75, 20.5], [5.0, 4.0, 33.0, 30.0], [0.0, 0.0, 0.0, 0.0]], np.float32),
                       dtype=wp.vec4, device=device)
    angles = wp.array(np.array([0.0, 0.3, 0.0], np.float32), dtype=wp.float32, device=device)
    tri_d = wp.array(tri, dtype=wp.int32, device=device)
    blocks = -(-n // block)
    outside = []
    for vi in range(3):
        common = [views, tri_d, e, width, n, windows, angles, vi, wp.vec2(20.0, 18.5), 1.25]
        twin_rows = wp.zeros(C.LEDGER_ROW, dtype=wp.vec3d, device=device)
        twin_max = wp.zeros(1, dtype=wp.float32, device=device)
        wp.launch_tiled(C.max_luminance, dim=-(-n // (block * C.MAX_LUM_TEXELS)), block_dim=block, device=device,
                        inputs=[views, vi, tri_d, e, n, twin_max])
        wp.launch_tiled(C.book_outside_window, dim=blocks, block_dim=block, device=device, inputs=common + [twin_rows])
        rows = wp.zeros(C.LEDGER_ROW, dtype=wp.vec3d, device=device)
        lum_max = wp.zeros(1, dtype=wp.float32, device=device)
        wp.launch_tiled(C.pilot_texel_pass, dim=blocks, block_dim=block, device=device,
                        inputs=common + [rows, lum_max])
        assert lum_max.numpy().tobytes() == twin_max.numpy().tobytes()
        assert 0.0 < lum_max.numpy()[0]
        got = rows.numpy()
        if block == 1 or wp.get_device(device).is_cpu:
            assert got.tobytes() == twin_rows.numpy().tobytes()
        else:  # the GPU adds its blocks in any order
            np.testing.assert_allclose(got, twin_rows.numpy(), rtol=1e-12)
        np.testing.assert_array_equal(got[C.L_SAMPLED], got[C.L_OUTSIDE])
        outside.append(got[C.L_OUTSIDE].sum())
    flux_total = (sa[tri >= 0].astype(np.float64)).sum() * 3.5
    assert 0.0 < outside[0] < flux_total and 0.0 < outside[1] < flux_total
    np.testing.assert_allclose(outside[2], flux_total, rtol=1e-5)  # an empty window: everything outside


def test_wide_clear_zeroes_every_accumulator(device):
    """``clear_frame_wide`` zeroes each array it is given whole, in 16-byte words and the 4-byte words past them (0-3),
    over arrays of unequal lengths with and without tails, an empty one and a view into a longer one (16-byte aligned
    as an allocation is), and nothing else; with fewer threads than words (strided). The pass's aliases
    (``PhotonPass._clear_wide``) cover every byte of its arrays, and ``begin`` clears with them."""
    whole = wp.full(64, 9.0, dtype=wp.float32, device=device)
    arrays = [wp.full(37, 1.5, dtype=wp.float32, device=device), wp.full(40, -1.0, dtype=wp.float32, device=device),
              wp.zeros(0, dtype=wp.float32, device=device), whole[8:19]]
    args = []
    for a in arrays:
        n16, n4 = a.capacity // 16, (a.capacity % 16) // 4
        args.append(wp.array(ptr=a.ptr if n16 else 0, dtype=wp.vec4, shape=(n16,), device=device))
    for a in arrays:
        n16, n4 = a.capacity // 16, (a.capacity % 16) // 4
        args.append(wp.array(ptr=a.ptr + 16 * n16 if n4 else 0, dtype=wp.float32, shape=(n4,), device=device))
    assert [x.shape[0] for x in args] == [9, 10, 0, 2, 1, 0, 0, 3]
    for threads in (4, 3 * 32):
        for a in arrays[:2]:
            a.fill_(2.5)
        whole.fill_(9.0)
        wp.launch(C.clear_frame_wide, dim=threads, device=device, inputs=[*args, threads])
        for a in arrays[:2]:
            assert not a.numpy().any() and not np.signbit(a.numpy()).any()
        w = whole.numpy()
        assert not w[8:19].any() and (w[:8] == 9.0).all() and (w[19:] == 9.0).all()
    settings = RenderSettings(rsm_size=32, method="cisp", denoiser="none", photons=PhotonSettings(photons=500, seed=7))
    p = Renderer(wavy_water(width=15, height=11), settings, device=device).photons  # 165 pixels: tails
    aliases, threads = p._clear_wide()
    arrays = (p.photon_map, p.photon_m2, p.hidden.all_flux, p._accumulators)
    for body, tail, arr in zip(aliases[:4], aliases[4:], arrays):
        assert body.ptr == arr.ptr and 16 * body.shape[0] + 4 * tail.shape[0] == arr.capacity
        assert tail.shape[0] == 0 or tail.ptr == arr.ptr + 16 * body.shape[0]
    assert any(t.shape[0] for t in aliases[4:])
    assert p._clear_wide() is p._clear_wide()  # made once
    for arr in arrays:
        arr.fill_(3)
    p.begin()  # clears, then books the light's brightest texel and the power outside its fitted views
    for arr in arrays[:3]:
        assert not arr.numpy().any()


def _pool_frames(device, fused: bool, monkeypatch, flags=None, sort=None) -> dict[str, np.ndarray]:
    """Two frames of the shipped pool (a fitted sun and a fitted spot, split shadow maps) at 48×27 with the launch
    folds of perf_notes section 63 on or off (their twins), or with ``flags`` (``PhotonPass`` attributes) set to
    ``fused`` instead: the ledger and every AOV."""
    import warnings
    from pathlib import Path

    from cisp_warp.photons.base import PhotonPass
    from cisp_warp.raster.light_maps import LightMaps, _ShadowView
    from cisp_warp.usd import load_usd

    switches = ((PhotonPass, "FUSED_PILOT_PASS"), (PhotonPass, "WIDE_CLEAR"), (_ShadowView, "FUSED_GATES"),
                (LightMaps, "FUSED_SOLID_ANGLES"), (PhotonPass, "FOLDED_OUTCOMES"))
    if flags is not None:
        switches = [(PhotonPass, name) for name in flags]
    for cls, name in switches:
        monkeypatch.setattr(cls, name, fused)
    path = Path(__file__).resolve().parents[1] / "scenes_usd" / "pool.usda"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stage = load_usd(path, width=48, height=27, device=device)
    r = Renderer(stage, RenderSettings(width=48, height=27, rsm_size=64, method="cisp", denoiser="svgf",
                                       photons=PhotonSettings(photons=8000, seed=3, sort_photons=sort)),
                 device=device)
    for _ in range(2):
        r.render_frame()
    out = {k: np.asarray(v) for k, v in r.aovs().items()}
    out["ledger"] = r.photons.read_ledger().values
    return out


def test_folded_launches_render_the_twins_frames(device, monkeypatch):
    """The frame with the folded launches (``pilot_texel_pass``, ``clear_frame_wide``, ``redraw_gate_split``,
    ``cascade_solid_angles_all``, the trace's final entries without the outcome pass) against the one with their twins: on the CPU every AOV and the ledger bit for bit
    (the same sums in the same order); on a GPU, whose atomics add in any order, the ledger to 1e-9 and the maps to
    1e-5 of their maximum."""
    fused = _pool_frames(device, True, monkeypatch)
    twin = _pool_frames(device, False, monkeypatch)
    assert fused.keys() == twin.keys() and fused["ledger"][C.L_OUTSIDE].sum() > 0.0
    exact = wp.get_device(device).is_cpu
    for k in fused:
        if exact:
            assert fused[k].tobytes() == twin[k].tobytes(), k
        elif k == "ledger":
            np.testing.assert_allclose(fused[k], twin[k], rtol=1e-9, atol=1e-9 * twin[k].max())
        elif np.issubdtype(fused[k].dtype, np.floating):
            np.testing.assert_allclose(fused[k], twin[k], rtol=1e-5, atol=1e-5 * max(1e-30, np.abs(twin[k]).max()))


def test_order15_paths_render_the_twins_frames(device, monkeypatch):
    """The pool's two frames (sorted photons: the group partition runs; the outcome pass of CISP's six entries) with
    ``BALLOT_GROUPS``, ``WIDE_OUTCOMES`` and ``OUTCOMES6`` on against off (perf_notes section 88): on the CPU every AOV
    and the ledger bit for bit; on a GPU the ledger to 1e-9, the maps to 1e-5 of their maximum (atomics' order)."""
    from cisp_warp.photons.base import PhotonPass

    monkeypatch.setattr(PhotonPass, "FOLDED_OUTCOMES", False)
    flags = ("BALLOT_GROUPS", "WIDE_OUTCOMES", "OUTCOMES6")
    new = _pool_frames(device, True, monkeypatch, flags, sort=True)
    twin = _pool_frames(device, False, monkeypatch, flags, sort=True)
    assert new.keys() == twin.keys() and new["ledger"][C.L_STORED].sum() > 0.0
    exact = wp.get_device(device).is_cpu
    for k in new:
        if exact:
            assert new[k].tobytes() == twin[k].tobytes(), k
        elif k == "ledger":
            np.testing.assert_allclose(new[k], twin[k], rtol=1e-9, atol=1e-9 * twin[k].max())
        elif np.issubdtype(new[k].dtype, np.floating):
            np.testing.assert_allclose(new[k], twin[k], rtol=1e-5, atol=1e-5 * max(1e-30, np.abs(twin[k]).max()))
