"""Eye-space Gaussian photon gather (Wyman & Davis 2006, seed 004, section 3.2.2): SVGF's cheap alternative.

What is followed from seed 004's gather ("For each pixel: 1. search the 7x7 pixel neighbourhood ...
4. weight the neighbour contributions using a Gaussian"): a (2·radius+1)² window, 7x7 by default,
with Gaussian weights. What differs, and why:

* step 2 (area from the world positions of neighbouring pixels, instead of eq. 5): our photon map
  already stores irradiance, each photon's power divided by its receiving pixel's exact footprint,
  so the gather averages irradiance and needs no area of its own;
* steps 3 and 4's lighting term and direct light belong to the shading pass here;
* only same-surface neighbours (depth within a relative tolerance, normals within a cosine) take
  part, and the weights are renormalised over them, so the gather does not bleed caustics across
  silhouettes and a constant stays constant;
* step 5 (discard gathers of fewer than three photons) is not done: it removes energy, and this
  project accounts for every watt (DESIGN.md).
"""

from __future__ import annotations

import math

import warp as wp


@wp.kernel
def gaussian_gather(
    irradiance: wp.array(dtype=wp.vec3),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    tri_id: wp.array(dtype=wp.int32),
    width: int,
    height: int,
    radius: int,
    inv_two_sigma_sq: float,
    depth_tolerance: float,
    normal_tolerance: float,
    out: wp.array(dtype=wp.vec3),
):
    """out[p] = Σ_q g(p−q) E_q / Σ_q g(p−q), g(d) = exp(−‖d‖² / 2σ²), over same-surface q in the window.

    The per-pixel twin of :func:`gather_kernel` (which the pass launches): every tap read from global memory.

    Reads ``irradiance`` (H*W vec3 [W/m²]), ``depth`` (H*W float32 [m], 0 = none), ``normal`` (H*W vec3),
    ``tri_id`` (H*W int32, -1 = none). Writes ``out`` (H*W vec3 [W/m²], 0 without a surface); must not
    alias ``irradiance``.
    """
    y, x = wp.tid()
    p = y * width + x
    z = depth[p]
    if z <= 0.0 or tri_id[p] < 0:
        out[p] = wp.vec3(0.0)
        return
    n = normal[p]
    sum_w = float(0.0)
    sum_e = wp.vec3(0.0)
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            qx = x + dx
            qy = y + dy
            if qx >= 0 and qx < width and qy >= 0 and qy < height:
                q = qy * width + qx
                z_q = depth[q]
                if (z_q > 0.0 and tri_id[q] >= 0 and wp.abs(z_q - z) <= depth_tolerance * z
                        and wp.dot(normal[q], n) >= normal_tolerance):
                    w = wp.exp(-float(dx * dx + dy * dy) * inv_two_sigma_sq)
                    sum_w += w
                    sum_e += w * irradiance[q]
    out[p] = sum_e / sum_w  # the centre pixel always takes part: sum_w >= 1


#: output tile of :func:`gather_kernel` [pixels]: a block of TILE_Y x TILE_X threads, one a pixel
GATHER_TILE_Y = 8
GATHER_TILE_X = 32
_KERNELS: dict = {}


