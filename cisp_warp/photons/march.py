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
    for i in range(1, n + 1):
        s = ds_step * float(i)
        sp = s0 + ds * s
        zr = float(0.0)
        if view.orthographic != 0:
            zr = z0 + (z1 - z0) * s
        else:
            zr = 1.0 / (k0 + (k1 - k0) * s)
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
            return MARCH_HIT, lam * t1, i
        s_prev = s
        zr_prev = zr
        diff_prev = diff
        s_last = s
    lam_last = s_last
    if view.orthographic == 0:
        lam_last = s_last * k1 / ((1.0 - s_last) * k0 + s_last * k1)
    return status, lam_last * t1, n
