"""Wavefront splatting (``--splat wavefront``): photons on a regular grid of each RSM view, traced by the
method's own tracer (CISP's cascade or SSPM's BVH), each grid triangle's power splatted over the area its
corner photons land on. No noise, sharp focus lines, the ledger exact; see :mod:`.kernels_wavefront` (grid)
and :mod:`.kernels_splat` (splat).

>>> r = Renderer(scene, RenderSettings(method="cisp", photons=PhotonSettings(photons=512 ** 2, splat="wavefront")))

``photons`` sets the grid: about ``photons`` cells per light (split over its RSM views), each of
``cell`` × ``cell`` texels (cell = round(sqrt(texels / photons)), at least 1); 2 · (cells + 1)² photons are
traced per view (a refracted and a reflected sheet through every cell corner).

:func:`splat_numpy` is the naive twin of the splat (numpy, polygon clipping written the other way round:
each pixel square cut by the triangle's edges), for the tests.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from . import common as C
from . import kernels_splat as S
from . import kernels_wavefront as K
from .base import PhotonPass, frame_random

MAX_SPAN = 64  #: [pixels] a landing triangle wider or taller than this is not one wavefront: point fallback


def make_wavefront(photon_pass: PhotonPass, cam):
    """The pass's wavefront splat over the grid its settings name: the RSM's texels (:class:`WavefrontSplat`) or the
    specular mesh's triangles (:class:`~.meshgrid.MeshWavefrontSplat`)."""
    if photon_pass.settings.wavefront_grid == "mesh":
        from .meshgrid import MeshWavefrontSplat

        return MeshWavefrontSplat(photon_pass, cam)
    return WavefrontSplat(photon_pass, cam)


