"""The per-pixel à-trous level (three launches): the caustics denoiser's ``levels="pixel"``.

:mod:`.kernels_atrous` holds the tiled level (a guide pass and one tiled launch) that SVGF and, by default, the
caustics denoiser run. This per-pixel form was the faster one on the gated levels against the first tiled level
(most pixels there have converged and skip their taps one by one, 2R <= step); the tiled level since rewritten
measured faster on an H100 (1080p, the caustics denoiser's 4 levels: pool 0.87 against 1.19 ms, Cornell box 0.80
against 1.33 ms; docs/perf_notes.md section 9). Same formula, same naive twin.

One level is three launches over ``dim=(height, width)``:

1. :func:`atrous_prepare` reads each pixel's 3x3 neighbourhood once and packs what every tap of the
   level needs into ``vec4``s: ``guide_a = (z [m], ‖∇z‖ [m/pixel], g3x3(Var), luminance)``,
   ``guide_b = (n_x, n_y, n_z, R [pixels])``, R the footprint the pixel still needs (gated levels only;
   1e30 otherwise), and ``color_variance = (c_r, c_g, c_b, Var)``. A tap of the filter then costs three
   aligned 16-byte loads and W_q instead of fourteen scattered ones.
2. :func:`atrous_weight_sum`: W_p = Σ_q w_pq.
3. :func:`atrous_filter`: c'_p = c_p + Σ_{q≠p} A_pq (c_q − c_p), Var'_p = Σ_q A_pq² Var_q, with
   A_pq = w_pq / max(W_p, W_q) (energy-conserving) or w_pq / W_p (the paper's gather).

w_pq (Schied et al. 2017, eqs. 3-5, made symmetric in p and q) is evaluated as one exponential:

    w_pq = h(dx) h(dy) · exp(σ_n ln max(0, n_p·n_q) − |z_p − z_q| / φ_z − |l_p − l_q| / φ_l) · g_pq

with φ_z = σ_z (max(‖∇z_p‖, ‖∇z_q‖) ‖p − q‖ + ε_z max(z_p, z_q)), φ_l = σ_l sqrt((g3x3(Var)_p + g3x3(Var)_q)/2 + ε)
(the paper's max(0, n_p·n_q)^σ_n, two exponentials and a power become one exp and one log), and the gate
g_pq = clamp(2 min(R_p, R_q) / step − 1, 0, 1): a level of tap spacing ``step`` acts fully between pixels
that both still need a footprint of ``step`` pixels and not at all where either needs less than half of it;
a pixel whose own R is below half the step keeps its value and skips its taps (converged regions are cheap).
For SVGF R = 1e30 and every gate is 1. Pixels without a surface (depth 0) take no part and come out 0.

The naive twin is :func:`cisp_warp.denoise.naive.atrous_level_naive`.
"""

from __future__ import annotations

import warp as wp

from .kernels_svgf import DEPTH_NOISE_REL, VARIANCE_EPS, b3_spline, luminance

# The 5x5 tap loops stay loops: unrolled (Warp's default, up to 16 iterations) the filter's 24 inlined taps
# made it 3x slower on an H100 (1080p pool, 5 levels: atrous_filter 8.0 -> 2.5 ms, atrous_weight_sum
# 2.7 -> 1.8 ms with max_unroll 1; tools/bench_denoise.py --max-unroll).
wp.set_module_options({"max_unroll": 1})

#: R of an ungated level [pixels]: larger than any step, so every gate is 1
UNGATED_RADIUS = wp.constant(1.0e30)
#: floor of 4π τ² μ² in R's denominator [(W/m²)²], so a pixel with no signal and no variance gets R = 0
GATE_EPS = wp.constant(1.0e-30)
FOUR_PI = wp.constant(12.566370614359172)


