"""The caustics denoiser (the default): reactive temporal accumulation of the *raw* photon map, then an
energy-conserving à-trous filter whose footprint follows the variance still left in the estimate.

Why not SVGF: SVGF feeds a filtered image back into its history (the paper's first à-trous level), so a
still caustic is blurred again every frame and converges to a blur; and its luminance edge stop is scaled
by the per-frame variance, which does not shrink as frames accumulate. Here

1. temporal (:mod:`.kernels_caustic`): the history is the running mean of the raw irradiance, reprojected
   through the motion vectors with SVGF's depth/normal consistency tests (Catmull-Rom where the 4x4
   footprint is one surface, so a camera pan does not blur it); a static caustic converges to the photon
   map's long-run mean. The frame's own noise is estimated from the photon map (neighbour differences) and,
   where the photon pass keeps it, capped by the photons' Σ e² per pixel (``photon_m2``). Where the new
   photons disagree with the history by more than its noise explains (moving water, a moving light) over the
   window or at the pixel alone, the history is cut back in proportion (the weight that minimises the blend's
   error for the measured bias), so an animated caustic follows within a few frames; a change found on a
   short history is kept for the next frames, fading (``change_persistence``), so a slow drift does not build
   a lagging history;
2. spatial (:mod:`.kernels_atrous`, gated levels): the variance of the *mean* (σ²/n, shrinking as frames
   accumulate) sets both the luminance edge stop and, per pixel, the footprint R still needed to bring the
   relative noise down to ``noise_target``; a level of spacing s acts only where R ≥ s/2, so the filter
   narrows as the estimate converges and vanishes once it has. Weights are symmetric and normalised by
   max(W_p, W_q): every level keeps the image's total irradiance exactly.

With ``caustic_flow`` (the default; the renderer measures the flow with cisp's point photons): the history is fetched along the caustic's own motion where the photon pass measured it
(:mod:`cisp_warp.photons.caustic_flow`: where the photons of the same light-space cell landed the frame before) and it
differs from the surface's beyond its noise (:func:`.kernels_caustic.caustic_motion`), at most ``flow_history``
frames of it (docs/perf_notes.md section 35: on the H100 at 960×540, 2M photons, a turning sun's caustic e/s 2.34 →
1.02, fast water 2.30 → 2.27, the camera pan and still scenes unchanged).

Inputs and output are SVGF's (:meth:`CausticDenoiser.denoise`); the naive twin is
:func:`cisp_warp.denoise.naive.caustic_frame_naive`.
"""

from __future__ import annotations

from dataclasses import dataclass

import warp as wp

from . import kernels_caustic as K
from .kernels_atrous import LATTICE_STEP, lattice_size, launch_atrous, launch_atrous_level, spare_outputs
from .kernels_svgf import flip_parity


