"""Naive twin of one SVGF à-trous level: per-pixel Python loops in float64, for tests only.

Written from the equations (Schied et al. 2017, eqs. 1-5), not from the kernel, so that the two
agree only if both say the same thing: see :func:`.kernels_svgf.atrous` for the formula.
"""

from __future__ import annotations

import numpy as np

B3 = {0: 3.0 / 8.0, 1: 1.0 / 4.0, 2: 1.0 / 16.0}  # 1-D B3-spline taps by |offset|
REC709 = np.array([0.2126, 0.7152, 0.0722])  # luminance weights
VARIANCE_EPS = 1.0e-10  # as kernels_svgf.VARIANCE_EPS
DEPTH_NOISE_REL = 1.0e-4  # as kernels_svgf.DEPTH_NOISE_REL


def depth_slope_naive(depth: np.ndarray) -> np.ndarray:
    """‖∇z‖ per pixel (H, W) from the smaller one-sided difference per axis to a neighbour with a surface."""
    h, w = depth.shape
    out = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            z = depth[y, x]
            if z <= 0:
                continue
            g = []
            for (ya, xa), (yb, xb) in (((y, x - 1), (y, x + 1)), ((y - 1, x), (y + 1, x))):
                diffs = [abs(z - depth[yy, xx]) for yy, xx in ((ya, xa), (yb, xb))
                         if 0 <= yy < h and 0 <= xx < w and depth[yy, xx] > 0]
                g.append(min(diffs) if diffs else 0.0)
            out[y, x] = np.hypot(g[0], g[1])
    return out


def atrous_level_naive(color: np.ndarray, variance: np.ndarray, depth: np.ndarray, normal: np.ndarray,
                       step: int, sigma_depth: float, sigma_normal: float, sigma_luminance: float,
                       conserve_energy: bool, noise_target: float | None = None, slope: np.ndarray | None = None):
    """One à-trous level. ``color`` (H, W, 3), ``variance`` (H, W), ``depth`` (H, W) [m] (0 = none),
    ``normal`` (H, W, 3); ``slope`` (H, W) [m/pixel] defaults to :func:`depth_slope_naive`. Returns
    (color_out (H, W, 3), variance_out (H, W)) in float64.

    ``noise_target`` (the caustics denoiser's gated levels): every w_pq (q ≠ p) is multiplied by
    clamp(2 min(R_p, R_q) / step − 1, 0, 1), where R = sqrt(g3x3(Var) / (4π τ² μ²)) is the footprint
    [pixels] a pixel still needs, μ the same 3x3 Gaussian's mean luminance and τ = ``noise_target``.

    Builds the level's matrix A row by row (out_p = Σ_q A_pq c_q, Var_p = Σ_q A_pq² Var_q) from the
    symmetric weights w_pq and their sums W_p = Σ_q w_pq (centre included): for q ≠ p, A_pq = w_pq / W_p
    (paper) or w_pq / max(W_p, W_q) (energy-conserving); A_pp = 1 − Σ_{q≠p} A_pq.
    """
    color = color.astype(np.float64)
    variance = variance.astype(np.float64)
    depth = depth.astype(np.float64)
    normal = normal.astype(np.float64)
    h, w = depth.shape
    lum = color @ REC709
    slope = depth_slope_naive(depth) if slope is None else slope.astype(np.float64)
    # 3x3 Gaussian of the variance over pixels with a surface
    var_blur = np.zeros((h, w))
    radius = np.full((h, w), np.inf)
    for y in range(h):
        for x in range(w):
            if depth[y, x] <= 0:
                continue
            kw, kv, kl = 0.0, 0.0, 0.0
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    yy, xx = y + dy, x + dx
                    if 0 <= yy < h and 0 <= xx < w and depth[yy, xx] > 0:
                        k = (0.5 if dx == 0 else 0.25) * (0.5 if dy == 0 else 0.25)
                        kw += k
                        kv += k * variance[yy, xx]
                        kl += k * lum[yy, xx]
            var_blur[y, x] = kv / kw
            if noise_target is not None:
                denom = 4.0 * np.pi * noise_target ** 2 * (kl / kw) ** 2
                radius[y, x] = np.sqrt(var_blur[y, x] / max(denom, 1e-30))
    def weights(y, x):
        """{(yy, xx): w_pq} over the taps q ≠ p with a surface."""
        z = depth[y, x]
        taps = {}
        for dy in range(-2, 3):
            for dx in range(-2, 3):
                yy, xx = y + dy * step, x + dx * step
                if (dx, dy) == (0, 0) or not (0 <= yy < h and 0 <= xx < w) or depth[yy, xx] <= 0:
                    continue
                zq = depth[yy, xx]
                phi_z = sigma_depth * (max(slope[y, x], slope[yy, xx]) * step * np.hypot(dx, dy)
                                       + DEPTH_NOISE_REL * max(z, zq))
                phi_l = sigma_luminance * np.sqrt(0.5 * (var_blur[y, x] + var_blur[yy, xx]) + VARIANCE_EPS)
                w_n = max(float(normal[y, x] @ normal[yy, xx]), 0.0) ** sigma_normal
                gate = float(np.clip(2.0 * min(radius[y, x], radius[yy, xx]) / step - 1.0, 0.0, 1.0))
                taps[yy, xx] = (B3[abs(dx)] * B3[abs(dy)] * w_n * gate
                                * np.exp(-abs(z - zq) / phi_z - abs(lum[y, x] - lum[yy, xx]) / phi_l))
        return taps

    weight_sum = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            if depth[y, x] > 0:
                weight_sum[y, x] = B3[0] ** 2 + sum(weights(y, x).values())
    color_out = np.zeros_like(color)
    variance_out = np.zeros_like(variance)
    for y in range(h):
        for x in range(w):
            if depth[y, x] <= 0:
                continue
            a = {q: wq / (max(weight_sum[y, x], weight_sum[q]) if conserve_energy else weight_sum[y, x])
                 for q, wq in weights(y, x).items()}
            a[y, x] = 1.0 - sum(a.values())
            color_out[y, x] = sum(aq * color[q] for q, aq in a.items())
            variance_out[y, x] = sum(aq * aq * variance[q] for q, aq in a.items())
    return color_out, variance_out