@wp.func
def footprint_radius(var_blur: float, mean_lum: float, noise_target: float) -> float:
    """R [pixels]: the standard deviation of a Gaussian footprint that brings the variance of the estimate,
    ``var_blur`` [(W/m²)²], down to (τ μ)², τ = ``noise_target`` relative, μ = ``mean_lum`` [W/m²].

    A normalised 2-D Gaussian of standard deviation R pixels averages independent pixel noise down by
    Σ w² = 1 / (4π R²), so R² = Var / (4π τ² μ²). A B3 à-trous level of spacing ``step`` has a standard
    deviation of ``step`` pixels per axis, which is what the gate compares R with.
    """
    return wp.sqrt(var_blur / wp.max(FOUR_PI * noise_target * noise_target * mean_lum * mean_lum, GATE_EPS))


@wp.kernel
def atrous_prepare(
    color_in: wp.array(dtype=wp.vec3),
    variance_in: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    slope: wp.array(dtype=wp.float32),
    width: int,
    height: int,
    gated: int,
    noise_target: float,
    guide_a: wp.array(dtype=wp.vec4),
    guide_b: wp.array(dtype=wp.vec4),
    color_variance: wp.array(dtype=wp.vec4),
):
    """Pack the level's per-pixel inputs (see the module docstring).

    Reads ``color_in`` (H*W vec3 [W/m²]), ``variance_in`` (H*W float32 [(W/m²)²], luminance variance),
    ``depth`` (float32 [m], 0 = none), ``normal`` (vec3), ``slope`` (float32 [m/pixel]). Writes
    ``guide_a`` = (z, slope, g3x3(Var), luminance), ``guide_b`` = (normal, R) and ``color_variance`` =
    (colour, Var) (H*W vec4; 0 without a surface). g3x3 is the 3x3 Gaussian (1/4, 1/8, 1/16) renormalised over pixels with a surface (paper
    eq. 5); with ``gated`` R comes from g3x3(Var) and the same Gaussian's mean luminance
    (:func:`footprint_radius`, relative ``noise_target``), else R = ``UNGATED_RADIUS``.
    """
    y, x = wp.tid()
    p = y * width + x
    z = depth[p]
    if z <= 0.0:
        guide_a[p] = wp.vec4(0.0)
        guide_b[p] = wp.vec4(0.0)
        color_variance[p] = wp.vec4(0.0)
        return
    sum_k = float(0.0)
    sum_v = float(0.0)
    sum_l = float(0.0)
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            qx = x + dx
            qy = y + dy
            if qx >= 0 and qx < width and qy >= 0 and qy < height:
                q = qy * width + qx
                if depth[q] > 0.0:
                    k = wp.where(dx == 0, 0.5, 0.25) * wp.where(dy == 0, 0.5, 0.25)
                    sum_k += k
                    sum_v += k * variance_in[q]
                    if gated != 0:
                        sum_l += k * luminance(color_in[q])
    var_blur = sum_v / sum_k
    radius = UNGATED_RADIUS
    if gated != 0:
        radius = footprint_radius(var_blur, sum_l / sum_k, noise_target)
    n = normal[p]
    c = color_in[p]
    guide_a[p] = wp.vec4(z, slope[p], var_blur, luminance(c))
    guide_b[p] = wp.vec4(n[0], n[1], n[2], radius)
    color_variance[p] = wp.vec4(c[0], c[1], c[2], variance_in[p])