@dataclass(frozen=True)
class CausticSettings:
    """Parameters of the caustics denoiser; every field is an argument of a kernel launch."""

    max_history: int = 64  #: cap on the effective history [frames] (then an exponential mean of weight 1/N)
    change_radius: int = 2  #: half width [pixels] of the window that tests the new photons against the history
    change_sigmas: float = 5.0  #: deviations of the window's new photons from the history beyond this many
    #: standard errors count as change (for a history of n < 16 frames, (n/16)^¼ of it: half after a reset)
    pixel_sigmas: float = 3.0  #: a pixel's own deviation beyond this many of its standard deviations (plus
    #: a photon's worth) counts as change there, however little of the window changed
    change_persistence: float = 0.7  #: factor by which the window's change ratio r = b²/σ², kept with the
    #: history, fades a frame; a frame's r is at least what is left (a caustic that moved keeps moving)
    atrous_levels: int = 4  #: à-trous levels, spacings 1, 2, 4, ... pixels (0: temporal accumulation only)
    noise_target: float = 0.05  #: relative noise τ the spatial footprint aims at (R from Var / (4π τ² μ²)), where the
    #: frame's variance comes from neighbour differences alone (no ``photon_m2``): they count a caustic's own
    #: gradient as noise (2-8x the Poisson variance on sharp bands, perf_notes section 19), so R comes out wide
    noise_target_m2: float = 0.015  #: τ where the photons' Σ e² caps the variance (``photon_m2`` given and
    #: ``use_photon_m2``, as the renderer does): the variance is honest there and the footprint may aim lower.
    #: H100, 1080p, 2M photons, 16 frames: 0.05 -> 0.015 took the pool 0.106 -> 0.086, the Cornell box 0.090 ->
    #: 0.079 relative RMSE (perf_notes section 25)
    sigma_depth: float = 1.0  #: σ_z of the depth edge stop (in units of the depth gradient)
    sigma_normal: float = 128.0  #: σ_n, exponent of the normal edge stop
    sigma_luminance: float = 2.0  #: σ_l, luminance edge stop in standard deviations of the mean
    depth_tolerance: float = 0.1  #: reprojection and change window: largest relative depth difference
    normal_tolerance: float = 0.9  #: reprojection and change window: smallest cosine between normals
    use_photon_m2: bool = True  #: cap each frame's variance estimate by the photons' own, Σ e² per pixel (the
    #: photon pass's ``photon_m2``), where :meth:`CausticDenoiser.denoise` is given it
    caustic_flow: bool = True  #: reproject the history along the caustic's own motion where the photon pass knows
    #: it (``caustic_flow`` of :meth:`CausticDenoiser.denoise`, photons/caustic_flow.py; the renderer asks cisp for it
    #: when set) and it differs from the surface's by more than its noise; the surface's motion elsewhere
    flow_sigmas: float = 3.0  #: k of that test: |caustic flow − surface motion|² > k² Var(caustic flow)
    flow_radius: int = 1  #: the caustic flow of a pixel pools the photons of its (2 r + 1)² neighbourhood
    flow_history: float = 2.0  #: at most this many frames of history where it was fetched along the caustic flow
    #: (2: the new frame weighs at least 1/3): a real caustic flow leaves a residual (the small preset's turning sun:
    #: 4% of the caustic a frame, its shape changes too) that the change test does not see and a longer history
    #: accumulates as bias (perf_notes section 35, moving light e/s at 96x72 / 192x144: 1.81 / 1.33 at 1, 1.86 / 1.28
    #: at 2, 2.00 / 1.32 at 4, 2.23 uncapped at 96x72)

    def target(self, photon_m2_given: bool) -> float:
        """The spatial footprint's τ for a frame with (``photon_m2_given`` and ``use_photon_m2``) or without the
        photons' Σ e²."""
        return self.noise_target_m2 if photon_m2_given and self.use_photon_m2 else self.noise_target

    def __post_init__(self):
        if self.max_history < 2:
            raise ValueError("max_history must be >= 2")
        if not 1 <= self.change_radius <= K.MAX_CHANGE_RADIUS:
            raise ValueError(f"change_radius must lie in [1, {K.MAX_CHANGE_RADIUS}]")
        if self.atrous_levels < 0:
            raise ValueError("atrous_levels must be >= 0")
        if self.change_sigmas <= 0.0 or self.pixel_sigmas <= 0.0:
            raise ValueError("change_sigmas and pixel_sigmas must be > 0")
        if not 0.0 <= self.change_persistence < 1.0:
            raise ValueError("change_persistence must lie in [0, 1)")
        if self.noise_target <= 0.0 or self.noise_target_m2 <= 0.0:
            raise ValueError("noise_target and noise_target_m2 must be > 0")
        if min(self.sigma_depth, self.sigma_normal, self.sigma_luminance) <= 0.0:
            raise ValueError("sigma_depth, sigma_normal and sigma_luminance must be > 0")
        if self.flow_sigmas <= 0.0 or self.flow_radius < 0 or self.flow_history < 1.0:
            raise ValueError("flow_sigmas must be > 0, flow_radius >= 0 and flow_history >= 1")
        if self.depth_tolerance <= 0.0 or not (-1.0 <= self.normal_tolerance <= 1.0):
            raise ValueError("depth_tolerance must be > 0 and normal_tolerance a cosine in [-1, 1]")


