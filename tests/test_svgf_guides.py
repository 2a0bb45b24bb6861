"""SVGF's guides written from the G-buffer alone before the photons are known (``SVGF.guides``, the concurrent frame's
shade lane), then ``denoise(guides_written=True)``: the same frame as ``denoise`` alone (reproject writing them), bit
for bit on the CPU, over frames whose G-buffers move (each frame writes the other history row)."""

import numpy as np
import warp as wp

from cisp_warp.denoise import SVGF, SVGFSettings

from test_denoise import moving_scene, upload

W, H = 40, 28  # steps 8 and 16 (the lattice levels whose guides reproject writes) at SVGF's 5 levels


def test_svgf_guides_first_equals_reproject_writing_them():
    out = {}
    for early in (False, True):
        svgf = SVGF(W, H, "cpu", SVGFSettings())
        assert sorted(svgf.lattice_guides) == [8, 16]
        o = wp.zeros(W * H, dtype=wp.vec3, device="cpu")
        frames = []
        for t in range(3):
            g, e, _ = moving_scene(t, W, H)
            g["motion"][..., 0] = -1.0
            g["tri_id"][:2, :5] = -1  # a corner without a surface
            a = upload(dict(g, irradiance=e), "cpu")
            if early:
                cur = (1 - int(svgf.parity.numpy()[0])) * W * H  # stale values the guide pass must overwrite
                svgf.hist_guide[cur : cur + W * H].fill_(wp.vec4(7.0))
                svgf.depth_slope.fill_(7.0)
                svgf.guides(a["depth"], a["normal"], a["tri_id"])
            svgf.denoise(a["irradiance"], a["depth"], a["normal"], a["motion"], a["tri_id"], o, guides_written=early)
            frames.append([o.numpy().copy(), svgf.depth_slope.numpy().copy(), svgf.filtered_variance.numpy().copy()]
                          + [x.numpy().copy() for x in svgf.lattice_guides.values()])
        frames.append([svgf.hist_guide.numpy().copy()[(1 - int(svgf.parity.numpy()[0])) * W * H:][: W * H]])
        out[early] = frames
    for fa, fb in zip(out[False], out[True]):
        for x, y in zip(fa, fb):
            np.testing.assert_array_equal(x, y)
    assert np.abs(out[True][-2][0]).max() > 0 and out[True][-2][1].max() > 0
