"""Naive twin of the rasterizer: a G-buffer by ray casting through a ``wp.Mesh`` BVH.

Slow and obvious on purpose. Tests hold the rasterizer to it (triangle id per pixel, depth).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..scene.device import DeviceScene
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
