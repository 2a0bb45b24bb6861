"""Device-resident copy of a :class:`Scene`: allocated once, updated in place per frame."""

from __future__ import annotations

import os

import numpy as np
import warp as wp

from ..errors import SceneError
from .model import LAYER_OPAQUE, LAYER_SPECULAR, Scene


def device_free_bytes(device) -> int:
    """Bytes that can still be allocated on ``device`` (GPU memory, or host RAM for ``cpu``)."""
    dev = wp.get_device(device)
    if dev.is_cuda:
        return int(dev.free_memory)
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 1 << 62


def check_memory(nbytes: int, what: str, device) -> None:
    """Raise :class:`SceneError` before allocating ``nbytes`` that ``device`` cannot hold."""
    free = device_free_bytes(device)
    if nbytes > free:
        raise SceneError(
            f"{what} needs {nbytes / 2**30:.2f} GiB but device '{wp.get_device(device).alias}' has "
            f"{free / 2**30:.2f} GiB free: lower the resolution or photon count"
        )


@wp.struct
class SurfaceGeometry:
    """The triangles as photon emission reads them (views of ``DeviceScene`` arrays, no copies)."""

    points: wp.array(dtype=wp.vec3)  #: (V,) vertex positions at this frame [m] (written in place by sim/)
    normals: wp.array(dtype=wp.vec3)  #: (V,) unit vertex normals
    indices: wp.array(dtype=wp.int32)  #: (3T,) triangle vertex indices
    neighbors: wp.array(dtype=wp.int32)  #: (3T,) triangle across the edge opposite vertex i of each triangle, -1 = none


#: ``DeviceScene.generation`` holds one counter per layer bit: index b counts the moves of the triangles of layer 1 << b
LAYER_BITS = 2


@wp.kernel
def bump_generation(generation: wp.array(dtype=wp.int32), layers: int):
    """One thread: count one move of the triangles of every layer in ``layers`` (bit b: ``generation[b]`` + 1)."""
    for b in range(generation.shape[0]):
        if ((layers >> b) & 1) != 0:
            generation[b] = generation[b] + 1


def triangle_neighbors(indices: np.ndarray) -> np.ndarray:
    """(T, 3) int32: for triangle t and corner i, the triangle sharing the edge opposite corner i (the
    edge from corner i+1 to corner i+2), or -1 on a boundary. Edges are matched by vertex index; an
    edge shared by more than two triangles (non-manifold) is left unconnected."""
    tri = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
    t_count = len(tri)
    out = np.full((t_count, 3), -1, dtype=np.int32)
    if t_count == 0:
        return out
    a = np.concatenate([tri[:, 1], tri[:, 2], tri[:, 0]])  # edge opposite corner 0, 1, 2
    b = np.concatenate([tri[:, 2], tri[:, 0], tri[:, 1]])
    key = np.minimum(a, b) * (int(tri.max()) + 1) + np.maximum(a, b)
    slot = np.arange(3 * t_count)  # slot = corner * T + triangle
    order = np.argsort(key, kind="stable")
    ks = key[order]
    start = np.r_[True, ks[1:] != ks[:-1]]
    group = np.cumsum(start) - 1
    count = np.bincount(group)
    pair = count[group] == 2
    first = np.flatnonzero(start)
    o = order[pair]
    g = group[pair]
    partner = order[first[g] + (1 - (np.arange(len(o)) - np.searchsorted(g, g)))]
    # slot s = corner*T + t: its neighbour is the triangle of the partner slot
    flat = out.reshape(-1)
    corner, t = o // t_count, o % t_count
    flat[t * 3 + corner] = (partner % t_count).astype(np.int32)
    return out


