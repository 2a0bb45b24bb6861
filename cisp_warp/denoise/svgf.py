"""Spatiotemporal variance-guided filtering (Schied et al. 2017) of the caustic irradiance map.

Follows Falcor's SVGFPass stage by stage (Reproject, FilterMoments, Atrous; FinalModulate is not
needed because the signal is irradiance [W/m²], never demodulated by albedo). Kernels live in
:mod:`.kernels_svgf`; this module holds the settings and the pass, which allocates every buffer once
and swaps its history double buffers with tuple swaps.
"""

from __future__ import annotations

from dataclasses import dataclass

import warp as wp

from . import kernels_svgf as K


@dataclass(frozen=True)
class SVGFSettings:
    """Parameters of SVGF; every field is an argument of a kernel launch."""

    alpha_color: float = 0.2  #: minimum EMA weight of the new frame's irradiance (paper α)
    alpha_moments: float = 0.2  #: minimum EMA weight of the new frame's luminance moments
    max_history: int = 32  #: cap on the history length [frames]
    atrous_levels: int = 5  #: à-trous levels, steps 1, 2, 4, ... pixels (0: temporal accumulation only)
    sigma_depth: float = 1.0  #: σ_z of the depth edge-stopping weight (in units of the depth gradient)
    sigma_normal: float = 128.0  #: σ_n, exponent of the normal edge-stopping weight
    sigma_luminance: float = 4.0  #: σ_l, luminance edge stop in units of the luminance standard deviation
    depth_tolerance: float = 0.1  #: reprojection: largest relative depth difference of a consistent tap
    normal_tolerance: float = 0.9  #: reprojection: smallest cosine between normals of a consistent tap
    feedback_level: int = 0  #: à-trous level whose output becomes the colour history (0 = first, as in
    #: the paper; -1 = the unfiltered temporal accumulation)
    conserve_energy: bool = True  #: à-trous with symmetric weights A_pq = w_pq / max(W_p, W_q) (image mean
    #: kept exactly); False: the paper's normalised gather, biased where luminance edge stops act

    def __post_init__(self):
        if not (0.0 < self.alpha_color <= 1.0 and 0.0 < self.alpha_moments <= 1.0):
            raise ValueError("alpha_color and alpha_moments must lie in (0, 1]")
        if self.max_history < 1:
            raise ValueError("max_history must be >= 1")
        if self.atrous_levels < 0:
            raise ValueError("atrous_levels must be >= 0")
        if min(self.sigma_depth, self.sigma_normal, self.sigma_luminance) <= 0.0:
            raise ValueError("sigma_depth, sigma_normal and sigma_luminance must be > 0")
        if self.depth_tolerance <= 0.0 or not (-1.0 <= self.normal_tolerance <= 1.0):
            raise ValueError("depth_tolerance must be > 0 and normal_tolerance a cosine in [-1, 1]")
        if not (-1 <= self.feedback_level < self.atrous_levels or self.feedback_level == -1):
            raise ValueError(f"feedback_level must lie in [-1, atrous_levels - 1], got {self.feedback_level}")


def launch_atrous_level(color_in: wp.array, variance_in: wp.array, depth: wp.array, normal: wp.array,
                        slope: wp.array, width: int, height: int, step: int, settings: SVGFSettings,
                        variance_blurred: wp.array, weight_sum: wp.array, color_out: wp.array,
                        variance_out: wp.array) -> None:
    """One à-trous level: :func:`.kernels_svgf.blur_variance`, :func:`.kernels_svgf.atrous_weight_sum`,
    :func:`.kernels_svgf.atrous`.

    Reads ``color_in`` (H*W vec3 [W/m²]), ``variance_in`` (H*W float32, luminance variance), ``depth``
    (H*W float32 [m], 0 = no surface), ``normal`` (H*W vec3), ``slope`` (H*W float32 [m/pixel], ‖∇z‖);
    ``step`` is the tap spacing [pixels]. Writes the scratch ``variance_blurred`` and ``weight_sum``
    (H*W float32 each) and ``color_out``/``variance_out``, which must not alias the inputs.
    """
    dim = (height, width)
    d = color_in.device
    wp.launch(K.blur_variance, dim=dim, device=d, inputs=[variance_in, depth, width, height],
              outputs=[variance_blurred])
    sigmas = [settings.sigma_depth, settings.sigma_normal, settings.sigma_luminance]
    wp.launch(K.atrous_weight_sum, dim=dim, device=d,
              inputs=[color_in, variance_blurred, depth, normal, slope, width, height, int(step), *sigmas],
              outputs=[weight_sum])
    wp.launch(K.atrous, dim=dim, device=d,
              inputs=[color_in, variance_in, variance_blurred, depth, normal, slope, weight_sum, width, height,
                      int(step), *sigmas, int(settings.conserve_energy)],
              outputs=[color_out, variance_out])