@wp.func
def tap_weight(ga_p: wp.vec4, gb_p: wp.vec4, ga_q: wp.vec4, gb_q: wp.vec4, kernel_weight: float, dist: float,
               step: float, sigma_depth: float, sigma_normal: float, sigma_luminance: float) -> float:
    """w_pq of the module docstring from the packed guides; ``dist`` = ‖p − q‖ [pixels]."""
    n_dot = gb_p[0] * gb_q[0] + gb_p[1] * gb_q[1] + gb_p[2] * gb_q[2]
    gate = wp.clamp(2.0 * wp.min(gb_p[3], gb_q[3]) / step - 1.0, 0.0, 1.0)
    if n_dot <= 0.0 or gate <= 0.0:
        return 0.0
    phi_z = sigma_depth * (wp.max(ga_p[1], ga_q[1]) * dist + DEPTH_NOISE_REL * wp.max(ga_p[0], ga_q[0]))
    phi_l = sigma_luminance * wp.sqrt(0.5 * wp.max(ga_p[2] + ga_q[2], 0.0) + VARIANCE_EPS)
    e = sigma_normal * wp.log(n_dot) - wp.abs(ga_p[0] - ga_q[0]) / phi_z - wp.abs(ga_p[3] - ga_q[3]) / phi_l
    return kernel_weight * wp.exp(e) * gate


@wp.kernel
def atrous_weight_sum(
    guide_a: wp.array(dtype=wp.vec4),
    guide_b: wp.array(dtype=wp.vec4),
    width: int,
    height: int,
    step: int,
    sigma_depth: float,
    sigma_normal: float,
    sigma_luminance: float,
    weight_sum: wp.array(dtype=wp.float32),
):
    """W_p = Σ_q w_pq over the level's 5x5 taps ``step`` pixels apart, centre ((3/8)²) included; 0 without a
    surface. Reads the guides of :func:`atrous_prepare`; writes ``weight_sum`` (H*W float32, in (0, 1])."""
    y, x = wp.tid()
    p = y * width + x
    ga_p = guide_a[p]
    if ga_p[0] <= 0.0:
        weight_sum[p] = 0.0
        return
    gb_p = guide_b[p]
    s = float(step)
    sum_w = b3_spline(0) * b3_spline(0)
    if 2.0 * gb_p[3] > s:  # else every gate of p is 0
        for dy in range(-2, 3):
            for dx in range(-2, 3):
                qx = x + dx * step
                qy = y + dy * step
                if (dx != 0 or dy != 0) and qx >= 0 and qx < width and qy >= 0 and qy < height:
                    q = qy * width + qx
                    ga_q = guide_a[q]
                    if ga_q[0] > 0.0:
                        sum_w += tap_weight(ga_p, gb_p, ga_q, guide_b[q], b3_spline(dx) * b3_spline(dy),
                                            s * wp.sqrt(float(dx * dx + dy * dy)), s, sigma_depth, sigma_normal,
                                            sigma_luminance)
    weight_sum[p] = sum_w