def grid_for(width: int, height: int, photons: int) -> tuple[int, int, int]:
    """(cell edge in texels, cells across, cells down) of a grid of about ``photons`` cells over a view."""
    cell = max(1, int(round(math.sqrt(width * height / max(photons, 1)))))
    return cell, -(-width // cell), -(-height // cell)


class WavefrontSplat:
    """The grid, its records and the splat for one photon pass; allocated once, launched per view.

    The grids lie over the light's RSM views as the pass emits from them: fitted to the camera (the
    cascades of ``LightViewSettings(fit="camera")``, the renderer's default) a grid covers each active
    cascade's window, its cells sized by that cascade's share of the light's photons, and leaves the texels
    inside the next finer window to that cascade (:func:`~.kernels_wavefront.texel_outside`); the power outside
    every window is booked ``outside_fitted_view`` by the pass (``PhotonPass.begin``). So the grid's cells go
    where the camera sees their light, as point photons do. Whole views (``fit="scene"``) keep one grid each.
    """

    def __init__(self, photon_pass: PhotonPass, cam):
        """``cam``: the pass's :class:`~.kernels_world.CameraBuffers` (its ``view`` is set each frame)."""
        self.p = photon_pass
        self.cam = cam
        d = photon_pass.device
        corners, tris = 1, 1
        for lm in photon_pass.lights:
            lm.keep_surface_maps()  # the grid's corners read the RSM texels' point and normal (kernels_wavefront)
            most = photon_pass.settings.photons if lm.fitted else photon_pass.photons_per_view(lm)  # one active view
            for r in lm.rsm:
                g = self.grid(r, most)
                corners = max(corners, (g.cells_x + 1) * (g.cells_y + 1))
                tris = max(tris, 4 * g.cells_x * g.cells_y)
        self.rec = K.Records()
        self.rec.entry = wp.zeros(2 * corners, dtype=wp.int32, device=d)
        self.rec.pos = wp.zeros(2 * corners, dtype=wp.vec3, device=d)
        self.rec.pix = wp.zeros(2 * corners, dtype=wp.int32, device=d)
        self.rec.dir = wp.zeros(2 * corners, dtype=wp.vec3, device=d)
        self.rec.throughput = wp.zeros(2 * corners, dtype=wp.vec3, device=d)
        self.tri_power = wp.zeros(tris, dtype=wp.vec3, device=d)
        self.tri_state = wp.zeros(tris, dtype=wp.int32, device=d)
        self.grids: list[K.Grid] = []  #: the grids of the last frame, in launch order

    @staticmethod
    def grid(r, photons: int) -> K.Grid:
        """The grid of about ``photons`` cells over RSM view ``r``."""
        g = K.Grid()
        g.width, g.height = r.width, r.height
        g.cell, g.cells_x, g.cells_y = grid_for(r.width, r.height, photons)
        return g

    def photons_traced(self) -> int:
        """Photons traced in the last frame over every light and view (two sheets per cell corner)."""
        return sum(2 * (g.cells_x + 1) * (g.cells_y + 1) for g in self.grids)

    def trace(self, frame: int, tracer: str, world=None) -> None:
        """Every emitting light view of the frame: cells, grid photons (``tracer`` "cisp" or "sspm"), splat."""
        p, s, dev = self.p, self.p.settings, self.p.device
        self.grids = []
        for li, lm in enumerate(p.lights):
            light_pos = wp.vec3(*np.asarray(lm.light.position, np.float32))
            kind = int(lm.light.kind)
            sc = lm.scene
            per = p.photons_per_view(lm)
            for vi, (params, r) in enumerate(zip(lm.host_views(), lm.rsm)):  # fitted: read back
                if not lm.active[vi]:
                    continue
                g = self.grid(r, per)
                self.grids.append(g)
                sp = r.specular
                cells = g.cells_x * g.cells_y
                corners = (g.cells_x + 1) * (g.cells_y + 1)
                p.launch_photons(K.grid_cells, cells, inputs=[
                    params, kind, light_pos, g, sp.position, sp.normal, lm.emission(r), sp.tri_id,
                    sc.triangle_material, sc.opacity, sc.albedo, p._max_lum_of[li], float(s.roughness_cutoff),
                    float(s.luminance_cutoff * lm.texel_scale[vi]), wp.vec4(*lm.skip_windows[vi]), self.tri_power,
                    p.ledger])
                if tracer == "cisp":  # p is the CISP pass: its depth bounds let the march skip hitless cells
                    rsm_bounds = p.build_rsm_bounds(lm, li, vi)
                    wp.launch(K.trace_grid_cisp, dim=2 * corners, device=dev, inputs=[
                        params, kind, light_pos, g, r.opaque_depth, rsm_bounds, sp.position, sp.normal, sp.tri_id,
                        sc.points, sc.normals, sc.indices, sc.triangle_material, sc.opacity, sc.ior, self.cam.view,
                        self.cam.depth, p.cam_bounds, self.cam.position, self.cam.normal, int(s.max_steps),
                        float(s.thickness), float(s.thickness_rel), p.t_max, int(s.cascade), self.rec])
                else:
                    _, _, seed = frame_random(s.seed, frame, li * 64 + vi)
                    wp.launch(K.trace_grid_world, dim=2 * corners, device=dev, inputs=[
                        params, kind, light_pos, g, world, self.cam,
                        seed, float(s.roughness_cutoff), float(s.thickness), float(s.thickness_rel), p.t_max,
                        int(s.max_bounces), self.rec])
                p.launch_photons(S.splat_triangles, 4 * cells, inputs=[
                    g, self.rec, self.tri_power, self.cam, float(s.thickness), float(s.thickness_rel), MAX_SPAN,
                    p.footprint_mode, p.photon_map, self.tri_state, p.ledger])

    def last_view_state(self) -> dict[str, np.ndarray]:
        """Host copies of the last traced view's grid, records and triangles (tests, the naive twin)."""
        g = self.grids[-1]
        corners = 2 * (g.cells_x + 1) * (g.cells_y + 1)
        tris = 4 * g.cells_x * g.cells_y
        return {"cell": g.cell, "cells_x": g.cells_x, "cells_y": g.cells_y,
                "entry": self.rec.entry.numpy()[:corners], "pos": self.rec.pos.numpy()[:corners],
                "pix": self.rec.pix.numpy()[:corners], "dir": self.rec.dir.numpy()[:corners],
                "throughput": self.rec.throughput.numpy()[:corners], "tri_power": self.tri_power.numpy()[:tris],
                "tri_state": self.tri_state.numpy()[:tris]}


# --- naive twin ------------------------------------------------------------------------------------------


def _clip_by_edge(poly: list, p: np.ndarray, q: np.ndarray, inside_sign: float) -> list:
    """The polygon's part on the inner side of the line pq (inner: sign of cross(q - p, x - p))."""
    def side(x):
        return inside_sign * ((q[0] - p[0]) * (x[1] - p[1]) - (q[1] - p[1]) * (x[0] - p[0]))

    out = []
    for i, x in enumerate(poly):
        y = poly[(i + 1) % len(poly)]
        sx, sy = side(x), side(y)
        if sx >= 0:
            out.append(x)
        if (sx >= 0) != (sy >= 0):
            out.append(x + (y - x) * (sx / (sx - sy)))
    return out


def pixel_triangle_overlap_np(tri: np.ndarray, px: int, py: int) -> float:
    """Area of the pixel square (px, py) cut by the three edges of ``tri`` (3×2), float64."""
    a, b, c = tri.astype(np.float64)
    orient = np.sign((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]))
    if orient == 0:
        return 0.0
    poly = [np.array(v, np.float64) for v in ((px, py), (px + 1, py), (px + 1, py + 1), (px, py + 1))]
    for p, q in ((a, b), (b, c), (c, a)):
        poly = _clip_by_edge(poly, p, q, orient)
        if not poly:
            return 0.0
    x, y = np.array([v[0] for v in poly]), np.array([v[1] for v in poly])
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def splat_numpy(state: dict, project, depth: np.ndarray, position: np.ndarray, normal: np.ndarray,
                footprint: np.ndarray, thickness: float, thickness_rel: float, near: float,
                max_span: int = MAX_SPAN) -> dict:
    """Naive twin of ``splat_triangles`` (exact footprint mode) for one view's ``state``
    (:meth:`WavefrontSplat.last_view_state`): loops in Python over triangles and the pixels of their bounds.

    ``state`` also names ``image_width`` [pixels]; ``project``: world points (N, 3) -> (N, 3) pixel x, y
    and depth; G-buffer arrays flat (H*W, ...);
    ``footprint``: (H*W,) exact pixel footprint [m²]. Returns the photon map (H*W, 3) [W/m²], the ledger
    parts it books {entry: (3,) W} and the triangle states.
    """
    h_w = depth.shape[0]
    emap = np.zeros((h_w, 3))
    book: dict[str, np.ndarray] = {}

    def add(name, v):
        book[name] = book.get(name, np.zeros(3)) + v

    cx, cy = state["cells_x"], state["cells_y"]
    row = cx + 1
    corners = row * (cy + 1)
    entry, pos, pix, dirs, thr = state["entry"], state["pos"].astype(np.float64), state["pix"], state["dir"], \
        state["throughput"].astype(np.float64)
    states = np.zeros(len(state["tri_power"]), np.int32)
    stored_id = C.LEDGER_NAMES.index("stored")
    names = C.LEDGER_NAMES
    W = state["image_width"]
    H = h_w // W

    def receiver(p, x0, n0):
        z = depth[p]
        return z > 0 and normal[p] @ n0 >= 0.9 and abs((position[p] - x0) @ n0) <= thickness + thickness_rel * z

    for t, power in enumerate(state["tri_power"].astype(np.float64)):
        if not power.any():
            continue
        half, c, sheet = t % 2, (t // 2) % (cx * cy), t // (2 * cx * cy)
        base = sheet * corners + (c // cx) * row + c % cx
        ids = (base, base + 1, base + row + 1) if half == 0 else (base, base + row + 1, base + row)
        e = [int(entry[i]) for i in ids]
        lost_camera_id = C.LEDGER_NAMES.index("lost_camera_view")
        on_surface = [i for i, v in zip(ids, e) if v == stored_id]
        ok = bool(on_surface) and all(v in (stored_id, lost_camera_id) for v in e)
        x = [pos[i] for i in ids]
        if ok:
            r = on_surface[0]
            n0 = normal[pix[r]].astype(np.float64)
            tol = thickness + thickness_rel * depth[pix[r]]
            ok = all(abs((xi - pos[r]) @ n0) <= tol for xi in x) and (project(np.array(x))[:, 2] > near).all()
            ok = ok and all(normal[pix[i]] @ n0 >= 0.9 and -dirs[i] @ normal[pix[i]] >= 0 for i in on_surface)
        if ok:
            s = project(np.array(x))[:, :2]
            lo, hi = s.min(0), s.max(0)
            ok = (hi - lo <= max_span).all()
        if ok:
            states[t] = 1
            x0, nref = pos[on_surface[0]], normal[pix[on_surface[0]]].astype(np.float64)
            p_eff = power * np.mean([thr[i] for i in ids], axis=0)
            area = 0.5 * abs((s[1, 0] - s[0, 0]) * (s[2, 1] - s[0, 1]) - (s[2, 0] - s[0, 0]) * (s[1, 1] - s[0, 1]))
            i0, j0 = np.floor(lo).astype(int)
            i1, j1 = np.floor(hi).astype(int)
            shares = []
            if area < 1e-6 or (i0 == i1 and j0 == j1):
                g = np.floor(s.mean(0)).astype(int)
                shares = [(g[0], g[1], 1.0)] if 0 <= g[0] < W and 0 <= g[1] < H else []
            else:
                for j in range(max(j0, 0), min(j1, H - 1) + 1):
                    for i in range(max(i0, 0), min(i1, W - 1) + 1):
                        o = pixel_triangle_overlap_np(s, i, j)
                        if o > 0:
                            shares.append((i, j, o / area))
            got = np.zeros(3)
            for i, j, f in shares:
                p = j * W + i
                if receiver(p, x0, nref):
                    emap[p] += p_eff * f / footprint[p]
                    add("stored", p_eff * f)
                else:
                    add("occluded", p_eff * f)
                got += p_eff * f
            add("lost_camera_view", p_eff - got)
            add("absorbed", power - p_eff)
            continue
        states[t] = 2
        valid = [i for i, v in zip(ids, e) if v >= 0]
        if not valid:
            add("lost_light_view", power)
            continue
        for i in valid:
            kept = power / len(valid) * thr[i]
            add("absorbed", power / len(valid) - kept)
            if entry[i] == stored_id:
                p = pix[i]
                if normal[p] @ -dirs[i] < 0 or depth[p] <= 0:
                    add("rejected", kept)
                else:
                    emap[p] += kept / footprint[p]
                    add("stored", kept)
            else:
                add(names[entry[i]], kept)
    return {"photon_map": emap, "ledger": book, "tri_state": states}
