"""Image-space ray march through a linear depth buffer (after McGuire & Mara 2014), shared by every
screen-space pass: the photons' light-view and camera-view traces and the water's refraction.

The ray segment is clipped to the view's near plane and to the image rectangle, then walked one pixel
per step along its major screen axis with perspective-correct depth (1/depth is linear in screen space
for a perspective view, depth itself for an orthographic one). At each step the ray's depth z_r is
compared with the buffer's z_s at that pixel:

* the ray's depth range over the step, [min(z_r, z_r'), max(z_r, z_r')], overlaps the surface's
  [z_s, z_s + thickness]: the ray crossed the surface: the exact crossing is found by intersecting
  the two linear segments of seed 000, eq. 2 (ray depth and sample depth between the last two
  steps), or within the pixel when the ray runs along the view axis, and the march reports a hit;
* otherwise the ray is in front of the surface, or passes behind it: go on.

Testing the depth *range* of each step rather than its end point matters for rays close to the
view axis, which advance far in depth per pixel.

``t`` is the parameter of the world-space ray ``o + d·t`` (``d`` need not be unit length).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..raster.views import ViewParams

MARCH_HIT = wp.constant(0)  #: crossed a surface of the depth buffer
MARCH_EXIT = wp.constant(1)  #: left the view (image border, near plane) or reached t_max
MARCH_STEPS = wp.constant(2)  #: ran out of steps before either

BIG_DEPTH = wp.constant(1.0e30)


@wp.func
def _buffer_depth(view: ViewParams, depth: wp.array(dtype=wp.float32), sx: float, sy: float) -> float:
    i = wp.clamp(int(wp.floor(sx)), 0, view.width - 1)
    j = wp.clamp(int(wp.floor(sy)), 0, view.height - 1)
    z = depth[j * view.width + i]
    if z <= 0.0:
        return BIG_DEPTH
    return z


@wp.func
def _level_offset(view: ViewParams, level: int) -> int:
    """Start of mip ``level`` (>= 1) in a flat min-depth pyramid: levels 1, 2, ... stored one after another."""
    off = int(0)
    for l in range(1, level):
        off += ((view.width + (1 << l) - 1) >> l) * ((view.height + (1 << l) - 1) >> l)
    return off


@wp.func
def _tile_min(view: ViewParams, pyramid: wp.array(dtype=wp.float32), level: int, tx: int, ty: int) -> float:
    w = (view.width + (1 << level) - 1) >> level
    return pyramid[_level_offset(view, level) + ty * w + tx]


@wp.func
def _ray_depth(view: ViewParams, z0: float, z1: float, k0: float, k1: float, s: float) -> float:
    """Depth of the ray at screen parameter s (linear in s orthographic, 1/depth linear in s perspective)."""
    if view.orthographic != 0:
        return z0 + (z1 - z0) * s
    return 1.0 / (k0 + (k1 - k0) * s)


@wp.func
def screen_march(
    view: ViewParams,
    depth: wp.array(dtype=wp.float32),  # (H*W,) linear depth [m], 0 = no surface (read)
    o: wp.vec3,  # world origin [m]
    d: wp.vec3,  # world direction
    t_max: float,
    max_steps: int,
    thickness: float,  # [m] absolute part of the surface thickness
    thickness_rel: float,  # relative part (× sample depth)
):
    """March ``o + d·t`` for t in (0, t_max]. Returns (status, t_end, steps taken).

    On a hit, ``t_end`` is the refined crossing; otherwise the last point inside the view.
    """
    return screen_march_hiz(view, depth, depth, 0, o, d, t_max, max_steps, thickness, thickness_rel)


@wp.func
def screen_march_hiz(
    view: ViewParams,
    depth: wp.array(dtype=wp.float32),  # (H*W,) linear depth [m], 0 = no surface (read)
    pyramid: wp.array(dtype=wp.float32),  # min-depth mips 1..levels of ``depth`` (``DepthPyramid``) (read)
    levels: int,  # mips in ``pyramid``; 0 = march pixel by pixel
    o: wp.vec3,  # world origin [m]
    d: wp.vec3,  # world direction
    t_max: float,
    max_steps: int,
    thickness: float,  # [m] absolute part of the surface thickness
    thickness_rel: float,  # relative part (× sample depth)
):
    """:func:`screen_march`, skipping tiles the ray crosses wholly in front of every surface.

    Hierarchical image-space tracing (seed 000 §4.2 after McGuire & Mara 2014, Stachowiak 2015): before a
    pixel step, the ray's depth over the rest of its way through a tile of mip L is compared with the
    tile's minimum depth; when the ray stays nearer than all of it no pixel in the tile can be hit and
    the march jumps to the tile's exit, trying the next coarser mip; otherwise it tries a finer one.
    The pixel steps that remain are exactly those of the plain march, so the hits are the same.
    """
    p0 = wp.transform_point(view.world_to_view, o)
    dv = wp.transform_vector(view.world_to_view, d)
    z0 = -p0[2]
    rate = -dv[2]  # d(depth)/dt
    t1 = t_max
    near = view.near * 1.0001
    if z0 < near:
        return MARCH_EXIT, float(0.0), int(0)
    if rate < 0.0:
        t1 = wp.min(t1, (z0 - near) / (-rate))
    if view.orthographic == 0:
        t1 = wp.min(t1, 1.0e6)
    p1 = p0 + dv * t1
    z1 = -p1[2]
    s0 = wp.vec2(0.0)
    s1 = wp.vec2(0.0)
    k0 = float(1.0)
    k1 = float(1.0)
    if view.orthographic != 0:
        s0 = wp.vec2(view.cx + view.fx * p0[0], view.cy - view.fy * p0[1])
        s1 = wp.vec2(view.cx + view.fx * p1[0], view.cy - view.fy * p1[1])
    else:
        k0 = 1.0 / z0
        k1 = 1.0 / z1
        s0 = wp.vec2(view.cx + view.fx * p0[0] * k0, view.cy - view.fy * p0[1] * k0)
        s1 = wp.vec2(view.cx + view.fx * p1[0] * k1, view.cy - view.fy * p1[1] * k1)
    # clip the screen segment to the image (Liang-Barsky); the origin must lie inside
    w = float(view.width)
    h = float(view.height)
    if s0[0] < 0.0 or s0[1] < 0.0 or s0[0] >= w or s0[1] >= h:
        return MARCH_EXIT, float(0.0), int(0)
    ds = s1 - s0
    s_end = float(1.0)
    if ds[0] > 0.0:
        s_end = wp.min(s_end, (w - 1.0e-3 - s0[0]) / ds[0])
    elif ds[0] < 0.0:
        s_end = wp.min(s_end, (1.0e-3 - s0[0]) / ds[0])
    if ds[1] > 0.0:
        s_end = wp.min(s_end, (h - 1.0e-3 - s0[1]) / ds[1])
    elif ds[1] < 0.0:
        s_end = wp.min(s_end, (1.0e-3 - s0[1]) / ds[1])
    s_end = wp.max(s_end, 0.0)
    pixels = wp.max(wp.abs(ds[0]), wp.abs(ds[1])) * s_end
    n = int(wp.ceil(pixels))
    status = MARCH_EXIT
    if n > max_steps:
        n = max_steps
        status = MARCH_STEPS
    n = wp.max(n, 1)
    ds_step = s_end / float(n)
    if pixels > float(max_steps):
        ds_step = s_end / pixels
    s_prev = float(0.0)
    zr_prev = z0
    diff_prev = z0 - _buffer_depth(view, depth, s0[0], s0[1])
    s_last = float(0.0)
    i = int(1)
    level = wp.min(1, levels)
    s_block = float(-1.0)  # pixel steps until here: the finest tile holding them was not skippable
    cap = levels  # coarsest mip worth trying from the current position
    iterations = int(0)
    while i <= n:
        iterations += 1
        if level == 0 and levels > 0 and s_prev >= s_block:
            level = 1
            cap = levels
        if level > 0:
            # can the ray skip the rest of the level-L tile holding its last sample?
            size = float(1 << level)
            q = s0 + ds * s_prev
            tx = int(wp.floor(q[0] / size))
            ty = int(wp.floor(q[1] / size))
            s_exit = s_end
            if ds[0] > 0.0:
                s_exit = wp.min(s_exit, (float(tx + 1) * size - s0[0]) / ds[0])
            elif ds[0] < 0.0:
                s_exit = wp.min(s_exit, (float(tx) * size - s0[0]) / ds[0])
            if ds[1] > 0.0:
                s_exit = wp.min(s_exit, (float(ty + 1) * size - s0[1]) / ds[1])
            elif ds[1] < 0.0:
                s_exit = wp.min(s_exit, (float(ty) * size - s0[1]) / ds[1])
            i_next = int(wp.floor(s_exit / ds_step))  # the last sample at or before the exit is re-checked
            z_far = wp.max(zr_prev, _ray_depth(view, z0, z1, k0, k1, s_exit))
            if z_far < _tile_min(view, pyramid, level, tx, ty):
                if i_next > i:
                    i = wp.min(i_next, n + 1)
                    s_prev = ds_step * float(i - 1)
                    q = s0 + ds * s_prev
                    zr_prev = _ray_depth(view, z0, z1, k0, k1, s_prev)
                    diff_prev = zr_prev - _buffer_depth(view, depth, q[0], q[1])
                    s_last = s_prev
                    cap = levels
                elif level >= cap:  # in front, but the tile ends within this pixel step: take the step
                    s_block = s_prev + 0.5 * ds_step
                    level = 0
                    continue
                level = wp.min(level + 1, cap)
            else:
                if level == 1:
                    s_block = wp.max(s_exit, s_prev + 0.5 * ds_step)  # at least one pixel step before retrying
                level -= 1
                cap = level  # no coarser tile from here until the ray moves on
            continue
        s = ds_step * float(i)
        sp = s0 + ds * s
        zr = _ray_depth(view, z0, z1, k0, k1, s)
        zs = _buffer_depth(view, depth, sp[0], sp[1])
        diff = zr - zs
        # the ray's depth over this step, [min, max], overlaps the surface's [zs, zs + thickness]
        if wp.max(zr, zr_prev) >= zs and wp.min(zr, zr_prev) <= zs + thickness + thickness_rel * zs:
            u = float(1.0)
            if diff_prev < 0.0 and diff >= 0.0:
                u = diff_prev / (diff_prev - diff)  # eq. 2: where the two depth segments cross
            elif zr != zr_prev:
                u = wp.clamp((zs - zr_prev) / (zr - zr_prev), 0.0, 1.0)  # crossing within this pixel
            s_hit = s_prev + (s - s_prev) * u
            lam = s_hit
            if view.orthographic == 0:
                lam = s_hit * k1 / ((1.0 - s_hit) * k0 + s_hit * k1)
            return MARCH_HIT, lam * t1, iterations
        s_prev = s
        zr_prev = zr
        diff_prev = diff
        s_last = s
        i += 1
    if i > n:
        s_last = ds_step * float(n)
    lam_last = s_last
    if view.orthographic == 0:
        lam_last = s_last * k1 / ((1.0 - s_last) * k0 + s_last * k1)
    return status, lam_last * t1, iterations


@wp.kernel
def _downsample_min(
    src: wp.array(dtype=wp.float32),  # level L-1: the depth buffer itself (0 = none) or a pyramid level (read)
    src_offset: int,
    src_w: int,
    src_h: int,
    from_depth: int,  # 1: src is the depth buffer, whose 0 means "no surface" (treated as infinitely far)
    dst: wp.array(dtype=wp.float32),  # the pyramid (write level L)
    dst_offset: int,
    dst_w: int,
):
    p = wp.tid()
    x = p % dst_w
    y = p / dst_w
    m = float(BIG_DEPTH)
    for dy in range(2):
        for dx in range(2):
            sx = wp.min(2 * x + dx, src_w - 1)
            sy = wp.min(2 * y + dy, src_h - 1)
            z = src[src_offset + sy * src_w + sx]
            if from_depth != 0 and z <= 0.0:
                z = BIG_DEPTH
            m = wp.min(m, z)
    dst[dst_offset + p] = m


class DepthPyramid:
    """Min-depth mips 1..``levels`` of one view's depth buffer, for :func:`screen_march_hiz`.

    Allocated once per view; :meth:`build` refreshes it from the depth buffer each frame.
    """

    def __init__(self, width: int, height: int, device, levels: int = 5):
        self.width, self.height, self.levels = int(width), int(height), int(levels)
        self.shapes = [((self.width + (1 << l) - 1) >> l, (self.height + (1 << l) - 1) >> l) for l in range(1, levels + 1)]
        self.offsets = np.cumsum([0] + [w * h for w, h in self.shapes]).tolist()
        self.data = wp.zeros(max(1, self.offsets[-1]), dtype=wp.float32, device=device)
        self.device = device

    def build(self, depth: wp.array) -> None:
        src, src_off, (sw, sh), from_depth = depth, 0, (self.width, self.height), 1
        for l, (w, h) in enumerate(self.shapes):
            wp.launch(_downsample_min, dim=w * h, device=self.device,
                      inputs=[src, src_off, sw, sh, from_depth, self.data, self.offsets[l], w])
            src, src_off, (sw, sh), from_depth = self.data, self.offsets[l], (w, h), 0