class SVGF:
    """SVGF denoiser for one ``width`` x ``height`` caustic irradiance map on ``device``.

    History (double-buffered, swapped after every frame; ``prev_*`` is what the next frame reads):
    ``*_depth`` (H*W float32 [m], 0 = no surface), ``*_normal`` (vec3), ``*_color`` (vec3 [W/m²]),
    ``*_moments`` (vec2: luminance mean, mean square), ``*_history`` (int32 [frames]).
    Scratch: ``integrated`` (vec3 [W/m²], temporal accumulation), ``depth_slope`` (float32 [m/pixel]),
    ``variance_blurred`` and ``weight_sum`` (float32), ``filtered_color`` (2 x vec3),
    ``filtered_variance`` (2 x float32). The Python-side tuple swaps mean a captured CUDA graph would
    have to be captured for both parities of the swap.
    """

    def __init__(self, width: int, height: int, device, settings: SVGFSettings = SVGFSettings()):
        self.width = width
        self.height = height
        self.device = wp.get_device(device)
        self.settings = settings
        n = width * height
        d = self.device

        def pair(dtype):
            return wp.zeros(n, dtype=dtype, device=d), wp.zeros(n, dtype=dtype, device=d)

        self.prev_depth, self.cur_depth = pair(wp.float32)
        self.prev_normal, self.cur_normal = pair(wp.vec3)
        self.prev_color, self.cur_color = pair(wp.vec3)
        self.prev_moments, self.cur_moments = pair(wp.vec2)
        self.prev_history, self.cur_history = pair(wp.int32)
        self.integrated = wp.zeros(n, dtype=wp.vec3, device=d)
        self.depth_slope = wp.zeros(n, dtype=wp.float32, device=d)
        self.variance_blurred = wp.zeros(n, dtype=wp.float32, device=d)
        self.weight_sum = wp.zeros(n, dtype=wp.float32, device=d)
        self.filtered_color = pair(wp.vec3)
        self.filtered_variance = pair(wp.float32)

    @property
    def history_length(self) -> wp.array:
        """History length [frames] of the last denoised frame, H*W int32 (1 = disoccluded, 0 = no surface)."""
        return self.prev_history

    @property
    def variance(self) -> wp.array:
        """Luminance variance after the last à-trous level of the last frame, H*W float32."""
        return self.filtered_variance[self.settings.atrous_levels % 2]

    def reset(self) -> None:
        """Forget all history: the next frame is treated as disoccluded everywhere."""
        for a in (self.prev_depth, self.prev_normal, self.prev_color, self.prev_moments, self.prev_history):
            a.zero_()

    def denoise(self, irradiance_in: wp.array, depth: wp.array, normal: wp.array, motion: wp.array,
                tri_id: wp.array, out: wp.array) -> None:
        """Denoise one frame.

        Reads ``irradiance_in`` (H*W vec3 [W/m²], the noisy photon map) and the camera G-buffer:
        ``depth`` (H*W float32 [m], 0 = none), ``normal`` (H*W vec3), ``motion`` (H*W vec2 [pixels],
        previous position minus pixel centre), ``tri_id`` (H*W int32, -1 = none). Writes ``out``
        (H*W vec3 [W/m²]; 0 where there is no surface). Nothing is allocated or read back.
        """
        s = self.settings
        w, h = self.width, self.height
        dim = (h, w)
        d = self.device
        wp.launch(K.reproject, dim=dim, device=d,
                  inputs=[irradiance_in, depth, normal, motion, tri_id,
                          self.prev_depth, self.prev_normal, self.prev_color, self.prev_moments, self.prev_history,
                          w, h, s.alpha_color, s.alpha_moments, s.max_history, s.depth_tolerance, s.normal_tolerance],
                  outputs=[self.cur_depth, self.cur_normal, self.integrated, self.cur_moments, self.cur_history])
        if s.feedback_level == -1:
            wp.copy(self.cur_color, self.integrated)
        wp.launch(K.filter_moments, dim=dim, device=d,
                  inputs=[self.cur_moments, self.cur_history, self.cur_depth, self.cur_normal,
                          w, h, s.sigma_depth, s.sigma_normal],
                  outputs=[self.filtered_variance[0], self.depth_slope])
        if s.atrous_levels == 0:
            wp.copy(out, self.integrated)
        color_src = self.integrated
        for level in range(s.atrous_levels):
            src, dst = level % 2, (level + 1) % 2
            color_dst = out if level == s.atrous_levels - 1 else self.filtered_color[dst]
            launch_atrous_level(color_src, self.filtered_variance[src], self.cur_depth, self.cur_normal,
                                self.depth_slope, w, h, 1 << level, s, self.variance_blurred,
                                self.weight_sum, color_dst, self.filtered_variance[dst])
            if level == s.feedback_level:
                wp.copy(self.cur_color, color_dst)
            color_src = color_dst
        self.prev_depth, self.cur_depth = self.cur_depth, self.prev_depth
        self.prev_normal, self.cur_normal = self.cur_normal, self.prev_normal
        self.prev_color, self.cur_color = self.cur_color, self.prev_color
        self.prev_moments, self.cur_moments = self.cur_moments, self.prev_moments
        self.prev_history, self.cur_history = self.cur_history, self.prev_history
