"""Naive twin of the rasterizer: a G-buffer by ray casting through a ``wp.Mesh`` BVH.

Slow and obvious on purpose. Tests hold the rasterizer to it (triangle id per pixel, depth).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..scene.device import DeviceScene
from .kernels import faces_away
from .views import View, ViewParams, pixel_ray_world


@wp.kernel
def raycast_depth(
    view: ViewParams,
    mesh: wp.uint64,
    face_to_triangle: wp.array(dtype=wp.int32),  # (F,) scene triangle of each BVH face (read)
    depth: wp.array(dtype=wp.float32),  # (H*W,) linear depth [m], 0 = miss (write)
    tri_id: wp.array(dtype=wp.int32),  # (H*W,) scene triangle id, -1 = miss (write)
):
    p = wp.tid()
    o, d = pixel_ray_world(view, float(p % view.width) + 0.5, float(p / view.width) + 0.5)
    scale = wp.length(d)
    q = wp.mesh_query_ray(mesh, o, d / scale, view.far * scale)
    depth[p] = 0.0
    tri_id[p] = -1
    if q.result:
        z = q.t / scale
        if z >= view.near:
            depth[p] = z
            tri_id[p] = face_to_triangle[q.face]


def raycast_view(scene: DeviceScene, view: View, layer: int) -> tuple[np.ndarray, np.ndarray]:
    """Depth (H, W) float32 [m] and triangle id (H, W) int32 of the nearest ``layer`` surface per pixel.

    Triangles nearer than the view's near plane are ignored wholesale by the ray (it starts on the
    near plane only for orthographic views), so compare against the rasterizer where nothing crosses it.
    """
    mesh, face_map = scene.bvh(layer)
    n = view.width * view.height
    depth = wp.zeros(n, dtype=wp.float32, device=scene.device)
    tri = wp.zeros(n, dtype=wp.int32, device=scene.device)
    wp.launch(raycast_depth, dim=n, device=scene.device, inputs=[view.params(), mesh.id, face_map, depth, tri])
    return depth.numpy().reshape(view.height, view.width), tri.numpy().reshape(view.height, view.width)


@wp.kernel
def raycast_back_depth(
    view: ViewParams,
    points: wp.array(dtype=wp.vec3),  # (V,) world positions [m] (read)
    normals: wp.array(dtype=wp.vec3),  # (V,) authored vertex normals (read)
    indices: wp.array(dtype=wp.int32),  # (3T,) (read)
    layers: wp.array(dtype=wp.int32),  # (T,) layer bits (read)
    layer: int,
    front_depth: wp.array(dtype=wp.float32),  # (H*W,) front layer depth [m], 0 = none (read)
    front_tri: wp.array(dtype=wp.int32),  # (H*W,) front layer triangle, -1 = none (read)
    back: wp.array(dtype=wp.float32),  # (H*W,) nearest back face at or behind the front [m], 0 = none (write)
):
    """Every triangle of ``layer`` against the pixel's centre ray (Moller-Trumbore, no BVH, no raster): the nearest
    hit at or behind the front depth on a triangle that faces away (``kernels.faces_away``), 0 where none or where
    the front triangle itself faces away. The naive twin of ``Rasterizer.draw_back`` + ``kernels.resolve_back``."""
    p = wp.tid()
    o, d = pixel_ray_world(view, float(p % view.width) + 0.5, float(p / view.width) + 0.5)
    zf = front_depth[p]
    best = float(0.0)
    ft = front_tri[p]
    if zf > 0.0 and ft >= 0 and not faces_away(view, ft, points, normals, indices):
        for t in range(layers.shape[0]):
            if (layers[t] & layer) != 0 and faces_away(view, t, points, normals, indices):
                p0 = points[indices[3 * t]]
                e1 = points[indices[3 * t + 1]] - p0
                e2 = points[indices[3 * t + 2]] - p0
                pv = wp.cross(d, e2)
                det = wp.dot(e1, pv)
                if wp.abs(det) > 1.0e-30:
                    inv = 1.0 / det
                    s = o - p0
                    u = wp.dot(s, pv) * inv
                    qv = wp.cross(s, e1)
                    v = wp.dot(d, qv) * inv
                    z = wp.dot(e2, qv) * inv  # t along d is depth
                    if u >= 0.0 and v >= 0.0 and u + v <= 1.0 and z >= zf and z >= view.near and z <= view.far:
                        if best == 0.0 or z < best:
                            best = z
    back[p] = best


def raycast_back_view(scene: DeviceScene, view: View, layer: int, front_depth: np.ndarray,
                      front_tri: np.ndarray) -> np.ndarray:
    """(H, W) float32 [m]: the nearest back face of ``layer`` at or behind ``front_depth`` per pixel (0 = none), by
    :func:`raycast_back_depth` (every triangle against every pixel: small views only)."""
    n = view.width * view.height
    back = wp.zeros(n, dtype=wp.float32, device=scene.device)
    fd = wp.array(np.asarray(front_depth, np.float32).reshape(-1), dtype=wp.float32, device=scene.device)
    ft = wp.array(np.asarray(front_tri, np.int32).reshape(-1), dtype=wp.int32, device=scene.device)
    wp.launch(raycast_back_depth, dim=n, device=scene.device,
              inputs=[view.params(), scene.points, scene.normals, scene.indices, scene.triangle_layers, int(layer), fd,
                      ft, back])
    return back.numpy().reshape(view.height, view.width)
