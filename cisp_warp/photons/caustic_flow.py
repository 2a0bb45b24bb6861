"""Caustic motion vectors: where the caustic under each camera pixel was the frame before, from the photons.

The caustics denoiser reprojects its history by the camera's motion vectors, which are the *surface's*: a caustic
that moves over a still floor (a turning sun, travelling waves) leaves its history behind, and at 3° of sun azimuth
a frame it moves more than its line width (docs/perf_notes.md section 18). The photons know better: a caustic line
is a fold of the map from light-space position u to landing point L(u, t), and at a fold (∂L/∂u singular across
the line) the line's own velocity across itself equals the landing velocity ∂L/∂t of the photons at fixed u, for
any light-space parametrisation u that moves smoothly with time (d/dt L(u_f(t), t) = L_u u_f' + L_t, and L_u u_f'
lies along the line). So the photons that make the caustic carry its motion.

"The same photon" across frames: not photon index k (the R2 sequence is Cranley-Patterson rotated every frame, so
photon k's light-space sample jumps by a random offset), nor a texel of the photon's own RSM view (fitted cascades
move with the camera), but a *cell* of the light's whole views (``LightMaps.pilot_views`` when fitted, as the
hidden-flux map uses): the first whole view holding the photon's origin on the specular surface, on a grid of
``flow_stride(...)`` RSM texels per cell (about ``FLOW_PHOTONS_PER_CELL`` photons a cell were a view's photons spread
over all of it). The cell's landing points this frame (camera pixels, continuous) are averaged; its displacement is
D = mean_{t−1} − mean_t, previous position minus current as the camera's motion vectors (a camera pan is in it).
Per-frame jitter: each frame's photons sit at other points of the cell, so D carries the landing spread of the cell's
photons, s_D² = spread_t / (n_t − 1) + spread_{t−1} / (n_{t−1} − 1) (spread: mean squared distance of the cell's
landings from their mean, both axes), an upper bound (the R2 points spread more evenly than independent ones).

Per camera pixel, ``flow`` holds (Σ Dx, Σ Dy, Σ s_D², count) over the photons stored there whose cell has two
landings or more in both frames: the count-weighted mean displacement of the photons landing there, and a
conservative variance of it (as if all came from one cell). The denoiser uses it only where it differs from the
surface's motion by more than its noise (:func:`cisp_warp.denoise.kernels_caustic.caustic_motion`).

Per frame (after :meth:`CausticFlow.begin`): the trace adds each stored photon to its cell's row ``1 − parity``
(:func:`add_landing`: Σ (q − c), Σ |q − c|², count, with c the cell's previous mean, so that float32 sums of pixel
coordinates near 10³ keep their spread), and records (cell + 1, pixel) in ``records`` (0: not stored);
:meth:`CausticFlow.finish` turns the row into (mean, spread, count) (:func:`finalize_cells`), splats each record's
displacement into ``flow`` (:func:`splat_flow`) and flips ``parity``. Nothing is allocated per frame; nothing is
read back.

Buffers (allocated once by :meth:`~.base.PhotonPass.keep_caustic_flow`):

``cells``    (2, Σ lights' cells) vec4: per cell, row ``parity[0]`` the last frame's (mean x, mean y [pixels], spread
             [pixels²], count); row ``1 − parity[0]`` this frame's sums, then the same once finalised
``records``  (Σ RSM views × slots,) vec2i: per photon slot, (cell + 1, camera pixel) where stored, else (0, 0)
``flow``     (H*W,) vec4: (Σ Dx, Σ Dy [pixels], Σ s_D² [pixels²], count) per camera pixel
``parity``   (1,) int32
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..raster.views import ViewParams, world_project

#: photons a cell the grid aims for were a whole view's photons spread over all of it (they fall on the specular
#: part only, and a fitted cascade concentrates them where the camera looks, so more there)
FLOW_PHOTONS_PER_CELL = 16
#: landings a cell needs in each frame for a displacement (its spread is unknown with one)
MIN_CELL_PHOTONS = 4.0


def flow_stride(view_width: int, view_height: int, photons: int) -> int:
    """RSM texels per cell along each axis of a whole view of ``view_width`` × ``view_height`` texels emitting
    ``photons``: about FLOW_PHOTONS_PER_CELL photons a cell (1 when the view is already that dense)."""
    texels = view_width * view_height
    return max(1, int(math.ceil(math.sqrt(FLOW_PHOTONS_PER_CELL * texels / max(1, photons)))))


@wp.func
def flow_cell(views: wp.array(dtype=ViewParams), map_w: int, map_h: int, x: wp.vec3) -> int:
    """Cell of the point ``x`` [m] (a photon's origin): in the first of the light's whole ``views`` whose image holds
    it, the cell of a ``map_w`` × ``map_h`` grid over that image, numbered view by view; -1 outside them all."""
    for v in range(views.shape[0]):
        view = views[v]
        q = world_project(view, x)
        if view.far > 0.0 and q[2] > 0.0 and q[0] >= 0.0 and q[1] >= 0.0 and q[0] < float(view.width) and \
                q[1] < float(view.height):
            i = wp.min(int(q[0] * float(map_w) / float(view.width)), map_w - 1)
            j = wp.min(int(q[1] * float(map_h) / float(view.height)), map_h - 1)
            return (v * map_h + j) * map_w + i
    return -1


@wp.func
def cell_shift(prev: wp.vec4, width: int, height: int) -> wp.vec2:
    """The point a cell's sums of this frame are taken about: its last mean where it had one, else the image
    centre [pixels]."""
    if prev[3] > 0.0:
        return wp.vec2(prev[0], prev[1])
    return wp.vec2(0.5 * float(width), 0.5 * float(height))


@wp.func
def add_landing(cells: wp.array2d(dtype=wp.vec4), parity: wp.array(dtype=wp.int32), records: wp.array(dtype=wp.vec2i),
                slot: int, cell: int, pix: int, q: wp.vec3, width: int, height: int):
    """A photon of ``cell`` (global index; < 0: none) stored at camera pixel ``pix``, landing at continuous pixel
    coordinates ``q`` (x, y): added to its cell's sums in row ``1 − parity[0]`` and recorded in ``records[slot]``."""
    if cell < 0:
        return
    prev = parity[0]
    c = cell_shift(cells[prev, cell], width, height)
    dx = q[0] - c[0]
    dy = q[1] - c[1]
    wp.atomic_add(cells, 1 - prev, cell, wp.vec4(dx, dy, dx * dx + dy * dy, 1.0))
    records[slot] = wp.vec2i(cell + 1, pix)


@wp.kernel
def zero_current(cells: wp.array2d(dtype=wp.vec4), parity: wp.array(dtype=wp.int32)):
    """Zero row ``1 − parity[0]`` of ``cells`` (this frame's)."""
    i = wp.tid()
    cells[1 - parity[0], i] = wp.vec4(0.0)


@wp.kernel
def finalize_cells(cells: wp.array2d(dtype=wp.vec4), parity: wp.array(dtype=wp.int32), width: int, height: int):
    """This frame's row of ``cells``, from sums about the shift (:func:`cell_shift`) to (mean x, mean y [pixels],
    spread [pixels²], count)."""
    i = wp.tid()
    prev = parity[0]
    s = cells[1 - prev, i]
    n = s[3]
    if n > 0.0:
        c = cell_shift(cells[prev, i], width, height)
        mx = s[0] / n
        my = s[1] / n
        cells[1 - prev, i] = wp.vec4(c[0] + mx, c[1] + my, wp.max(s[2] / n - mx * mx - my * my, 0.0), n)


@wp.kernel
def splat_flow(records: wp.array(dtype=wp.vec2i), cells: wp.array2d(dtype=wp.vec4), parity: wp.array(dtype=wp.int32),
               flow: wp.array(dtype=wp.vec4)):
    """Each recorded photon's cell displacement D = mean_{t−1} − mean_t [pixels] and its variance s_D² added to
    ``flow`` at its pixel, (D, s_D², 1), where its cell has MIN_CELL_PHOTONS landings or more in both frames."""
    t = wp.tid()
    r = records[t]
    if r[0] <= 0:
        return
    prev = parity[0]
    cur = cells[1 - prev, r[0] - 1]
    old = cells[prev, r[0] - 1]
    if cur[3] < MIN_CELL_PHOTONS or old[3] < MIN_CELL_PHOTONS:
        return
    s2 = cur[2] / (cur[3] - 1.0) + old[2] / (old[3] - 1.0)
    wp.atomic_add(flow, r[1], wp.vec4(old[0] - cur[0], old[1] - cur[1], s2, 1.0))


@wp.kernel
def flip(parity: wp.array(dtype=wp.int32)):
    parity[0] = 1 - parity[0]


class CausticFlow:
    """The caustic flow's buffers (module docstring) for ``lights`` (``LightMaps``), ``photons`` per light,
    ``slots`` photon slots per RSM view and a ``width`` × ``height`` camera."""

    def __init__(self, lights, photons: int, slots: int, width: int, height: int, device):
        self.device = wp.get_device(device)
        self.width, self.height = int(width), int(height)
        self.views, self.shape, self.base = [], [], []
        total = 0
        for lm in lights:
            views = lm.pilot_views if lm.fitted else lm.views
            n_views = len(lm.pilot) if lm.fitted else len(lm.rsm)
            edge = lm.rsm_size
            s = flow_stride(edge, edge, max(1, photons // n_views))
            w, h = (edge + s - 1) // s, (edge + s - 1) // s
            self.views.append(wp.clone(views))  # frozen: cells fixed on the surfaces while the light moves
            self.shape.append((w, h))
            self.base.append(total)
            total += n_views * w * h
        self.n_cells = max(1, total)
        self.cells = wp.zeros((2, self.n_cells), dtype=wp.vec4, device=self.device)
        self.slots = int(slots)
        self._record_base = np.cumsum([0] + [len(lm.rsm) for lm in lights]).tolist()
        self.records = wp.zeros(max(1, self._record_base[-1] * self.slots), dtype=wp.vec2i, device=self.device)
        self.flow = wp.zeros(self.width * self.height, dtype=wp.vec4, device=self.device)
        self.parity = wp.zeros(1, dtype=wp.int32, device=self.device)

    def record_offset(self, light_index: int, view_index: int) -> int:
        """First record slot of a light's RSM view."""
        return (self._record_base[light_index] + view_index) * self.slots

    def begin(self) -> None:
        """Zero this frame's cells, the records and the flow."""
        wp.launch(zero_current, dim=self.n_cells, device=self.device, inputs=[self.cells, self.parity])
        self.records.zero_()
        self.flow.zero_()

    def finish(self) -> None:
        """After every view's trace: this frame's cell means, the flow splat, the parity flip."""
        wp.launch(finalize_cells, dim=self.n_cells, device=self.device,
                  inputs=[self.cells, self.parity, self.width, self.height])
        wp.launch(splat_flow, dim=self.records.shape[0], device=self.device,
                  inputs=[self.records, self.cells, self.parity, self.flow])
        wp.launch(flip, dim=1, device=self.device, inputs=[self.parity])

    def trace_args(self, light_index: int, view_index: int) -> list:
        """The trace kernel's flow arguments for one RSM view."""
        w, h = self.shape[light_index]
        return [self.views[light_index], w, h, self.base[light_index], self.cells, self.parity, self.records,
                self.record_offset(light_index, view_index)]


def flow_naive(records: np.ndarray, cells_cur_sums: np.ndarray, cells_prev: np.ndarray, width: int,
               height: int) -> np.ndarray:
    """Numpy twin of :func:`finalize_cells` + :func:`splat_flow`: from this frame's records ((R, 2) int), this
    frame's cell sums about the shift ((C, 4)) and the last frame's finalised cells ((C, 4)), the (H*W, 4) flow."""
    cur = np.zeros_like(cells_cur_sums, dtype=np.float64)
    for i, s in enumerate(cells_cur_sums.astype(np.float64)):
        n = s[3]
        if n > 0:
            c = cells_prev[i, :2] if cells_prev[i, 3] > 0 else (0.5 * width, 0.5 * height)
            m = s[:2] / n
            cur[i] = (c[0] + m[0], c[1] + m[1], max(s[2] / n - m @ m, 0.0), n)
    flow = np.zeros((width * height, 4))
    for cell1, pix in records:
        if cell1 <= 0:
            continue
        a, b = cur[cell1 - 1], cells_prev[cell1 - 1].astype(np.float64)
        if a[3] < MIN_CELL_PHOTONS or b[3] < MIN_CELL_PHOTONS:
            continue
        flow[pix] += (b[0] - a[0], b[1] - a[1], a[2] / (a[3] - 1) + b[2] / (b[3] - 1), 1.0)
    return flow


__all__ = ["CausticFlow", "FLOW_PHOTONS_PER_CELL", "MIN_CELL_PHOTONS", "add_landing", "finalize_cells", "flow_cell",
           "flow_naive", "flow_stride", "splat_flow"]