@wp.kernel
def atrous_filter(
    color_variance: wp.array(dtype=wp.vec4),
    guide_a: wp.array(dtype=wp.vec4),
    guide_b: wp.array(dtype=wp.vec4),
    weight_sum: wp.array(dtype=wp.float32),
    width: int,
    height: int,
    step: int,
    sigma_depth: float,
    sigma_normal: float,
    sigma_luminance: float,
    conserve_energy: int,
    color_out: wp.array(dtype=wp.vec3),
    variance_out: wp.array(dtype=wp.float32),
):
    """One à-trous level (module docstring): reads ``color_variance`` (H*W vec4: colour [W/m²], luminance
    variance), the guides and ``weight_sum``; writes ``color_out`` (H*W vec3 [W/m²]) and ``variance_out``
    (H*W float32; 0 without a surface).

    ``conserve_energy != 0``: A_pq = w_pq / max(W_p, W_q) is symmetric, so what p takes from q, q gives to
    p and Σ_p c'_p = Σ_p c_p exactly; Σ_{q≠p} A_pq ≤ 1 − w_pp / W_p keeps it a convex combination.
    ``conserve_energy == 0``: the paper's normalised gather A_pq = w_pq / W_p (a constant stays constant,
    the image mean is biased where the luminance stops act).
    """
    y, x = wp.tid()
    p = y * width + x
    ga_p = guide_a[p]
    if ga_p[0] <= 0.0:
        color_out[p] = wp.vec3(0.0)
        variance_out[p] = 0.0
        return
    gb_p = guide_b[p]
    cv_p = color_variance[p]
    c_p = wp.vec3(cv_p[0], cv_p[1], cv_p[2])
    v_p = cv_p[3]
    s = float(step)
    if 2.0 * gb_p[3] <= s:  # every gate of p is 0: A_pp = 1
        color_out[p] = c_p
        variance_out[p] = v_p
        return
    w_p = weight_sum[p]
    sum_a = float(0.0)  # Σ_{q≠p} A_pq
    sum_dc = wp.vec3(0.0)  # Σ_{q≠p} A_pq (c_q − c_p)
    sum_av = float(0.0)  # Σ_{q≠p} A_pq² Var_q
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            qx = x + dx * step
            qy = y + dy * step
            if (dx != 0 or dy != 0) and qx >= 0 and qx < width and qy >= 0 and qy < height:
                q = qy * width + qx
                ga_q = guide_a[q]
                if ga_q[0] > 0.0:
                    w = tap_weight(ga_p, gb_p, ga_q, guide_b[q], b3_spline(dx) * b3_spline(dy),
                                   s * wp.sqrt(float(dx * dx + dy * dy)), s, sigma_depth, sigma_normal,
                                   sigma_luminance)
                    if w > 0.0:
                        a = w / wp.where(conserve_energy != 0, wp.max(w_p, weight_sum[q]), w_p)
                        cv_q = color_variance[q]
                        sum_a += a
                        sum_dc += a * (wp.vec3(cv_q[0], cv_q[1], cv_q[2]) - c_p)
                        sum_av += a * a * cv_q[3]
    a_centre = 1.0 - sum_a
    color_out[p] = c_p + sum_dc
    variance_out[p] = sum_av + a_centre * a_centre * v_p


def launch_atrous_level(color_in: wp.array, variance_in: wp.array, depth: wp.array, normal: wp.array,
                        slope: wp.array, width: int, height: int, step: int, sigma_depth: float,
                        sigma_normal: float, sigma_luminance: float, conserve_energy: bool,
                        guide_a: wp.array, guide_b: wp.array, color_variance: wp.array, weight_sum: wp.array,
                        color_out: wp.array, variance_out: wp.array, noise_target: float | None = None) -> None:
    """One à-trous level: :func:`atrous_prepare`, :func:`atrous_weight_sum`, :func:`atrous_filter`.

    Reads ``color_in`` (H*W vec3 [W/m²]), ``variance_in`` (H*W float32), ``depth`` (H*W float32 [m], 0 =
    none), ``normal`` (H*W vec3), ``slope`` (H*W float32 [m/pixel]); ``step`` is the tap spacing [pixels].
    ``noise_target`` (relative, e.g. 0.05): gate the level by the footprint the remaining variance needs;
    None: ungated (SVGF). Writes the scratch ``guide_a``/``guide_b``/``color_variance`` (H*W vec4) and
    ``weight_sum`` (H*W float32), and ``color_out``/``variance_out`` (may alias the inputs: the filter reads
    only the packed copies).
    """
    dim = (height, width)
    d = color_in.device
    gated = noise_target is not None
    wp.launch(atrous_prepare, dim=dim, device=d,
              inputs=[color_in, variance_in, depth, normal, slope, width, height, int(gated),
                      float(noise_target) if gated else 0.0],
              outputs=[guide_a, guide_b, color_variance])
    sigmas = [float(sigma_depth), float(sigma_normal), float(sigma_luminance)]
    wp.launch(atrous_weight_sum, dim=dim, device=d, inputs=[guide_a, guide_b, width, height, int(step), *sigmas],
              outputs=[weight_sum])
    wp.launch(atrous_filter, dim=dim, device=d,
              inputs=[color_variance, guide_a, guide_b, weight_sum, width, height, int(step), *sigmas,
                      int(conserve_energy)],
              outputs=[color_out, variance_out])