def gather_kernel(radius: int):
    """:func:`gaussian_gather` for one ``radius`` with its neighbourhood read once: a block loads its
    GATHER_TILE_Y x GATHER_TILE_X pixels and an apron of ``radius`` (the packed guide (n, z), z = 0 where there
    is no surface or ``tri_id < 0``, and the irradiance) into shared memory, and every thread gathers its window
    from there. The same sum in the same order as :func:`gaussian_gather`: bitwise the same output.

    ``wp.launch_tiled`` over ``ceil(H / TILE_Y) * ceil(W / TILE_X)`` blocks; arguments as
    :func:`gaussian_gather` without ``radius``. On the CPU the block is one lane that loads and gathers it all."""
    if radius in _KERNELS:
        return _KERNELS[radius]
    ty, tx = GATHER_TILE_Y, GATHER_TILE_X
    ay, ax = ty + 2 * radius, tx + 2 * radius
    n_apron = ay * ax
    r = radius

    @wp.kernel(enable_backward=False, module="unique")
    def gather_tiled(
        irradiance: wp.array(dtype=wp.vec3),
        depth: wp.array(dtype=wp.float32),
        normal: wp.array(dtype=wp.vec3),
        tri_id: wp.array(dtype=wp.int32),
        width: int,
        height: int,
        tiles_x: int,
        inv_two_sigma_sq: float,
        depth_tolerance: float,
        normal_tolerance: float,
        out: wp.array(dtype=wp.vec3),
    ):
        block, lane = wp.tid()
        threads = wp.block_dim()
        y0 = (block // tiles_x) * ty - r
        x0 = (block % tiles_x) * tx - r
        guide = wp.tile_empty(shape=n_apron, dtype=wp.vec4, storage="shared")
        signal = wp.tile_empty(shape=n_apron, dtype=wp.vec3, storage="shared")
        for k0 in range(0, n_apron, threads):
            k = k0 + lane
            g = wp.vec4(0.0)
            e = wp.vec3(0.0)
            if k < n_apron:
                y = y0 + k // ax
                x = x0 + k % ax
                if y >= 0 and y < height and x >= 0 and x < width:
                    q = y * width + x
                    z = depth[q]
                    if z > 0.0 and tri_id[q] >= 0:
                        n = normal[q]
                        g = wp.vec4(n[0], n[1], n[2], z)
                        e = irradiance[q]
            wp.tile_scatter_masked(guide, k, g, k < n_apron)
            wp.tile_scatter_masked(signal, k, e, k < n_apron)
        for k in range(lane, ty * tx, threads):
            y = y0 + r + k // tx
            x = x0 + r + k % tx
            if y < height and x < width:
                u = (r + k // tx) * ax + r + k % tx
                g_p = guide[u]
                res = wp.vec3(0.0)
                if g_p[3] > 0.0:
                    z = g_p[3]
                    n = wp.vec3(g_p[0], g_p[1], g_p[2])
                    sum_w = float(0.0)
                    sum_e = wp.vec3(0.0)
                    for dy in range(-r, r + 1):
                        for dx in range(-r, r + 1):
                            v = u + dy * ax + dx
                            g_q = guide[v]
                            z_q = g_q[3]  # 0 off the image, as without a surface
                            if (z_q > 0.0 and wp.abs(z_q - z) <= depth_tolerance * z
                                    and wp.dot(wp.vec3(g_q[0], g_q[1], g_q[2]), n) >= normal_tolerance):
                                w = wp.exp(-float(dx * dx + dy * dy) * inv_two_sigma_sq)
                                sum_w += w
                                sum_e += w * signal[v]
                    res = sum_e / sum_w
                out[y * width + x] = res

    wp.set_module_options({"block_dim": ty * tx}, module=gather_tiled.module)
    _KERNELS[radius] = gather_tiled
    return gather_tiled


class GaussianGather:
    """Same-surface Gaussian gather of a ``width`` x ``height`` irradiance map on ``device``.

    ``radius`` [pixels]: half width of the window (3 → 7x7, seed 004); ``sigma`` [pixels]: Gaussian
    standard deviation (default radius/2, so the window spans ±2σ); ``depth_tolerance``: largest
    relative depth difference of a same-surface neighbour; ``normal_tolerance``: smallest cosine
    between the normals of same-surface neighbours.
    """

    def __init__(self, width: int, height: int, device, radius: int = 3, sigma: float | None = None,
                 depth_tolerance: float = 0.05, normal_tolerance: float = 0.9):
        if radius < 0:
            raise ValueError("radius must be >= 0")
        self.width = width
        self.height = height
        self.device = wp.get_device(device)
        self.radius = int(radius)
        self.sigma = float(sigma) if sigma is not None else max(0.5 * radius, 0.5)
        if self.sigma <= 0.0 or not math.isfinite(self.sigma):
            raise ValueError("sigma must be a positive finite number of pixels")
        self.depth_tolerance = float(depth_tolerance)
        self.normal_tolerance = float(normal_tolerance)
        self.kernel = gather_kernel(self.radius)

    def apply(self, irradiance_in: wp.array, depth: wp.array, normal: wp.array, tri_id: wp.array,
              out: wp.array) -> None:
        """Gather ``irradiance_in`` (H*W vec3 [W/m²]) into ``out`` (H*W vec3 [W/m²]) over the G-buffer
        ``depth`` (float32 [m]), ``normal`` (vec3) and ``tri_id`` (int32)."""
        tiles_x = (self.width + GATHER_TILE_X - 1) // GATHER_TILE_X
        tiles_y = (self.height + GATHER_TILE_Y - 1) // GATHER_TILE_Y
        wp.launch_tiled(self.kernel, dim=tiles_y * tiles_x, block_dim=GATHER_TILE_Y * GATHER_TILE_X, device=self.device,
                        inputs=[irradiance_in, depth, normal, tri_id, self.width, self.height, tiles_x,
                                1.0 / (2.0 * self.sigma * self.sigma), self.depth_tolerance, self.normal_tolerance],
                        outputs=[out])
