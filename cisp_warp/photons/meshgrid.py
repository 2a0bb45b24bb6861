"""Wavefront splatting over the water mesh (``PhotonSettings(splat="wavefront", wavefront_grid="mesh")``, CLI
``--wavefront-grid mesh``): the grid's cells are the specular triangles of the scene cut ``n`` × ``n`` in their
own barycentric coordinates (:mod:`.kernels_meshgrid`), traced and splatted as the RSM grid's are.

``photons`` sets ``n``: about ``photons`` cells per light over all its specular triangles,
``n = round(sqrt(photons / T))`` (at least 1; T the grid's triangles: the scene's specular triangles, elongated
ones cut into pieces by :func:`grid_triangles`), so ``T · n²`` cells and ``2 · T · (n + 1)(n + 2)/2`` corner
photons per light (a refracted and a reflected sheet through every corner; a corner on an edge shared by two
triangles is traced once for each).

:func:`mesh_cells_numpy` is the naive twin of the cells' power (numpy, loops over triangles and sub-triangles).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..optics import fresnel_dielectric_np
from ..scene.model import LAYER_SPECULAR
from . import kernels_meshgrid as K
from . import kernels_meshrefine as R
from . import kernels_wavefront as KW
from .base import PhotonPass, frame_random

MAX_SPAN = 64  #: [pixels] a landing triangle wider or taller than this is not one wavefront: point fallback
REFINE_SHARE = 4  #: refinement holds sub-cells for 1/REFINE_SHARE of the grid's cells (the rest fall back)


ASPECT_MAX = 2.5  #: a grid triangle's longest edge over its height: more, and it is cut across


def grid_triangles(points: np.ndarray, indices: np.ndarray, tris: np.ndarray, photons: int):
    """The grid's triangles over scene triangles ``tris``: each one whole, or, when elongated (longest edge over
    height above ``ASPECT_MAX``), cut across its length into k stripes by lines parallel to its shortest edge
    (each stripe two triangles, the tip's one): k = min(its share of the budget's cells / 2, ceil(aspect /
    ASPECT_MAX)), the budget ``photons`` cells of equal area over all the triangles. The pieces then hold about
    one cell each (n = 1), or are cut n × n with the rest; they are as long as a k-th of the triangle (those at its
    tip as thin as the tip). Returns
    (scene triangle (T,) int32, corners in its barycentric coordinates (T, 3, 2) float32: weights of its
    vertices 1 and 2), each piece wound as its triangle."""
    p = points.astype(np.float64)
    idx = indices.reshape(-1, 3)[tris]
    x = p[idx]  # (S, 3 corners, 3)
    twice_area = np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)
    cell = math.sqrt(twice_area.sum() / max(photons, 1))  # a right isoceles cell's leg [m]: area cell² / 2
    edge = np.stack([np.linalg.norm(x[:, 2] - x[:, 1], axis=1), np.linalg.norm(x[:, 0] - x[:, 2], axis=1),
                     np.linalg.norm(x[:, 1] - x[:, 0], axis=1)], 1)  # edge opposite corner 0, 1, 2
    longest = edge.max(1)
    aspect = longest * longest / np.maximum(twice_area, 1e-30)  # longest edge over its height
    k = np.minimum(np.round(twice_area / (2.0 * cell * cell)), np.ceil(aspect / ASPECT_MAX)).astype(np.int64)
    k = np.where(aspect > ASPECT_MAX, np.maximum(k, 1), 1)
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    out_t, out_b = [], []
    for t, kk, e in zip(tris, k, edge):
        if kk == 1:
            out_t.append(t)
            out_b.append(corners)
            continue
        tip = int(e.argmin())  # the vertex opposite the shortest edge; the next two follow in winding order
        tp, pp, qp = corners[tip], corners[(tip + 1) % 3], corners[(tip + 2) % 3]
        for i in range(kk):
            s0, s1 = i / kk, (i + 1) / kk
            a0, a1 = tp + s0 * (pp - tp), tp + s1 * (pp - tp)
            b0, b1 = tp + s0 * (qp - tp), tp + s1 * (qp - tp)
            out_t.append(t)
            out_b.append(np.stack([a0, a1, b1]))
            if i > 0:  # the tip's stripe is one triangle
                out_t.append(t)
                out_b.append(np.stack([a0, b1, b0]))
    if not out_t:
        return np.zeros(0, np.int32), np.zeros((0, 3, 2), np.float32)
    return np.asarray(out_t, np.int32), np.asarray(out_b, np.float32)


def subdivision_for(triangles: int, photons: int) -> int:
    """Sub-triangles per triangle edge for about ``photons`` cells over ``triangles`` triangles."""
    return max(1, int(round(math.sqrt(photons / max(triangles, 1)))))


class MeshWavefrontSplat:
    """The mesh grid, its records and the splat for one photon pass; allocated once, launched per light view
    (the interface of :class:`~.wavefront.WavefrontSplat`)."""

    def __init__(self, photon_pass: PhotonPass, cam):
        """``cam``: the pass's :class:`~.kernels_world.CameraBuffers` (its ``view`` is set each frame)."""
        self.p = photon_pass
        self.cam = cam
        d = photon_pass.device
        sc = photon_pass.scene
        for lm in photon_pass.lights:  # mesh_cells reads each RSM view's shadow depth (fitted views keep none else)
            lm.keep_shadow_depth()
        specular = np.flatnonzero(sc.scene.triangle_layers() & LAYER_SPECULAR).astype(np.int32)
        tris, bary = grid_triangles(sc.scene.points, sc.scene.indices, specular, photon_pass.settings.photons)
        self.grid = K.MeshGrid()
        self.grid.tris = wp.array(tris if len(tris) else np.zeros(1, np.int32), dtype=wp.int32, device=d)
        self.grid.bary = wp.array(bary.reshape(-1, 2) if len(tris) else np.zeros((3, 2), np.float32), dtype=wp.vec2,
                                  device=d)
        self.grid.count = int(len(tris))
        n = subdivision_for(len(tris), photon_pass.settings.photons)
        self.grid.n, self.grid.cells, self.grid.corners = n, n * n, (n + 1) * (n + 2) // 2
        records = max(1, 2 * self.grid.count * self.grid.corners)
        cells = max(1, 2 * self.grid.count * self.grid.cells)
        self.rec = KW.Records()
        self.rec.entry = wp.zeros(records, dtype=wp.int32, device=d)
        self.rec.pos = wp.zeros(records, dtype=wp.vec3, device=d)
        self.rec.pix = wp.zeros(records, dtype=wp.int32, device=d)
        self.rec.dir = wp.zeros(records, dtype=wp.vec3, device=d)
        self.rec.throughput = wp.zeros(records, dtype=wp.vec3, device=d)
        self.tri_power = wp.zeros(cells, dtype=wp.vec3, device=d)
        self.tri_state = wp.zeros(cells, dtype=wp.int32, device=d)
        # refinement: cells whose corners diverge, cut m × m; up to REFINE_SHARE of the cells (the rest fall back)
        self.m = int(photon_pass.settings.wavefront_refine)
        self.refine_capacity = max(1, cells // REFINE_SHARE) if self.m > 1 else 1
        cm = (self.m + 1) * (self.m + 2) // 2
        self.flags = wp.zeros(cells, dtype=wp.int32, device=d)
        self.offsets = wp.zeros(cells, dtype=wp.int32, device=d)
        self.refine_list = wp.zeros(cells if self.m > 1 else 1, dtype=wp.int32, device=d)
        self.sub_rec = KW.Records()
        sub = self.refine_capacity * cm
        self.sub_rec.entry = wp.zeros(sub, dtype=wp.int32, device=d)
        self.sub_rec.pos = wp.zeros(sub, dtype=wp.vec3, device=d)
        self.sub_rec.pix = wp.zeros(sub, dtype=wp.int32, device=d)
        self.sub_rec.dir = wp.zeros(sub, dtype=wp.vec3, device=d)
        self.sub_rec.throughput = wp.zeros(sub, dtype=wp.vec3, device=d)
        self.sub_power = wp.zeros(self.refine_capacity * self.m * self.m, dtype=wp.vec3, device=d)
        self.sub_state = wp.zeros(self.refine_capacity * self.m * self.m, dtype=wp.int32, device=d)
        self.refined: list[tuple[int, int]] = []  #: per light of the last frame: (cells listed, cells cut m × m)
        self.grids: list[K.MeshGrid] = []  #: one entry per light traced in the last frame

    def photons_traced(self) -> int:
        """Corner photon slots of the last frame over every light (each corner traced in the view it lies in)."""
        cm = (self.m + 1) * (self.m + 2) // 2
        return 2 * self.grid.count * self.grid.corners * len(self.grids) + sum(r * cm for _, r in self.refined)

    def trace(self, frame: int, tracer: str, world=None) -> None:
        """Every light: its corner photons traced view by view (``tracer`` "cisp" or "sspm"), each view's cells
        booked, then all its cells splatted."""
        p, s, dev, g = self.p, self.p.settings, self.p.device, self.grid
        self.grids = []
        self.refined = []
        if g.count == 0:
            return
        total = g.count * g.cells
        corners = 2 * g.count * g.corners
        sc = p.scene
        for li, lm in enumerate(p.lights):
            light = lm.light
            light_pos = wp.vec3(*np.asarray(light.position, np.float32))
            rgb = wp.vec3(*light.radiometric_rgb.astype(np.float32))
            axis = wp.vec3(*np.asarray(light.direction, np.float32))
            kind = int(light.kind)
            n_views = len(lm.rsm)
            active = lm.active  # fitted: a device->host copy, as the RSM grid's views
            wp.launch(K.clear_records, dim=corners, device=dev, inputs=[self.rec])
            self.tri_power.zero_()
            self.grids.append(g)
            for vi, r in enumerate(lm.rsm):
                if not active[vi]:
                    continue
                p.launch_photons(K.mesh_cells, total, inputs=[
                    lm.views, lm.states, n_views, vi, kind, light_pos, rgb, axis, float(light.cone_angle),
                    float(light.cone_softness), g, r.shadow_depth, sc.points, sc.normals, sc.indices,
                    sc.triangle_material, sc.roughness, sc.opacity, sc.albedo, sc.ior, float(s.roughness_cutoff),
                    float(s.thickness), float(s.thickness_rel), self.tri_power, p.ledger])
                if tracer == "cisp":
                    rsm_bounds = p.build_rsm_bounds(lm, li, vi)
                    wp.launch(K.trace_mesh_cisp, dim=corners, device=dev, inputs=[
                        lm.views, lm.states, n_views, vi, kind, light_pos, g, r.opaque_depth, rsm_bounds, sc.points,
                        sc.normals, sc.indices, sc.triangle_material, sc.roughness, sc.opacity, sc.ior,
                        float(s.roughness_cutoff), self.cam.view, self.cam.depth, p.cam_bounds, self.cam.position,
                        self.cam.normal, int(s.max_steps), float(s.thickness), float(s.thickness_rel), p.t_max,
                        int(s.cascade), self.rec])
                else:
                    _, _, seed = frame_random(s.seed, frame, li * 64 + vi)
                    wp.launch(K.trace_mesh_world, dim=corners, device=dev, inputs=[
                        lm.views, lm.states, n_views, vi, kind, light_pos, g, world, self.cam, seed,
                        float(s.roughness_cutoff), float(s.thickness), float(s.thickness_rel), p.t_max,
                        int(s.max_bounces), self.rec])
            p.launch_photons(K.splat_mesh, 2 * total, inputs=[
                g, self.rec, self.tri_power, self.cam, float(s.thickness), float(s.thickness_rel), MAX_SPAN,
                p.footprint_mode, p.photon_map, self.tri_state, int(self.m > 1), p.ledger])
            if self.m > 1:
                self._refine(li, lm, active, tracer, frame, world, light_pos, kind)

    def _refine(self, li: int, lm, active: list[bool], tracer: str, frame: int, world, light_pos, kind: int) -> None:
        """The cells the splat left to refinement (``TRI_REFINE``), listed in cell order (a scan), cut m × m,
        their corners traced view by view, their sub-cells splatted; listed cells past the capacity fall back.
        Reads the list's length back (a device->host copy, as the fitted views' read-back)."""
        p, s, dev, g, m = self.p, self.p.settings, self.p.device, self.grid, self.m
        cells = 2 * g.count * g.cells
        wp.launch(R.refine_flags, dim=cells, device=dev, inputs=[self.tri_state, self.flags])
        wp.utils.array_scan(self.flags, self.offsets, inclusive=False)
        wp.launch(R.refine_scatter, dim=cells, device=dev, inputs=[self.flags, self.offsets, self.refine_list])
        ends = np.concatenate([self.offsets[cells - 1 : cells].numpy(), self.flags[cells - 1 : cells].numpy()])
        listed = int(ends.sum())
        refined = min(listed, self.refine_capacity)
        self.refined.append((listed, refined))
        if listed == 0:
            return
        cm = (m + 1) * (m + 2) // 2
        sc = p.scene
        if refined > 0:
            wp.launch(K.clear_records, dim=refined * cm, device=dev, inputs=[self.sub_rec])
            for vi, r in enumerate(lm.rsm):
                if not active[vi]:
                    continue
                if tracer == "cisp":
                    wp.launch(R.trace_refine_cisp, dim=refined * cm, device=dev, inputs=[
                        lm.views, lm.states, len(lm.rsm), vi, kind, light_pos, g, m, self.refine_list,
                        r.opaque_depth, p.rsm_bounds[li][vi], sc.points, sc.normals, sc.indices,
                        sc.triangle_material, sc.opacity, sc.ior, self.cam.view, self.cam.depth, p.cam_bounds,
                        self.cam.position, self.cam.normal, int(s.max_steps), float(s.thickness),
                        float(s.thickness_rel), p.t_max, int(s.cascade), self.sub_rec])
                else:
                    _, _, seed = frame_random(s.seed, frame, li * 64 + vi)
                    wp.launch(R.trace_refine_world, dim=refined * cm, device=dev, inputs=[
                        lm.views, lm.states, len(lm.rsm), vi, kind, light_pos, g, m, self.refine_list, world,
                        self.cam, seed, float(s.roughness_cutoff), float(s.thickness), float(s.thickness_rel),
                        p.t_max, int(s.max_bounces), self.sub_rec])
        p.launch_photons(R.splat_refined, refined * m * m + listed - refined, inputs=[
            g, m, self.refine_list, refined, listed, self.rec, self.sub_rec, self.tri_power, self.sub_power, self.cam,
            float(s.thickness), float(s.thickness_rel), MAX_SPAN, p.footprint_mode, p.photon_map, self.tri_state,
            self.sub_state, p.ledger])

    def last_view_state(self) -> dict:
        """Host copies of the last traced light's records and cells (tests, the naive twins)."""
        g = self.grid
        corners, cells = 2 * g.count * g.corners, 2 * g.count * g.cells
        return {"grid": "mesh", "n": g.n, "count": g.count, "tris": g.tris.numpy()[: g.count],
                "bary": g.bary.numpy()[: 3 * g.count].reshape(-1, 3, 2),
                "entry": self.rec.entry.numpy()[:corners], "pos": self.rec.pos.numpy()[:corners],
                "pix": self.rec.pix.numpy()[:corners], "dir": self.rec.dir.numpy()[:corners],
                "throughput": self.rec.throughput.numpy()[:corners], "tri_power": self.tri_power.numpy()[:cells],
                "tri_state": self.tri_state.numpy()[:cells]}


# --- naive twin ------------------------------------------------------------------------------------------


def sub_cells_numpy(n: int) -> list[tuple[tuple[int, int], tuple[int, int], tuple[int, int]]]:
    """The n² sub-triangles of a triangle cut n × n, in the kernels' order, as lattice corners (i, j):
    row by row, along a row upright (i, j) (i+1, j) (i, j+1) then inverted (i+1, j) (i+1, j+1) (i, j+1)."""
    out = []
    for j in range(n):
        for i in range(n - j):
            out.append(((i, j), (i + 1, j), (i, j + 1)))
            if i < n - j - 1:
                out.append(((i + 1, j), (i + 1, j + 1), (i, j + 1)))
    return out


def mesh_cells_numpy(scene, light, views: list, skip_windows: list, view_index: int, shadow_depth: np.ndarray,
                     tris: np.ndarray, bary: np.ndarray, n: int, roughness_cutoff: float, thickness: float,
                     thickness_rel: float) -> dict:
    """Naive twin of ``mesh_cells`` for one light view, float64: loops in Python over the grid's triangles
    and their sub-triangles.

    ``scene``: the :class:`~cisp_warp.scene.model.Scene`; ``light``: its
    :class:`~cisp_warp.scene.model.Light`; ``views``: the light's active views
    (:class:`~cisp_warp.raster.views.View`), ``skip_windows`` theirs ((x0, y0, x1, y1) [pixels]), the cells of
    ``views[view_index]`` booked; ``shadow_depth``: (H*W,) that view's nearest depth [m]; ``tris``, ``bary``: the
    grid's triangles (:func:`grid_triangles`). Returns the cells' power (2 sheets · T · n², 3) [W] and the ledger parts they book
    {entry: (3,) W}."""
    pts = scene.points.astype(np.float64)
    nrm = scene.normals.astype(np.float64)
    idx = scene.indices.reshape(-1, 3)
    mats = scene.materials
    rgb = light.radiometric_rgb
    kind = int(light.kind)
    pos = np.asarray(light.position, np.float64)
    axis = np.asarray(light.direction, np.float64)
    view = views[view_index]

    def owner(x):
        for v, (w, (x0, y0, x1, y1)) in enumerate(zip(views, skip_windows)):
            px, py, z = w.project(x)
            if w.far > 0 and z > 0 and 0 <= px < w.width and 0 <= py < w.height \
                    and not (x0 <= px < x1 and y0 <= py < y1):
                return v
        return -1

    forward = np.asarray(view.to_world, np.float64)[:3, :3] @ np.array([0.0, 0.0, -1.0])
    forward /= np.linalg.norm(forward)
    cells = sub_cells_numpy(n)
    total = len(tris) * n * n
    power = np.zeros((2 * total, 3))
    book: dict[str, np.ndarray] = {}

    def add(name, v):
        book[name] = book.get(name, np.zeros(3)) + v

    def reaches(x):
        px, py, z = view.project(x)
        ix = min(max(int(px), 0), view.width - 1)
        iy = min(max(int(py), 0), view.height - 1)
        s = shadow_depth[iy * view.width + ix]
        return 0.0 if 0.0 < s < z - (thickness + thickness_rel * z) else 1.0

    def direction(x):
        if kind == 0:
            return forward
        d = x - pos
        return d / np.linalg.norm(d)

    def spot(cos_angle):
        angle = math.acos(min(max(cos_angle, -1.0), 1.0))
        if angle >= light.cone_angle:
            return 0.0
        inner = light.cone_angle * (1.0 - min(max(light.cone_softness, 0.0), 1.0))
        if angle <= inner:
            return 1.0
        s = (light.cone_angle - angle) / (light.cone_angle - inner)
        return s * s * (3.0 - 2.0 * s)

    for k, tri in enumerate(tris):
        a, b, c = pts[idx[tri]]
        na, nb, nc = nrm[idx[tri]]
        m = mats[scene.triangle_material[tri]]

        def lattice(ij):
            b0, b1, b2 = bary[k].astype(np.float64)
            wb, wc = b0 + (b1 - b0) * (ij[0] / n) + (b2 - b0) * (ij[1] / n)
            wa = 1.0 - wb - wc
            return a * wa + b * wb + c * wc, na * wa + nb * wb + nc * wc

        for s, corners in enumerate(cells):
            (xa, ma), (xb, mb), (xc, mc) = (lattice(ij) for ij in corners)
            g = (xa + xb + xc) / 3.0
            if owner(g) != view_index or min(owner(xa), owner(xb), owner(xc)) < 0:
                continue  # another view's cell, or one with a corner outside every view
            d_in = direction(g)
            if kind == 0:
                flux = rgb * abs(d_in @ (0.5 * np.cross(xb - xa, xc - xa)))
            else:
                ra, rb, rc = xa - pos, xb - pos, xc - pos
                la, lb, lc = np.linalg.norm(ra), np.linalg.norm(rb), np.linalg.norm(rc)
                omega = 2.0 * math.atan2(abs(ra @ np.cross(rb, rc)),
                                         la * lb * lc + (ra @ rb) * lc + (ra @ rc) * lb + (rb @ rc) * la)
                flux = rgb * omega * (spot(d_in @ axis) if kind == 2 else 1.0)
            flux = flux * (reaches(xa) + reaches(xb) + reaches(xc)) / 3.0
            add("sampled", flux)
            refr = refl = np.zeros(3)
            if m.roughness > roughness_cutoff:
                add("culled_roughness", flux)
            elif m.opacity < 1.0:
                nn = (ma + mb + mc) / np.linalg.norm(ma + mb + mc)
                eta = m.ior
                if d_in @ nn > 0:
                    nn, eta = -nn, 1.0 / eta
                refl = flux * float(fresnel_dielectric_np(-(d_in @ nn), eta))
                refr = flux - refl
            else:
                refl = flux * np.asarray(m.albedo, np.float64)
                add("absorbed", flux - refl)
            add("refracted", refr)
            add("reflected", refl)
            power[k * n * n + s] = refr
            power[total + k * n * n + s] = refl
    return {"tri_power": power, "ledger": book}
