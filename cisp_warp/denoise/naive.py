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


def blur_variance_naive(color: np.ndarray, variance: np.ndarray, depth: np.ndarray,
                        noise_target: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(g3x3(Var), R) per pixel (H, W), float64: the 3x3 Gaussian (1/4, 1/8, 1/16) of ``variance`` renormalised
    over pixels with a surface (paper eq. 5) and the footprint R = sqrt(g3x3(Var) / (4π τ² μ²)) [pixels] a pixel
    still needs, μ the same Gaussian's mean luminance of ``color`` and τ = ``noise_target`` (inf if None)."""
    h, w = depth.shape
    lum = color.astype(np.float64) @ REC709
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
                        kv += k * float(variance[yy, xx])
                        kl += k * lum[yy, xx]
            var_blur[y, x] = kv / kw
            if noise_target is not None:
                denom = 4.0 * np.pi * noise_target ** 2 * (kl / kw) ** 2
                radius[y, x] = np.sqrt(var_blur[y, x] / max(denom, 1e-30))
    return var_blur, radius


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
    var_blur, radius = blur_variance_naive(color, variance, depth, noise_target)
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


SPATIAL_VARIANCE_HISTORY = 4  # as kernels_svgf.SPATIAL_VARIANCE_HISTORY
MIN_BILINEAR_WEIGHT = 0.01  # as kernels_svgf.MIN_BILINEAR_WEIGHT
FLOAT_RESOLUTION = 1.0e-5  # as kernels_caustic.FLOAT_RESOLUTION
MAX_KEPT_RATIO = 64.0  # as kernels_caustic.MAX_KEPT_RATIO


def catmull_rom_naive(t: float) -> np.ndarray:
    """Catmull-Rom weights of the taps at offsets -1, 0, 1, 2 for a position t in [0, 1) past tap 0."""
    return np.array([((-t + 2) * t - 1) * t / 2, ((3 * t - 5) * t * t + 2) / 2, ((-3 * t + 4) * t + 1) * t / 2,
                     (t - 1) * t * t / 2])


def reproject_naive(depth: np.ndarray, normal: np.ndarray, motion: np.ndarray, history: dict, fields: tuple,
                    depth_tolerance: float, normal_tolerance: float, cubic: dict | None = None) -> tuple[dict, np.ndarray]:
    """Fetch ``history[f]`` for ``f`` in ``fields`` at each pixel's previous position (``motion``, (H, W, 2)
    [pixels]). A history texel is consistent when on screen, a surface with history n > 0, relative depth
    difference ≤ ``depth_tolerance``, normal cosine ≥ ``normal_tolerance``. Bilinear over the consistent
    taps, renormalised; where the position is fractional and all 16 texels of the 4x4 footprint are
    consistent, the channels ``cubic[f]`` (a list of channel indices, () for a scalar field) instead take the
    Catmull-Rom value, clamped to the range of the 2x2 taps. ``history`` holds ``depth``, ``normal``,
    ``frames`` (H, W) and the fields. Returns ({field: values}, valid (H, W) bool)."""
    cubic = cubic or {}
    h, w = depth.shape
    out = {f: np.zeros(history[f].shape, np.float64) for f in fields}
    valid = np.zeros((h, w), bool)

    def ok(ty, tx, z, n):
        if not (0 <= tx < w and 0 <= ty < h):
            return False
        zq = history["depth"][ty, tx]
        return bool(history["frames"][ty, tx] > 0 and zq > 0 and abs(zq - z) <= depth_tolerance * z
                    and float(history["normal"][ty, tx] @ n) >= normal_tolerance)

    for y in range(h):
        for x in range(w):
            z = depth[y, x]
            if z <= 0:
                continue
            px, py = x + motion[y, x, 0], y + motion[y, x, 1]
            x0, y0 = int(np.floor(px)), int(np.floor(py))
            fx, fy = px - x0, py - y0
            acc = {f: 0.0 for f in fields}
            sw = 0.0
            taps = []
            for dy in (0, 1):
                for dx in (0, 1):
                    tx, ty = x0 + dx, y0 + dy
                    if ok(ty, tx, z, normal[y, x]):
                        taps.append((ty, tx))
                        wt = (fx if dx else 1 - fx) * (fy if dy else 1 - fy)
                        sw += wt
                        for f in fields:
                            acc[f] = acc[f] + wt * history[f][ty, tx]
            if sw < MIN_BILINEAR_WEIGHT:
                continue
            valid[y, x] = True
            for f in fields:
                out[f][y, x] = acc[f] / sw
            if (fx > 0 or fy > 0) and len(taps) == 4 and all(
                    ok(y0 + j, x0 + i, z, normal[y, x]) for j in range(-1, 3) for i in range(-1, 3)):
                wx, wy = catmull_rom_naive(fx), catmull_rom_naive(fy)
                for f, channels in cubic.items():
                    value = sum(wy[j + 1] * wx[i + 1] * np.asarray(history[f][y0 + j, x0 + i], np.float64)
                                for j in range(-1, 3) for i in range(-1, 3))
                    lo = np.min([history[f][t] for t in taps], axis=0)
                    hi = np.max([history[f][t] for t in taps], axis=0)
                    clamped = np.clip(value, lo, hi)
                    if channels == ():
                        out[f][y, x] = clamped
                    else:
                        out[f][y, x, list(channels)] = clamped[list(channels)]
    return out, valid


def caustic_temporal_naive(irradiance: np.ndarray, depth: np.ndarray, normal: np.ndarray, motion: np.ndarray,
                           history: dict | None, settings, photon_m2: np.ndarray | None = None,
                           flow_used: np.ndarray | None = None) -> dict:
    """The caustics denoiser's temporal stage (:mod:`cisp_warp.denoise.kernels_caustic`, equations in its
    docstring) for one frame, in float64. ``irradiance`` (H, W, 3) [W/m²]; ``depth`` (H, W) [m] (0 = none);
    ``normal`` (H, W, 3); ``motion`` (H, W, 2) [pixels]; ``history``: the previous call's result (None: none).
    ``settings``: a :class:`cisp_warp.denoise.CausticSettings`; ``photon_m2`` (H, W) [(W/m²)²]: Σ luminance(e)²
    of the frame's photons per pixel, or None (read only with ``settings.use_photon_m2``); ``flow_used`` (H, W) bool:
    where ``motion`` is the caustic flow, the history there at most ``settings.flow_history`` frames. Returns dict(depth,
    normal, mean (H, W, 3), moments (H, W, 4): m1, m2, s², kept change ratio, frames, photon_var (the running
    mean of the window's photon_m2), variance (variance of the accumulated luminance), slope) for the next call."""
    s = settings
    depth = depth.astype(np.float64)
    normal = normal.astype(np.float64)
    irradiance = irradiance.astype(np.float64)
    h, w = depth.shape
    lum = irradiance @ REC709
    if history is None:
        prev, valid = {"mean": np.zeros((h, w, 3)), "moments": np.zeros((h, w, 4)), "frames": np.zeros((h, w)),
                       "photon_var": np.zeros((h, w))}, np.zeros((h, w), bool)
    else:
        prev, valid = reproject_naive(depth, normal, motion.astype(np.float64), history,
                                      ("mean", "moments", "frames", "photon_var"),
                                      s.depth_tolerance, s.normal_tolerance, cubic={"mean": (0, 1, 2), "moments": (0, 1)})
    n_prev = np.where(valid, prev["frames"], 0.0)
    if flow_used is not None:
        n_prev = np.where(flow_used, np.minimum(n_prev, settings.flow_history), n_prev)
    m1, m2, s2 = prev["moments"][..., 0], prev["moments"][..., 1], prev["moments"][..., 2]
    r_prev = prev["moments"][..., 3]  # the window's change ratio kept from the last frame
    res = {"depth": np.where(depth > 0, depth, 0.0), "normal": np.where(depth[..., None] > 0, normal, 0.0),
           "mean": np.zeros((h, w, 3)), "moments": np.zeros((h, w, 4)), "frames": np.zeros((h, w)),
           "photon_var": np.zeros((h, w)), "variance": np.zeros((h, w)), "slope": depth_slope_naive(depth)}
    r = s.change_radius
    k = s.change_sigmas
    for y in range(h):
        for x in range(w):
            z = depth[y, x]
            if z <= 0:
                continue
            qs = [(yy, xx) for yy in range(y - r, y + r + 1) for xx in range(x - r, x + r + 1)
                  if 0 <= yy < h and 0 <= xx < w and depth[yy, xx] > 0 and abs(depth[yy, xx] - z) <= s.depth_tolerance * z
                  and float(normal[yy, xx] @ normal[y, x]) >= s.normal_tolerance]
            e = np.array([lum[q] for q in qs])
            qset = set(qs)
            # a sixth of the mean squared second difference of three neighbours in a row, along rows or columns,
            # whichever is smaller
            dh = [(lum[q] - 2 * lum[q[0], q[1] - 1] + lum[q[0], q[1] - 2]) ** 2 for q in qs
                  if (q[0], q[1] - 1) in qset and (q[0], q[1] - 2) in qset]
            dv = [(lum[q] - 2 * lum[q[0] - 1, q[1]] + lum[q[0] - 2, q[1]]) ** 2 for q in qs
                  if (q[0] - 1, q[1]) in qset and (q[0] - 2, q[1]) in qset]
            var_pairs = min([np.mean(dd) for dd in (dh, dv) if dd], default=0.0) / 6
            # the photons' own variance: the window's mean Σ e² (0 where not given)
            p2 = np.mean([float(photon_m2[q]) for q in qs]) if s.use_photon_m2 and photon_m2 is not None else 0.0
            photon = min([v for v in e if v > 0], default=0.0)
            n = n_prev[y, x]
            bias2 = 0.0
            kept = 0.0
            pairs = var_pairs  # running mean over frames of the neighbour-difference variance
            if n <= 0:
                alpha, n_new, sigma2_est = 1.0, 1.0, (min(var_pairs, p2) if p2 > 0 else var_pairs)
            else:
                pairs = s2[y, x] + (var_pairs - s2[y, x]) / (min(n, s.max_history - 1) + 1)
                p2 = prev["photon_var"][y, x] + (p2 - prev["photon_var"][y, x]) / (min(n, s.max_history - 1) + 1)
                capped = min(pairs, p2) if p2 > 0 else pairs  # s², at most the running mean of the photons' own
                hq = [q for q in qs if n_prev[q] > 0]
                d = np.array([lum[q] - m1[q] for q in hq])
                nq = np.array([n_prev[q] for q in hq])
                var_t = np.array([max(m2[q] - m1[q] ** 2, 0.0) for q in hq]) * nq / np.maximum(nq - 1, 1)
                d2 = np.mean(d ** 2)
                temporal = np.mean(var_t)
                if n < SPATIAL_VARIANCE_HISTORY:
                    var_t = np.full(len(hq), capped)
                elif capped < temporal:  # scaled down to the spatial estimate, their spread kept
                    var_t = var_t * (capped / temporal)
                sigma2 = np.mean(var_t)
                sigma2_est = sigma2
                sigma2 = max(sigma2, (FLOAT_RESOLUTION * np.mean([m1[q] for q in hq])) ** 2)
                if sigma2 > np.mean(var_t):  # floored: a homogeneous window of sigma2
                    var_t = np.full(len(hq), sigma2)
                m1_sum = sum(m1[q] for q in hq)
                if m1_sum > 0:  # at most the window's Poisson quantum
                    photon = min(photon, var_t.sum() / m1_sum)
                history_noise = 1 + np.mean(1 / nq)
                spread = sigma2 * history_noise
                se_d2 = history_noise * np.sqrt(np.sum(2 * var_t ** 2 + photon ** 2 * var_t)) / len(hq)
                kn = k * min((n / 16) ** 0.25, 1.0)  # the threshold rises with the history's length
                bias2 = max(d2 - spread - kn * se_d2, np.mean(d) ** 2 - kn * kn * spread / len(hq), 0.0)
                ratio = bias2 / sigma2 if sigma2 > 0 else 0.0
                # the window's ratio is kept, fading by change_persistence a frame; this frame's at least the rest
                carried = s.change_persistence * r_prev[y, x]
                # full k, under 16 frames of history (kernels_caustic.FULL_THRESHOLD_HISTORY)
                confirmed = n < 16 and (d2 - spread - k * se_d2 > 0 or np.mean(d) ** 2 - k * k * spread / len(hq) > 0)
                kept = min(max(ratio if confirmed else 0.0, carried), MAX_KEPT_RATIO)
                ratio = max(ratio, carried)
                if n < SPATIAL_VARIANCE_HISTORY:
                    sigma2_est = min(capped, max(temporal, max(d2 - bias2, 0.0) / history_noise))
                if m1_sum > 0:  # the pixel alone, against its share of the window's variance (∝ its mean)
                    kp = s.pixel_sigmas
                    var_p = sigma2 * max(m1[y, x], lum[y, x]) * len(hq) / m1_sum * (1 + 1 / n)
                    bias2_p = max((lum[y, x] - m1[y, x]) ** 2 - kp * kp * var_p - kp * photon * np.sqrt(var_p), 0.0)
                    if bias2_p > 0:
                        ratio = max(ratio, bias2_p * (1 + 1 / n) / var_p)
                        bias2 = max(bias2, bias2_p)
                ratio = min(ratio, 1e30)  # as the kernel: an overflowing ratio resets (α = 1)
                inv_n = 1.0 / min(n, s.max_history - 1)
                alpha = (ratio + inv_n) / (ratio + inv_n + 1)
                n_new = 1.0 / ((1 - alpha) ** 2 * (ratio + inv_n) + alpha ** 2)
            res["mean"][y, x] = (1 - alpha) * prev["mean"][y, x] + alpha * irradiance[y, x]
            new_m1 = (1 - alpha) * m1[y, x] + alpha * lum[y, x]
            # blend of the history (variance v) and the new sample, less the change found
            own = ((1 - alpha) * max(m2[y, x] - m1[y, x] ** 2, 0.0)
                   + alpha * (1 - alpha) * max((lum[y, x] - m1[y, x]) ** 2 - bias2, 0.0))
            res["moments"][y, x] = (new_m1, new_m1 ** 2 + own, pairs, kept)
            sigma2_est = max(sigma2_est, own * n_new / max(n_new - 1, 1))
            res["frames"][y, x] = n_new
            res["photon_var"][y, x] = p2
            res["variance"][y, x] = sigma2_est / n_new
    return res


def caustic_frame_naive(irradiance: np.ndarray, depth: np.ndarray, normal: np.ndarray, motion: np.ndarray,
                        history: dict | None, settings, photon_m2: np.ndarray | None = None,
                        caustic_flow: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """One frame of the caustics denoiser: the motion from :func:`caustic_motion_naive` where ``caustic_flow``
    ((H, W, 4)) is given and ``settings.caustic_flow`` set, :func:`caustic_temporal_naive` (``photon_m2`` as there), then
    ``settings.atrous_levels`` gated, energy-conserving levels of :func:`atrous_level_naive`. Returns (output
    (H, W, 3) [W/m²], the history for the next call)."""
    s = settings
    flow_used = None
    if s.caustic_flow and caustic_flow is not None:
        motion, flow_used = caustic_motion_naive(motion, caustic_flow, s.flow_radius, s.flow_sigmas)
        motion = motion.astype(np.float32)
    t = caustic_temporal_naive(irradiance, depth, normal, motion, history, s, photon_m2, flow_used)
    color, variance = t["mean"], t["variance"]
    for level in range(s.atrous_levels):
        color, variance = atrous_level_naive(color, variance, t["depth"], t["normal"], 1 << level, s.sigma_depth,
                                             s.sigma_normal, s.sigma_luminance, True,
                                             noise_target=s.target(photon_m2 is not None),
                                             slope=t["slope"])
    return color, t


def caustic_motion_naive(motion: np.ndarray, flow: np.ndarray, radius: int, sigmas: float) -> tuple[np.ndarray, np.ndarray]:
    """Twin of :func:`cisp_warp.denoise.kernels_caustic.caustic_motion`: ``motion`` (H, W, 2) [pixels], ``flow``
    (H, W, 4) (Σ D, Σ s_D², count per pixel); returns the (H, W, 2) motion the history is fetched by (the pooled
    caustic flow of the (2 ``radius`` + 1)² neighbourhood where |D̄ − motion|² > ``sigmas``² · mean s_D², else
    ``motion``) and where the flow was taken ((H, W) bool)."""
    h, w = motion.shape[:2]
    pad = np.zeros((h + 2 * radius, w + 2 * radius, 4))
    pad[radius:radius + h, radius:radius + w] = flow
    pooled = sum(pad[dy:dy + h, dx:dx + w] for dy in range(2 * radius + 1) for dx in range(2 * radius + 1))
    out = motion.astype(np.float64).copy()
    known = pooled[..., 3] > 0
    n = np.where(known, pooled[..., 3], 1.0)
    mean = pooled[..., :2] / n[..., None]
    dist2 = ((mean - motion) ** 2).sum(-1)
    use = known & (dist2 > sigmas * sigmas * pooled[..., 2] / n)
    out[use] = mean[use]
    return out, use
