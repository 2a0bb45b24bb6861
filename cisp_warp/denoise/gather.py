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

    def apply(self, irradiance_in: wp.array, depth: wp.array, normal: wp.array, tri_id: wp.array,
              out: wp.array) -> None:
        """Gather ``irradiance_in`` (H*W vec3 [W/m²]) into ``out`` (H*W vec3 [W/m²]) over the G-buffer
        ``depth`` (float32 [m]), ``normal`` (vec3) and ``tri_id`` (int32)."""
        wp.launch(gaussian_gather, dim=(self.height, self.width), device=self.device,
                  inputs=[irradiance_in, depth, normal, tri_id, self.width, self.height, self.radius,
                          1.0 / (2.0 * self.sigma * self.sigma), self.depth_tolerance, self.normal_tolerance],
                  outputs=[out])