class CausticDenoiser:
    """Caustics denoiser for one ``width`` x ``height`` irradiance map on ``device``.

    History (2 x H*W vec4 each, so that a tap is one aligned 16-byte load; row ``parity[0]`` holds the last
    frame, the next frame writes the other row and flips ``parity`` on the device, so a captured CUDA graph
    replays every frame): ``hist_surface`` (z [m], 0 = no surface; normal), ``hist_mean`` (running mean of the
    raw photon map [W/m²]; effective frames n), ``hist_moments`` (luminance mean [W/m²], mean square,
    neighbour-difference variance s², kept change ratio), ``hist_photon_var`` (float32 [(W/m²)²], running mean
    of the window's ``photon_m2``; 0 without it); ``parity`` (1 int32).
    Per frame (H*W each): ``depth``/``normal`` (G-buffer copy; depth 0 without a surface; for the à-trous
    levels; packed as (z, normal) in ``hist_surface``'s new row, which the change window reads), ``prev_mean``
    (vec3 [W/m²]), ``prev_pairs`` (vec3) and ``stats`` (vec4) of the reprojection, ``integrated`` (vec3 [W/m²], the accumulated
    estimate), ``frames`` (float32), ``depth_slope`` (float32 [m/pixel]), ``temporal_variance`` (float32
    [(W/m²)²], variance of the accumulated luminance), and the à-trous levels' scratch: with ``levels="tiled"``
    (the default, :func:`.kernels_atrous.launch_atrous`) ``packed`` (2 x vec4: colour, Var, ping-ponged),
    ``guide`` (vec4: n, z), ``level_guides`` (vec4, the guide pass's output; at steps >= ``LATTICE_STEP`` in
    sub-lattice-major order, a little more than H*W), ``lattice`` (2 x vec4: those levels' input and guide copied
    in that order by their guide pass; None without such a level), ``filtered_variance`` (float32);
    with ``levels="pixel"`` (:func:`.kernels_atrous_pixel.launch_atrous_level`, three launches a level)
    ``guide_a``/``guide_b``/``color_variance`` (vec4), ``weight_sum`` (float32), ``filtered_color`` (2 x vec3),
    ``filtered_variance`` (2 x float32). Both give the same output (one naive twin).
    """

    def __init__(self, width: int, height: int, device, settings: CausticSettings = CausticSettings(),
                 levels: str = "tiled"):
        if levels not in ("tiled", "pixel"):
            raise ValueError(f"levels must be 'tiled' or 'pixel', got {levels!r}")
        self.levels = levels
        self.width = width
        self.height = height
        self.device = wp.get_device(device)
        self.settings = settings
        n = width * height
        d = self.device

        def one(dtype):
            return wp.zeros(n, dtype=dtype, device=d)

        def two(dtype):
            return wp.zeros((2, n), dtype=dtype, device=d)

        self.hist_surface = two(wp.vec4)
        self.hist_mean = two(wp.vec4)
        self.hist_moments = two(wp.vec4)
        self.hist_photon_var = two(wp.float32)
        self.parity = wp.zeros(1, dtype=wp.int32, device=d)
        self.depth = one(wp.float32)
        self.normal = one(wp.vec3)
        self.prev_mean = one(wp.vec3)
        self.prev_pairs = one(wp.vec3)
        self.stats = one(wp.vec4)
        self.integrated = one(wp.vec3)
        self.frames = one(wp.float32)
        self.temporal_variance = one(wp.float32)
        self.depth_slope = one(wp.float32)
        #: (H*W,) vec2 [pixels]: the motion the history is fetched by, the caustic's where known (settings.caustic_flow)
        self.motion_used = one(wp.vec2) if settings.caustic_flow else None
        #: (H*W,) float32: 1 where the history was fetched along the caustic flow, else 0 (settings.caustic_flow)
        self.flow_used = one(wp.float32) if settings.caustic_flow else wp.zeros(0, dtype=wp.float32, device=d)
        if levels == "tiled":
            self.packed = one(wp.vec4), one(wp.vec4)
            self.guide = one(wp.vec4)
            # levels of step >= LATTICE_STEP read their input, guide and level_guides in sub-lattice-major order
            # (perf_notes section 11): a little more than H*W entries each, the input and guide copied there by
            # the level's guide pass
            lattice = max([lattice_size(width, height, 1 << k) for k in range(settings.atrous_levels)
                           if (1 << k) >= LATTICE_STEP], default=0)
            self.level_guides = wp.zeros(max(n, lattice), dtype=wp.vec4, device=d)
            self.lattice = (wp.zeros(lattice, dtype=wp.vec4, device=d),
                            wp.zeros(lattice, dtype=wp.vec4, device=d)) if lattice else None
            self.filtered_variance = one(wp.float32)
            spare_outputs(d)  # allocated here, not inside a frame that may be captured as a CUDA graph
        else:
            self.guide_a = one(wp.vec4)
            self.guide_b = one(wp.vec4)
            self.color_variance = one(wp.vec4)
            self.weight_sum = one(wp.float32)
            self.filtered_color = one(wp.vec3), one(wp.vec3)
            self.filtered_variance = one(wp.float32), one(wp.float32)

    @property
    def history_length(self) -> wp.array:
        """Effective frames behind each pixel's estimate after the last frame, H*W float32 (1 = disoccluded
        or reset, 0 = no surface)."""
        return self.frames

    @property
    def variance(self) -> wp.array:
        """Variance of the accumulated luminance [(W/m²)²] after the temporal stage, H*W float32."""
        return self.temporal_variance

    def reset(self) -> None:
        """Forget all history: the next frame is treated as disoccluded everywhere."""
        for a in (self.hist_surface, self.hist_mean, self.hist_moments, self.hist_photon_var):
            a.zero_()

    def denoise(self, irradiance_in: wp.array, depth: wp.array, normal: wp.array, motion: wp.array,
                tri_id: wp.array, out: wp.array, photon_m2: wp.array | None = None,
                caustic_flow: wp.array | None = None) -> None:
        """Denoise one frame.

        Reads ``irradiance_in`` (H*W vec3 [W/m²], the raw photon map), ``photon_m2`` (H*W float32 [(W/m²)²], the
        photon pass's Σ luminance(e)² per pixel, or None; read only with ``use_photon_m2``) and the camera
        G-buffer: ``depth`` (H*W float32 [m], 0 = none), ``normal`` (H*W vec3), ``motion`` (H*W vec2 [pixels],
        previous position minus pixel centre), ``tri_id`` (H*W int32, -1 = none). Writes ``out`` (H*W vec3
        [W/m²]; 0 where there is no surface). ``caustic_flow`` (H*W vec4: Σ Dx, Σ Dy [pixels], Σ s_D² [pixels²],
        count per pixel, :mod:`cisp_warp.photons.caustic_flow`; read only with ``settings.caustic_flow``): the history
        is fetched along the caustic's displacement where it differs from ``motion`` by more than its noise
        (:func:`.kernels_caustic.caustic_motion`). Nothing is allocated, read back or swapped on the host.
        """
        s = self.settings
        w, h = self.width, self.height
        dim = (h, w)
        d = self.device
        if s.caustic_flow and caustic_flow is not None:
            wp.launch(K.caustic_motion, dim=w * h, device=d,
                      inputs=[motion, caustic_flow, w, h, s.flow_radius, s.flow_sigmas * s.flow_sigmas],
                      outputs=[self.motion_used, self.flow_used])
            motion = self.motion_used
        elif s.caustic_flow:
            self.flow_used.zero_()
        wp.launch(K.reproject_history, dim=dim, block_dim=K.REPROJECT_THREADS, device=d,
                  inputs=[irradiance_in, depth, normal, motion, tri_id, self.hist_surface, self.hist_mean,
                          self.hist_moments, self.hist_photon_var, self.parity, w, h, s.depth_tolerance,
                          s.normal_tolerance, self.flow_used, float(s.flow_history)],
                  outputs=[self.depth, self.normal, self.prev_mean, self.prev_pairs, self.stats])
        m2 = photon_m2 if s.use_photon_m2 else None
        blocks, tiles_x = K.accumulate_blocks(w, h)
        wp.launch_tiled(K.accumulate, dim=blocks, block_dim=K.BLOCK_THREADS, device=d,
                        inputs=[irradiance_in, m2, self.hist_surface, self.prev_mean, self.prev_pairs, self.stats,
                                self.parity, w, h, tiles_x,
                                s.change_radius, float(s.max_history), s.change_sigmas, s.pixel_sigmas, s.change_persistence,
                                s.depth_tolerance, s.normal_tolerance],
                        outputs=[self.hist_mean, self.hist_moments, self.hist_photon_var, self.integrated,
                                 self.temporal_variance, self.frames, self.depth_slope])
        if s.atrous_levels == 0:
            wp.copy(out, self.integrated)
        tau = s.target(photon_m2 is not None)
        if self.levels == "tiled":
            self._tiled_levels(out, tau)
        else:
            self._pixel_levels(out, tau)
        wp.launch(flip_parity, dim=1, device=d, inputs=[self.parity])

    def _tiled_levels(self, out: wp.array, tau: float) -> None:
        """The gated levels as tiled launches (:func:`.kernels_atrous.launch_atrous`): the first level's guide pass
        packs the accumulated estimate, levels ping-pong it packed, the last one writes ``out`` (at a step of
        ``UNPACK_STEP`` or more packed into the free ping-pong buffer, unpacked densely)."""
        s = self.settings
        w, h = self.width, self.height
        for level in range(s.atrous_levels):
            last = level == s.atrous_levels - 1
            source = {} if level > 0 else dict(unpacked=(self.integrated, self.temporal_variance, self.depth, self.normal),
                                               pack_into=(self.packed[0], self.guide))
            launch_atrous(self.packed[level % 2] if level > 0 else None, self.guide if level > 0 else None,
                          self.depth_slope, w, h, 1 << level, s.sigma_depth, s.sigma_normal, s.sigma_luminance, True,
                          self.level_guides, noise_target=tau,
                          color_variance_out=None if last else self.packed[(level + 1) % 2],
                          color_out=out if last else None, variance_out=self.filtered_variance if last else None,
                          lattice=self.lattice, unpack_from=self.packed[(level + 1) % 2] if last else None, **source)

    def _pixel_levels(self, out: wp.array, tau: float) -> None:
        """The gated levels as per-pixel launches (:func:`.kernels_atrous_pixel.launch_atrous_level`)."""
        s = self.settings
        w, h = self.width, self.height
        color_src, variance_src = self.integrated, self.temporal_variance
        for level in range(s.atrous_levels):
            dst = level % 2
            color_dst = out if level == s.atrous_levels - 1 else self.filtered_color[dst]
            launch_atrous_level(color_src, variance_src, self.depth, self.normal, self.depth_slope,
                                w, h, 1 << level, s.sigma_depth, s.sigma_normal, s.sigma_luminance, True,
                                self.guide_a, self.guide_b, self.color_variance, self.weight_sum, color_dst, self.filtered_variance[dst],
                                noise_target=tau)
            color_src, variance_src = color_dst, self.filtered_variance[dst]
