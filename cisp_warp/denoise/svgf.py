"""Spatiotemporal variance-guided filtering (Schied et al. 2017) of the caustic irradiance map.

Follows Falcor's SVGFPass stage by stage (Reproject, FilterMoments, Atrous; FinalModulate is not
needed because the signal is irradiance [W/m²], never demodulated by albedo). Kernels live in
:mod:`.kernels_svgf` and :mod:`.kernels_atrous`; this module holds the settings and the pass, which
allocates every buffer once. The history double buffers are the two rows of (2, H*W) arrays, flipped on
the device by a one-element parity array, so a frame captured as a CUDA graph replays correctly.
"""

from __future__ import annotations

from dataclasses import dataclass

import warp as wp

from . import kernels_svgf as K
from .kernels_atrous import LATTICE_STEP, UNPACK_STEP, lattice_size, launch_atrous, packed_color_view, spare_outputs,\
    unpack_level


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


class SVGF:
    """SVGF denoiser for one ``width`` x ``height`` caustic irradiance map on ``device``.

    History (2 x H*W each; row ``parity[0]`` holds the last frame, the next frame writes the other row and
    flips ``parity`` on the device): ``hist_guide`` (vec4: n, z [m], z = 0 = no surface; one array of 2*H*W,
    row r at r*H*W), ``hist_color`` (vec3 [W/m²]), ``hist_moments`` (vec2: luminance mean, mean square),
    ``hist_length`` (int32 [frames]); ``parity`` (1 int32). During a frame, row ``1 - parity[0]`` holds this
    frame's: its guide (n, z) is the G-buffer copy the filters read, its moments and lengths what
    ``filter_moments`` reads (no per-frame copies of them).
    Per frame (H*W each): ``depth_slope`` (float32 [m/pixel]), ``integrated`` (vec3 [W/m²],
    the temporal accumulation; written only where it is the output or the colour history: without levels or
    with ``feedback_level`` -1; the levels read it packed in ``color_variance[0]``), ``color_variance`` (2 x
    vec4: colour, Var; the à-trous levels' packed input and output, ping-ponged; the input of a level of step >=
    ``LATTICE_STEP`` in its sub-lattice-major order, written so by the level before (a little more than H*W); a
    last level of step >= ``UNPACK_STEP`` writes its output there packed, unpacked into ``out`` densely),
    ``level_variance`` (1 or 2 x float32: the Var of a level's output but the last's, NO_SURFACE without a
    surface, what the next level's guide pass (or the step-2 level itself) reads of it, level k's in [k % 2]; None
    with fewer than 2 levels), ``level_guides`` (vec4: a
    level's ‖∇z‖, g3x3(Var), R from its guide pass; at steps >= ``LATTICE_STEP`` in sub-lattice-major order, a
    little more than H*W), ``lattice_guides`` ({step: vec4}: the guide in the sub-lattice-major order of the first
    two such steps, written by ``reproject``), ``lattice`` (2 x vec4: unused (one element), and the guide of any
    further step, copied in that order by its guide pass; None with fewer levels), ``filtered_variance``
    (float32: luminance variance of the last level, or of the temporal accumulation without levels).

    Deferred output (:meth:`denoise` with ``defer``, where :attr:`defers` holds): the last level's output stays
    packed in ``color_variance[atrous_levels % 2]``, its colour read in place through :attr:`packed_color` (an H*W
    vec3 view of it) by the caller, which also flips ``parity``; ``out`` and ``filtered_variance`` are written by
    :meth:`unpack` on demand (``deferred`` names the packed output and the ``out`` waiting for it; :attr:`variance`
    unpacks first).
    """

    def __init__(self, width: int, height: int, device, settings: SVGFSettings = SVGFSettings()):
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

        self.hist_guide = wp.zeros(2 * n, dtype=wp.vec4, device=d)
        self.hist_color = two(wp.vec3)
        self.hist_moments = two(wp.vec2)
        self.hist_length = two(wp.int32)
        self.parity = wp.zeros(1, dtype=wp.int32, device=d)
        self.integrated = one(wp.vec3)
        self.depth_slope = one(wp.float32)
        # levels of step >= LATTICE_STEP read their input, guide and level_guides in sub-lattice-major order; the
        # input written so by the previous level (into the ping-pong buffer, hence its size), the guide of the first
        # two such steps by reproject (one buffer each), of any further step copied by its level's guide pass into
        # lattice[1] (lattice[0], the input's copy, is not used: one element)
        steps = [1 << k for k in range(settings.atrous_levels) if (1 << k) >= LATTICE_STEP]
        lattice = max([lattice_size(width, height, st) for st in steps], default=0)
        self.color_variance = (wp.zeros(max(n, lattice), dtype=wp.vec4, device=d),
                               wp.zeros(max(n, lattice), dtype=wp.vec4, device=d))
        self.level_guides = wp.zeros(max(n, lattice), dtype=wp.vec4, device=d)
        self.lattice = (wp.zeros(1, dtype=wp.vec4, device=d),
                        wp.zeros(lattice if len(steps) > 2 else 1, dtype=wp.vec4, device=d)) if lattice else None
        # the Var of each level's output but the last, densely (NO_SURFACE without a surface): all the next level's
        # guide pass reads of its input; level k writes level_variance[k % 2] (section 85: the step-2 level reads its
        # input's copy itself while it writes its own: two buffers with 3 levels or more)
        self.level_variance = tuple(one(wp.float32) for _ in range(min(settings.atrous_levels - 1, 2))) or None
        self.lattice_guides = {st: wp.zeros(lattice_size(width, height, st), dtype=wp.vec4, device=d)
                               for st in steps[:2]}
        self.filtered_variance = one(wp.float32)
        self._packed_colors = tuple(packed_color_view(cv, n) for cv in self.color_variance)  # their colour, H*W vec3
        #: (packed output, ``out``) of the last deferred frame, until :meth:`unpack` writes it (and
        #: ``filtered_variance``); else None
        self.deferred: tuple | None = None
        spare_outputs(d)  # allocated here, not inside a frame that may be captured as a CUDA graph

    @property
    def history_length(self) -> wp.array:
        """History length [frames] of the last denoised frame, H*W int32 (1 = disoccluded, 0 = no surface): the
        row of ``hist_length`` that ``parity`` names (read back from the device: not for use inside a frame)."""
        return self.hist_length[int(self.parity.numpy()[0])]

    @property
    def defers(self) -> bool:
        """Whether :meth:`denoise` with ``defer`` leaves the output packed: the last level's step >= ``UNPACK_STEP``."""
        levels = self.settings.atrous_levels
        return levels > 0 and (1 << (levels - 1)) >= UNPACK_STEP

    @property
    def packed_output(self) -> wp.array:
        """The last level's packed output (``color_variance[atrous_levels % 2]``, vec4: colour [W/m²], Var, pixel
        order; where :attr:`defers`)."""
        return self.color_variance[self.settings.atrous_levels % 2]

    @property
    def packed_color(self) -> wp.array:
        """The colour of :attr:`packed_output`, an H*W vec3 view of it (16-byte stride): ``out``'s values in place."""
        return self._packed_colors[self.settings.atrous_levels % 2]

    @property
    def variance(self) -> wp.array:
        """Luminance variance after the last à-trous level of the last frame, H*W float32 (unpacked first where the
        frame was deferred, :meth:`unpack`)."""
        self.unpack()
        return self.filtered_variance

    def unpack(self) -> None:
        """Where the last frame was deferred (``deferred`` is not None): write its output, packed by the last level,
        densely into that ``out`` and ``filtered_variance`` (:func:`.kernels_atrous.unpack_level`, without the parity
        flip, which the caller did), once; else nothing. Outside a frame: where a reader needs them."""
        if self.deferred is None:
            return
        (packed, out), self.deferred = self.deferred, None
        wp.launch(unpack_level, dim=self.width * self.height, device=self.device,
                  inputs=[packed, out, self.filtered_variance, 0, spare_outputs(self.device)["parity"]])

    def reset(self) -> None:
        """Forget all history: the next frame is treated as disoccluded everywhere."""
        for a in (self.hist_guide, self.hist_color, self.hist_moments, self.hist_length):
            a.zero_()

    def guides(self, depth: wp.array, normal: wp.array, tri_id: wp.array) -> None:
        """The frame's guides from the G-buffer alone (``kernels_svgf.reproject_guides``: the guide row, its lattice
        copies, the depth slope), before the photons are known; then :meth:`denoise` with ``guides_written``."""
        w, h = self.width, self.height
        lg = list(self.lattice_guides.items()) + [(0, spare_outputs(self.device)["vec4"])] * 2
        wp.launch(K.reproject_guides, dim=(h, w), device=self.device,
                  inputs=[depth, normal, tri_id, self.parity, w, h, lg[0][0], lg[1][0]],
                  outputs=[self.hist_guide, self.depth_slope, lg[0][1], lg[1][1]])

    def denoise(self, irradiance_in: wp.array, depth: wp.array, normal: wp.array, motion: wp.array,
                tri_id: wp.array, out: wp.array, guides_written: bool = False, defer: bool = False) -> bool:
        """Denoise one frame.

        Reads ``irradiance_in`` (H*W vec3 [W/m²], the noisy photon map) and the camera G-buffer:
        ``depth`` (H*W float32 [m], 0 = none), ``normal`` (H*W vec3), ``motion`` (H*W vec2 [pixels],
        previous position minus pixel centre), ``tri_id`` (H*W int32, -1 = none). Writes ``out``
        (H*W vec3 [W/m²]; 0 where there is no surface). Nothing is allocated, read back or swapped on
        the host: the same launches with the same arguments every frame (CUDA-graph capturable).
        ``guides_written``: :meth:`guides` ran for this frame's G-buffer (``reproject`` does not write them again).
        ``defer`` (where :attr:`defers`): the last level's output stays packed, :attr:`packed_color` holds its colour,
        ``out`` and ``filtered_variance`` are not written (:meth:`unpack` writes them) and ``parity`` is not flipped:
        the caller flips it once after its last read of it in this frame (the composite's gather does). Returns
        whether it deferred.
        """
        s = self.settings
        w, h = self.width, self.height
        dim = (h, w)
        d = self.device
        temporal_only = s.atrous_levels == 0
        deferred = bool(defer) and self.defers
        self.deferred = (self.packed_output, out) if deferred else None  # an earlier one's is overwritten below
        lg = list(self.lattice_guides.items()) + [(0, spare_outputs(d)["vec4"])] * 2
        wp.launch(K.reproject, dim=dim, device=d,
                  inputs=[irradiance_in, depth, normal, motion, tri_id,
                          self.hist_guide, self.hist_color, self.hist_moments, self.hist_length,
                          self.parity, w, h, s.alpha_color, s.alpha_moments, s.max_history, s.depth_tolerance,
                          s.normal_tolerance, int(temporal_only or s.feedback_level == -1), int(temporal_only),
                          lg[0][0], lg[1][0], int(guides_written)],
                  outputs=[self.color_variance[0], self.depth_slope, self.integrated,
                           self.filtered_variance, lg[0][1], lg[1][1]])
        if s.feedback_level == -1:
            wp.launch(K.store_history, dim=w * h, device=d, inputs=[self.integrated, self.parity],
                      outputs=[self.hist_color])
        wp.launch(K.filter_moments, dim=(h, (w + K.MOMENTS_RUN - 1) // K.MOMENTS_RUN), device=d,
                  inputs=[self.hist_moments, self.hist_length, self.parity, self.hist_guide, self.depth_slope, w, h,
                          s.sigma_depth, s.sigma_normal],
                  outputs=[self.filtered_variance, self.color_variance[0]])
        if s.atrous_levels == 0:
            wp.copy(out, self.integrated)
        flipped = False
        for level in range(s.atrous_levels):
            last = level == s.atrous_levels - 1
            feedback = level == s.feedback_level
            ready = (1 << level) in self.lattice_guides
            step = 1 << level
            # a level's output in the next level's sub-lattice-major order where that one reads it so
            lattice_out = 2 * step if not last and self.lattice is not None and 2 * step >= LATTICE_STEP else 0
            flipped = launch_atrous(
                self.color_variance[level % 2], self.hist_guide, self.depth_slope, w, h, 1 << level, s.sigma_depth,
                s.sigma_normal, s.sigma_luminance, s.conserve_energy, self.level_guides,
                color_variance_out=None if last else self.color_variance[(level + 1) % 2],
                color_out=out if last else None, variance_out=self.filtered_variance if last else None,
                hist_color=self.hist_color if feedback else None, parity=self.parity if feedback else None,
                lattice=(self.lattice[0], self.lattice_guides[1 << level]) if ready else self.lattice,
                unpack_from=self.color_variance[(level + 1) % 2] if last else None, lattice_guide_ready=ready,
                flip=self.parity if last else None, guide_parity=self.parity,
                variance=self.level_variance[(level - 1) % 2] if level > 0 else None,
                input_lattice=level > 0 and self.lattice is not None and step >= LATTICE_STEP,
                variance_next=None if last else self.level_variance[level % 2], lattice_out=lattice_out,
                defer_unpack=deferred and last)
        if not flipped and not deferred:  # the last level's unpack flips it where it runs; deferred: the caller
            wp.launch(K.flip_parity, dim=1, device=d, inputs=[self.parity])
        return deferred