class DeviceScene:
    """The scene's geometry and materials as Warp arrays on one device.

    ====================  ===========  =======  ================================================
    array                 shape        dtype    meaning
    ====================  ===========  =======  ================================================
    points                (V,)         vec3     vertex positions at this frame [m] (read by all views)
    prev_points           (V,)         vec3     vertex positions at the previous frame [m] (motion)
    normals               (V,)         vec3     unit vertex normals
    indices               (3T,)        int32    flattened triangle vertex indices
    tri_neighbors         (3T,)        int32    triangle across the edge opposite each corner, -1 = none
    triangle_material     (T,)         int32    material index per triangle
    triangle_layers       (T,)         int32    ``LAYER_*`` bit mask per triangle
    albedo                (M,)         vec3     diffuse reflectance, linear RGB
    roughness             (M,)         float32
    metallic              (M,)         float32
    opacity               (M,)         float32
    ior                   (M,)         float32
    generation            (2,)         int32    moves of the opaque, specular triangles so far (``LAYER_BITS``)
    ====================  ===========  =======  ================================================

    ``generation`` lets a view whose maps depend only on its parameters and on the triangles it draws keep them while
    neither changed (``raster.light_maps.redraw_gate``): it is counted on the device (``bump_generation``), so a
    captured frame keeps deciding. Whoever moves points calls :meth:`begin_frame` first (it must, for the motion
    vectors) or :meth:`geometry_moved`.
    """

    def __init__(self, scene: Scene, device=None):
        self.scene = scene
        self.device = wp.get_device(device)
        scene.validate()
        nbytes = scene.points.nbytes * 3 + scene.indices.nbytes * 2
        check_memory(nbytes, f"the geometry of '{scene.source}' ({scene.triangle_count} triangles)", self.device)
        d = self.device
        self.points = wp.array(scene.points.astype(np.float32), dtype=wp.vec3, device=d)
        self.prev_points = wp.clone(self.points)
        self.normals = wp.array(scene.normals.astype(np.float32), dtype=wp.vec3, device=d)
        self.indices = wp.array(scene.indices.astype(np.int32).reshape(-1), dtype=wp.int32, device=d)
        self.triangle_material = wp.array(scene.triangle_material.astype(np.int32), dtype=wp.int32, device=d)
        layers = scene.triangle_layers()
        self.triangle_layers = wp.array(layers, dtype=wp.int32, device=d)
        mats = scene.materials
        self.albedo = wp.array(np.array([m.albedo for m in mats], dtype=np.float32), dtype=wp.vec3, device=d)
        self.roughness = wp.array(np.array([m.roughness for m in mats], dtype=np.float32), device=d)
        self.metallic = wp.array(np.array([m.metallic for m in mats], dtype=np.float32), device=d)
        self.opacity = wp.array(np.array([m.opacity for m in mats], dtype=np.float32), device=d)
        self.ior = wp.array(np.array([m.ior for m in mats], dtype=np.float32), device=d)
        self.tri_neighbors = wp.array(triangle_neighbors(scene.indices).reshape(-1), dtype=wp.int32, device=d)
        self.geometry = SurfaceGeometry()
        self.geometry.points, self.geometry.normals = self.points, self.normals
        self.geometry.indices, self.geometry.neighbors = self.indices, self.tri_neighbors
        self.has_layer = {LAYER_OPAQUE: bool(np.any(layers & LAYER_OPAQUE)), LAYER_SPECULAR: bool(np.any(layers & LAYER_SPECULAR))}
        self.generation = wp.zeros(LAYER_BITS, dtype=wp.int32, device=d)
        # a scene without mesh ranges (built in code) says nothing of what moves: every layer may
        dyn = layers if not scene.meshes else np.zeros(0, np.int32)
        for m in scene.meshes:
            if m.dynamic:
                dyn = np.concatenate([dyn, layers[m.triangle_start : m.triangle_start + m.triangle_count]])
        #: layer bits of the triangles that may move (of dynamic meshes; every layer of a scene without mesh ranges)
        self.dynamic_layers = int(np.bitwise_or.reduce(dyn.astype(np.int64))) if dyn.size else 0
        self._bvh: dict[int, tuple[wp.Mesh, wp.array]] = {}
        self._bvh_dynamic: dict[int, bool] = {}  #: whether a BVH's triangles include a dynamic mesh's (refit them)

    @property
    def triangle_count(self) -> int:
        return self.scene.triangle_count

    def begin_frame(self) -> None:
        """Keep this frame's points as the previous frame's before dynamic meshes are moved (and count the move of
        their layers, :meth:`geometry_moved`)."""
        wp.copy(self.prev_points, self.points)
        self.geometry_moved()

    def geometry_moved(self, layers: int | None = None) -> None:
        """Count a move of the triangles of ``layers`` (default ``dynamic_layers``) in ``generation``, on the
        device: the views that draw them are redrawn next frame. A launch, no host copy."""
        layers = self.dynamic_layers if layers is None else int(layers)
        if layers:
            wp.launch(bump_generation, dim=1, device=self.device, inputs=[self.generation, layers])

    def mesh_points(self, mesh_index: int) -> tuple[wp.array, wp.array]:
        """Views (no copy) of one mesh's points and normals, for ``sim/`` to write in place."""
        r = self.scene.meshes[mesh_index]
        a, b = r.vertex_start, r.vertex_start + r.vertex_count
        return self.points[a:b], self.normals[a:b]

    def bvh(self, layer: int = LAYER_OPAQUE | LAYER_SPECULAR) -> tuple[wp.Mesh, wp.array]:
        """A ``wp.Mesh`` BVH over the triangles of ``layer`` and the map from its faces to scene triangles.

        Built once, refit by :meth:`refit` when points move. Raises :class:`SceneError` for a layer
        without triangles (building a ``wp.Mesh`` of zero triangles corrupts Warp's CUDA allocator).
        """
        if layer not in self._bvh:
            tri = np.nonzero(self.scene.triangle_layers() & layer)[0].astype(np.int32)
            if tri.size == 0:
                raise SceneError(f"no triangles in raster layer {layer}: cannot build a BVH", file=self.scene.source)
            idx = wp.array(self.scene.indices[tri].astype(np.int32).reshape(-1), dtype=wp.int32, device=self.device)
            mesh = wp.Mesh(points=self.points, indices=idx)
            self._bvh[layer] = (mesh, wp.array(tri, dtype=wp.int32, device=self.device))
            # a scene without mesh ranges (built in code) says nothing of what moves: every BVH is refit
            moving = np.full(self.scene.triangle_count, not self.scene.meshes, dtype=bool)
            for m in self.scene.meshes:
                if m.dynamic:
                    moving[m.triangle_start : m.triangle_start + m.triangle_count] = True
            self._bvh_dynamic[layer] = bool(moving[tri].any())
        return self._bvh[layer]

    def refit(self) -> None:
        """Refit every BVH that holds a dynamic mesh's triangles after points moved (never rebuilds); a BVH of
        static triangles only (the pool's opaque layer under its simulated water) is left as built."""
        for layer, (mesh, _) in self._bvh.items():
            if self._bvh_dynamic[layer]:
                mesh.refit()
