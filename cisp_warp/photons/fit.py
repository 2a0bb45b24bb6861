"""Light views fitted to the camera (DESIGN, CISP step 0): cascaded shadow maps for photons.

Per frame, after the camera's G-buffer and before the lights' RSM views are drawn, all on the device:

1. every light's pilot views (its whole views, ``pilot_size``²) are drawn;
2. :func:`pilot_branches` sends one photon per pilot texel and branch (reflected; refracted where the
   surface transmits; a thread each) from the surface under the texel's centre, traces it through the scene's BVH
   (further specular bounces by Fresnel probability) and keeps the camera depth [m] where it lands on
   a surface the camera sees (the depth-visibility test of the photon stores); the nearer branch per texel, 0 where
   neither lands, is the texel's receiver depth, taken by :func:`fit_reduce_angles` on the device fit (its own launch,
   :func:`pilot_nearest`, before the host fit; :func:`pilot_receivers`, one thread per texel, is the twin); the
   kernel launched is compiled for the pilot view's and the camera's projections (:func:`projected_pilot_branches`;
   :func:`pilot_branches`, which reads them at run time, is its twin);
3. three small kernels fit the cascades to those depths (``views.fit_angle`` and ``views.fit_windows`` on the
   device): :func:`fit_reduce_angles` reduces, per pilot view and each of ``FIT_STEPS`` turns about its axis, the
   box of the turned useful texels (and their depth range) with Warp tiles, one block each, turning only each
   column's first and last useful texel (``fit_reduce_*_naive``, every texel turned, are the twins);
   :func:`fit_reduce_cascades` picks the tightest turn and reduces each cascade's box (texels nearer than its
   split); :func:`fit_solve_cascades` (one thread per cascade; :func:`fit_solve`, one thread per light, is the twin)
   grows, clips, merges and nests the windows and writes the cascades' views and states into ``LightMaps.views`` /
   ``states`` / ``outside`` (see ``LightMaps``);
4. the photon and raster kernels read those arrays: the host neither waits for the fit nor knows its result.

The numpy fit (:meth:`LightViewFitter.fit_host`: read the depths back, ``fit_angle``, ``fit_windows``,
``LightMaps.set_windows``) is the naive twin; a test compares the two.

Photons are then emitted from the cascades (``PhotonPass.rsm_batches``): each active cascade gets an
equal share of the light's photons, a cascade leaves the samples inside the next finer window to it,
and the power on the pilot texels outside the coarsest window is booked as ``outside_fitted_view``
(``common.book_outside_window``), so the ledger still closes to the light's whole specular power.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..frame import FrameInputs
from ..optics import reflect, refract
from ..raster import GBuffer, LightMaps, Rasterizer
from ..raster.kernels import TexelEmission, texel_emitted_flux, texel_ior, texel_roughness
from ..raster.light_maps import INACTIVE_FAR, CascadeState
from ..raster.views import MERGE_AREA, ViewParams, fit_angle, fit_windows, fixed_projection, pixel_ray_world
from ..scene import DeviceScene
from ..scene.device import SurfaceGeometry
from .common import surface_at_sample, tally_new
from .kernels_world import WT_LANDED, CameraBuffers, WorldScene, camera_pixel, world_trace
from .world import world_scene

wp.set_module_options({"enable_backward": False})  # forward only (world_trace books into a tally by reference)


@wp.func
def pilot_branch(
    light: ViewParams,
    light_kind: int,
    light_pos: wp.vec3,
    rsm_depth: wp.array(dtype=wp.float32),
    rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
    rsm_tri: wp.array(dtype=wp.int32),
    geometry: SurfaceGeometry,
    ws: WorldScene,
    cam: CameraBuffers,
    roughness_cutoff: float,
    thickness: float,
    thickness_rel: float,
    t_max: float,
    max_bounces: int,
    seed: int,
    p: int,
    branch: int,  # 0 reflected, 1 refracted
) -> float:
    """Camera depth [m] where branch ``branch`` of pilot texel ``p`` lands on a surface the camera sees (traced in
    world space from the texel's exact surface point), 0 where it lands nowhere seen or the texel sends no light
    (arguments as :func:`pilot_receivers`'; ``cam.view`` is this frame's camera)."""
    tri = rsm_tri[p]
    if tri < 0 or texel_roughness(rsm_emission, tri) > roughness_cutoff:
        return 0.0
    if wp.length(texel_emitted_flux(rsm_emission, light, p)) <= 0.0:
        return 0.0
    lo, ld = pixel_ray_world(light, float(p % light.width) + 0.5, float(p / light.width) + 0.5)
    x, n_s = surface_at_sample(light, lo, ld, tri, p, rsm_depth, geometry)
    d_in = wp.normalize(ld)
    if light_kind != 0:
        d_in = wp.normalize(x - light_pos)
    nn = n_s
    eta = texel_ior(rsm_emission, tri)
    if wp.dot(d_in, n_s) > 0.0:
        nn = -n_s
        eta = 1.0 / eta
    d = reflect(d_in, nn)
    if branch == 1:
        if ws.opacity[ws.triangle_material[tri]] >= 1.0:  # opaque: no refracted branch
            return 0.0
        d = refract(d_in, nn, eta)
        if wp.length(d) == 0.0:  # total internal reflection
            return 0.0
    tally = tally_new()  # the pilot's bookings: discarded
    state = wp.rand_init(seed, 2 * p + branch)
    status, y, nr, d_end, power, state = world_trace(ws, x, n_s, d, wp.vec3(1.0), state, roughness_cutoff, t_max,
                                                     max_bounces, tally)
    if status != WT_LANDED:
        return 0.0
    pix, q = camera_pixel(cam, y)
    if pix < 0:
        return 0.0
    zc = cam.depth[pix]
    if zc <= 0.0 or wp.abs(q[2] - zc) > thickness + thickness_rel * zc or wp.dot(-d_end, cam.normal[pix]) < 0.0:
        return 0.0
    return q[2]


@wp.kernel
def pilot_receivers(
    light: ViewParams,  # a pilot (whole) view of the light
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,  # [m]
    rsm_depth: wp.array(dtype=wp.float32),  # (P*P,) specular layer's depth [m] (read)
    rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
    rsm_tri: wp.array(dtype=wp.int32),  # (P*P,) -1 = none (read)
    geometry: SurfaceGeometry,
    ws: WorldScene,
    cam: CameraBuffers,  # its ``view`` is replaced by cameras[0]
    cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (frame.FrameInputs.cameras, read)
    roughness_cutoff: float,
    thickness: float,  # [m] depth-visibility tolerance, absolute
    thickness_rel: float,  # relative (× depth)
    t_max: float,  # [m]
    max_bounces: int,
    randoms: wp.array(dtype=wp.vec3i),  # (S,) per stream, the seed third (frame.FrameInputs.randoms, read)
    stream: int,  # this pilot view's stream
    receiver_depth: wp.array(dtype=wp.float32),  # (P*P,) nearest camera depth [m] a texel's light is seen at, 0 = none (write)
):
    p = wp.tid()
    receiver_depth[p] = 0.0
    cam.view = cameras[0]
    seed = randoms[stream][2]
    nearest = float(0.0)
    for branch in range(2):
        z = pilot_branch(light, light_kind, light_pos, rsm_depth, rsm_emission, rsm_tri,
                         geometry, ws, cam, roughness_cutoff, thickness, thickness_rel, t_max, max_bounces, seed, p,
                         branch)
        if z > 0.0 and (nearest == 0.0 or z < nearest):
            nearest = z
    receiver_depth[p] = nearest


#: a branch's receiver depth in ``pilot_branches``' scratch when it lands nowhere the camera sees
PILOT_NONE = wp.constant(float("inf"))
#: threads per block of ``pilot_branches`` on CUDA: a 128² pilot's 2 × 16k branches in 512 blocks, spread over every
#: SM (blocks of 256 over one branch a thread filled 64 SMs of an H100's 132 with 8 warps each)
PILOT_BLOCK = 64


def _make_pilot_branches(light_ortho: int = -1, camera_ortho: int = -1):
    """The kernel :func:`pilot_branches`. ``light_ortho``, ``camera_ortho``: -1 reads the pilot view's and the camera's
    projection (``ViewParams.orthographic``) at run time (the module's ``pilot_branches``, the twin); 0 or 1 compiles
    it for that projection of the pilot view or of the camera (:func:`projected_pilot_branches`): both views are read
    with their ``orthographic`` field replaced by the constant, which the compiler folds through ``pixel_ray_world``
    (the texel's ray, ``texel_surface``) and ``camera_pixel``'s ``view_project``, so a launch carries only its
    projections' code (the same values wherever the constants equal the views' fields: the same bits). Such kernels
    are modules of their own, compiled when first launched (as ``kernels_cisp.projected_trace``)."""
    LIGHT_ORTHO = int(light_ortho)
    CAMERA_ORTHO = int(camera_ortho)

    light_projected = fixed_projection(LIGHT_ORTHO)
    camera_projected = fixed_projection(CAMERA_ORTHO)

    def pilot_branches(
        light: ViewParams,  # a pilot (whole) view of the light
        light_kind: int,  # 0 distant, 1 point, 2 spot
        light_pos: wp.vec3,  # [m]
        rsm_depth: wp.array(dtype=wp.float32),  # (P*P,) specular layer's depth [m] (read)
        rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
        rsm_tri: wp.array(dtype=wp.int32),  # (P*P,) -1 = none (read)
        geometry: SurfaceGeometry,
        ws: WorldScene,
        cam: CameraBuffers,  # its ``view`` is replaced by cameras[0]
        cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (frame.FrameInputs.cameras, read)
        roughness_cutoff: float,
        thickness: float,  # [m] depth-visibility tolerance, absolute
        thickness_rel: float,  # relative (× depth)
        t_max: float,  # [m]
        max_bounces: int,
        randoms: wp.array(dtype=wp.vec3i),  # (S,) per stream, the seed third (frame.FrameInputs.randoms, read)
        stream: int,  # this pilot view's stream
        branch_depth: wp.array(dtype=wp.float32),  # (2*P*P,) camera depth [m] where branch b of texel p lands, at
        # b*P*P + p; PILOT_NONE where it lands nowhere the camera sees (write)
    ):
        """:func:`pilot_receivers` with one thread per texel and branch (threads 0..P²-1 reflect, P²..2P²-1 refract,
        so a warp traces alike): twice the threads for a launch of 16k texels that filled half the GPU, and a warp
        waits for its own branch's longest trace, not for both. :func:`pilot_nearest` takes the nearer branch."""
        tid = wp.tid()
        n = light.width * light.height
        branch = tid / n
        p = tid - branch * n
        branch_depth[tid] = PILOT_NONE
        cam.view = camera_projected(cameras[0])
        z = pilot_branch(light_projected(light), light_kind, light_pos, rsm_depth, rsm_emission, rsm_tri, geometry, ws, cam, roughness_cutoff, thickness, thickness_rel, t_max, max_bounces,
                         randoms[stream][2], p, branch)
        if z > 0.0:
            branch_depth[tid] = z

    # an orthographic pilot's or camera's kernel named apart (the per-kernel tables: the pool's sun apart from its spot)
    pilot_branches.__qualname__ = ("pilot_branches" + ("_ortho" if LIGHT_ORTHO == 1 else "")
                                   + ("_orthocam" if CAMERA_ORTHO == 1 else ""))
    projected = LIGHT_ORTHO >= 0 or CAMERA_ORTHO >= 0
    return wp.kernel(pilot_branches, enable_backward=False, module="unique" if projected else None)


#: the pilot trace, one thread per texel and branch, reading the views' projections at run time (the twin of the
#: projected kernels ``LightViewFitter`` launches: :func:`projected_pilot_branches`)
pilot_branches = _make_pilot_branches()

_PROJECTED_PILOTS: dict = {}


def projected_pilot_branches(light_ortho: int, camera_ortho: int):
    """:func:`pilot_branches` compiled for one projection of the pilot view and one of the camera (0 perspective,
    1 orthographic; :func:`_make_pilot_branches`), made on first use, each a module of its own: the kernel
    ``LightViewFitter.pilot_kernel`` picks (the pool's sun is orthographic, its spot, the Cornell box's light and every
    shipped camera perspective). The same inputs, the same outputs bit for bit where the views have those
    projections (``tests/test_fit.py``)."""
    key = (int(light_ortho), int(camera_ortho))
    if key not in _PROJECTED_PILOTS:
        _PROJECTED_PILOTS[key] = _make_pilot_branches(*key)
    return _PROJECTED_PILOTS[key]


@wp.kernel
def pilot_nearest(
    branch_depth: wp.array(dtype=wp.float32),  # (V*2*P*P,) each pilot view's pilot_branches scratch in turn (read)
    texels: int,  # P*P
    receiver_depth: wp.array(dtype=wp.float32),  # (V*P*P,) the light's pilots' receiver depths [m], 0 = none (write)
):
    """Texel g's receiver depth from its two branches, as :func:`pilot_receivers` keeps it: the reflected
    branch's depth, then the refracted one's where there was none (0) or it is nearer."""
    g = wp.tid()
    b = g / texels
    p = g - b * texels
    nearest = float(0.0)
    d0 = branch_depth[2 * b * texels + p]
    d1 = branch_depth[(2 * b + 1) * texels + p]
    if d0 != PILOT_NONE:
        nearest = d0
    if d1 != PILOT_NONE and (nearest == 0.0 or d1 < nearest):
        nearest = d1
    receiver_depth[g] = nearest


#: turns about the pilot view's axis tried by the fit, in [0, 90°) (``views.fit_angle``'s ``steps``)
FIT_STEPS = 18
#: threads per block of the fit's reductions on CUDA (one per block on the CPU): 512 = four rows of a 128² pilot at a
#: time, so a thread's column takes 8 rounds of COLUMN_ROUND rows instead of 16 at 256 (each round a round trip to L2,
#: ~0.4 µs: perf_notes sections 53, 63); 104 registers (fit_reduce_angles) × 512 fit one block an SM, and the launches
#: are 19 and 2 blocks a pilot view
FIT_BLOCK = 512
MAX_CASCADES = 4  #: LightViewSettings.cascades is at most this (the solve keeps windows in a mat44d)
#: where a LightViewFitter fits unless told: True, on the device; False, the numpy twin (a host sync per frame)
FIT_ON_DEVICE = True


@wp.func
def _turn(i: int, j: int, w: int, h: int, c: wp.float64, s: wp.float64, aspect: wp.float64):
    """``views.rotate_pixels`` of the centre of texel (i, j) about the pilot image's centre (float64)."""
    half = wp.float64(0.5)
    dx = wp.float64(i) + half - half * wp.float64(w)
    dy = wp.float64(j) + half - half * wp.float64(h)
    return half * wp.float64(w) + c * dx - s * aspect * dy, half * wp.float64(h) + s * dx / aspect + c * dy


@wp.func
def _step_angle(k: int) -> wp.float64:
    return wp.float64(0.5 * wp.pi) * wp.float64(k) / wp.float64(FIT_STEPS)


@wp.func
def _box_reduce(umin: wp.float64, umax: wp.float64, vmin: wp.float64, vmax: wp.float64) -> wp.vec4d:
    """The block's (min u, max u, min v, max v) of its threads' boxes (Warp tiles)."""
    a = wp.tile_min(wp.tile(umin))
    b = wp.tile_max(wp.tile(umax))
    c = wp.tile_min(wp.tile(vmin))
    d = wp.tile_max(wp.tile(vmax))
    return wp.vec4d(a[0], b[0], c[0], d[0])


@wp.kernel
def fit_reduce_angles_naive(
    receiver_depth: wp.array(dtype=wp.float32),  # (V*P*P,) the light's pilots' receiver depths [m], 0 = none (read)
    width: int,  # P
    height: int,
    aspects: wp.array(dtype=wp.float64),  # (V,) each pilot view's fx / fy (read)
    boxes: wp.array(dtype=wp.vec4d),  # (V*(FIT_STEPS+1),) per view and turn k < FIT_STEPS the useful texels' turned
    # box (min u, max u, min v, max v) [pilot pixels]; at k = FIT_STEPS (min depth, max depth, count, 0) (write)
):
    """One block per (pilot view, turn): the box of the useful texels (receiver depth > 0) turned by that
    angle, each thread over a strided share of the texels, reduced with Warp tiles (``views.fit_angle``).
    The twin of :func:`fit_reduce_angles` (every texel turned)."""
    b, k, lane = wp.tid()
    n = width * height
    big = wp.float64(1.0e300)
    umin = big
    umax = -big
    vmin = big
    vmax = -big
    count = wp.float64(0.0)
    c = wp.cos(_step_angle(k))
    s = wp.sin(_step_angle(k))
    aspect = aspects[b]
    p = lane
    while p < n:
        z = receiver_depth[b * n + p]
        if z > 0.0:
            if k == FIT_STEPS:
                umin = wp.min(umin, wp.float64(z))
                umax = wp.max(umax, wp.float64(z))
                count += wp.float64(1.0)
            else:
                u, v = _turn(p % width, p / width, width, height, c, s, aspect)
                umin = wp.min(umin, u)
                umax = wp.max(umax, u)
                vmin = wp.min(vmin, v)
                vmax = wp.max(vmax, v)
        p += wp.block_dim()
    box = _box_reduce(umin, umax, vmin, vmax)
    total = wp.tile_sum(wp.tile(count))
    if lane == 0:
        if k == FIT_STEPS:
            box = wp.vec4d(box[0], box[1], total[0], wp.float64(0.0))
        boxes[b * (FIT_STEPS + 1) + k] = box


@wp.func
def _fitted_angle(boxes: wp.array(dtype=wp.vec4d), b: int) -> wp.float64:
    """``views.fit_angle`` from the reduced boxes: the smallest turn unless a later one is clearly tighter."""
    best = wp.float64(0.0)
    if boxes[b * (FIT_STEPS + 1) + FIT_STEPS][2] == wp.float64(0.0):
        return best
    best_area = wp.float64(1.0e300)
    for k in range(FIT_STEPS):
        q = boxes[b * (FIT_STEPS + 1) + k]
        area = (q[1] - q[0] + wp.float64(1.0)) * (q[3] - q[2] + wp.float64(1.0))
        if area < best_area * wp.float64(0.98):
            best = _step_angle(k)
            best_area = area
    return best


@wp.func
def _split(z_near: wp.float64, z_far: wp.float64, c: int, cascades: int) -> wp.float64:
    """``views.cascade_splits``: the receiver depth [m] that ends cascade c (blend 0.5; the last is infinite)."""
    if c == cascades - 1:
        return wp.float64(1.0e300)
    i = wp.float64(c + 1) / wp.float64(cascades)
    zn = wp.max(z_near, wp.float64(1.0e-6))
    log = zn * wp.pow(z_far / zn, i)
    uni = zn + (z_far - zn) * i
    return wp.float64(0.5) * log + wp.float64(0.5) * uni


@wp.kernel
def fit_reduce_cascades_naive(
    receiver_depth: wp.array(dtype=wp.float32),  # (V*P*P,) (read)
    width: int,
    height: int,
    aspects: wp.array(dtype=wp.float64),  # (V,) (read)
    cascades: int,
    boxes: wp.array(dtype=wp.vec4d),  # (V*(FIT_STEPS+1),) from fit_reduce_angles (read)
    cascade_boxes: wp.array(dtype=wp.vec4d),  # (V*cascades,) turned box of the texels nearer than each split (write)
    cascade_counts: wp.array(dtype=wp.float64),  # (V*cascades,) those texels (write)
    angles: wp.array(dtype=wp.float64),  # (V,) the fitted turn [rad] (write)
):
    """One block per (pilot view, cascade): the tightest turn (``views.fit_angle``), the cascade's depth split
    (``views.cascade_splits``) and the turned box of the useful texels it covers (``views.fit_windows``).
    The twin of :func:`fit_reduce_cascades` (every texel turned)."""
    b, ci, lane = wp.tid()
    n = width * height
    angle = _fitted_angle(boxes, b)
    zs = boxes[b * (FIT_STEPS + 1) + FIT_STEPS]
    split = _split(zs[0], zs[1], ci, cascades)
    c = wp.cos(angle)
    s = wp.sin(angle)
    aspect = aspects[b]
    big = wp.float64(1.0e300)
    umin = big
    umax = -big
    vmin = big
    vmax = -big
    count = wp.float64(0.0)
    p = lane
    while p < n:
        z = receiver_depth[b * n + p]
        if z > 0.0 and wp.float64(z) <= split:
            u, v = _turn(p % width, p / width, width, height, c, s, aspect)
            umin = wp.min(umin, u)
            umax = wp.max(umax, u)
            vmin = wp.min(vmin, v)
            vmax = wp.max(vmax, v)
            count += wp.float64(1.0)
        p += wp.block_dim()
    box = _box_reduce(umin, umax, vmin, vmax)
    total = wp.tile_sum(wp.tile(count))
    if lane == 0:
        cascade_boxes[b * cascades + ci] = box
        cascade_counts[b * cascades + ci] = total[0]
        if ci == 0:
            angles[b] = angle


#: rows of a column :func:`_column_box` reads a round (a thread's loads were one after another: 64 dependent
#: round trips to L2 for a 128² pilot in blocks of 256)
COLUMN_ROUND = wp.constant(4)


@wp.func
def _receiver_at(receiver_depth: wp.array(dtype=wp.float32), branch_depth: wp.array(dtype=wp.float32), pair: int,
                 base: int, n: int, p: int) -> float:
    """Texel p's receiver depth [m] of the pilot view whose texels start at ``base`` (``n`` of them): from its two
    branches in :func:`pilot_branches`' scratch by :func:`pilot_nearest`'s rule (``pair`` != 0), or as stored."""
    if pair != 0:
        d0 = branch_depth[2 * base + p]
        d1 = branch_depth[2 * base + n + p]
        nearest = float(0.0)
        if d0 != PILOT_NONE:
            nearest = d0
        if d1 != PILOT_NONE and (nearest == 0.0 or d1 < nearest):
            nearest = d1
        return nearest
    return receiver_depth[base + p]


@wp.func
def _take_row(z: float, j: int, split: wp.float64, first: int, last: int, count: wp.float64, zmin: wp.float64,
              zmax: wp.float64):
    """A column's first and last useful rows, count and depth range grown by row j's receiver depth z (useful:
    0 < z <= ``split``; a row past the pilot reads z = 0)."""
    if z > 0.0 and wp.float64(z) <= split:
        if first < 0:
            first = j
        last = j
        count += wp.float64(1.0)
        zmin = wp.min(zmin, wp.float64(z))
        zmax = wp.max(zmax, wp.float64(z))
    return first, last, count, zmin, zmax


@wp.func
def _column_box(receiver_depth: wp.array(dtype=wp.float32), branch_depth: wp.array(dtype=wp.float32), pair: int,
                write: int, base: int, width: int, height: int, lane: int, bd: int, c: wp.float64, s: wp.float64,
                aspect: wp.float64, split: wp.float64, turn: int):
    """This thread's share of a turned box by columns: (min u, max u, min v, max v, count, min z, max z) over the
    useful texels (0 < z <= ``split``; an infinite ``split`` takes every z > 0) of its columns (``i = lane % width``, then every ``bd``-th) and rows
    (``j = lane / width``, then every ``max(1, bd / width)``-th: a warp reads one row's texels side by side), four
    rows a round (``COLUMN_ROUND``: their loads issued together).

    Only a column's first and last useful rows are turned (``turn`` != 0): for a turn in [0°, 90°) (c > 0, s >= 0)
    ``_turn``'s u = (hw + c·dx) − (s·aspect)·dy falls and v = (hh + s·dx/aspect) + c·dy rises with the row,
    operation by operation (each a correctly rounded product or sum of a monotone term), so the column's extremes
    of u and v lie at those rows: the same values, bit for bit, as turning every texel."""
    big = wp.float64(1.0e300)
    umin = big
    umax = -big
    vmin = big
    vmax = -big
    zmin = big
    zmax = -big
    count = wp.float64(0.0)
    groups = wp.max(1, bd / width)
    n = width * height
    if lane < groups * width:
        i = lane % width
        while i < width:
            first = int(-1)
            last = int(-1)
            j = lane / width
            while j < height:  # COLUMN_ROUND rows a round: their loads in flight together, then taken in row order
                p = j * width + i
                dp = groups * width
                z0 = _receiver_at(receiver_depth, branch_depth, pair, base, n, p)
                z1 = float(0.0)
                z2 = float(0.0)
                z3 = float(0.0)
                if j + groups < height:
                    z1 = _receiver_at(receiver_depth, branch_depth, pair, base, n, p + dp)
                if j + 2 * groups < height:
                    z2 = _receiver_at(receiver_depth, branch_depth, pair, base, n, p + 2 * dp)
                if j + 3 * groups < height:
                    z3 = _receiver_at(receiver_depth, branch_depth, pair, base, n, p + 3 * dp)
                if write != 0:
                    receiver_depth[base + p] = z0
                    if j + groups < height:
                        receiver_depth[base + p + dp] = z1
                    if j + 2 * groups < height:
                        receiver_depth[base + p + 2 * dp] = z2
                    if j + 3 * groups < height:
                        receiver_depth[base + p + 3 * dp] = z3
                first, last, count, zmin, zmax = _take_row(z0, j, split, first, last, count, zmin, zmax)
                first, last, count, zmin, zmax = _take_row(z1, j + groups, split, first, last, count, zmin, zmax)
                first, last, count, zmin, zmax = _take_row(z2, j + 2 * groups, split, first, last, count, zmin, zmax)
                first, last, count, zmin, zmax = _take_row(z3, j + 3 * groups, split, first, last, count, zmin, zmax)
                j += COLUMN_ROUND * groups
            if first >= 0 and turn != 0:
                u0, v0 = _turn(i, first, width, height, c, s, aspect)
                u1, v1 = _turn(i, last, width, height, c, s, aspect)
                umin = wp.min(umin, wp.min(u0, u1))
                umax = wp.max(umax, wp.max(u0, u1))
                vmin = wp.min(vmin, wp.min(v0, v1))
                vmax = wp.max(vmax, wp.max(v0, v1))
            i += bd
    return umin, umax, vmin, vmax, count, zmin, zmax


@wp.kernel
def fit_reduce_angles(
    branch_depth: wp.array(dtype=wp.float32),  # (V*2*P*P,) each pilot view's pilot_branches scratch (read when
    # from_branches)
    from_branches: int,  # 1: each texel's receiver depth from its two branches (pilot_nearest folded in: the
    # depth-range block writes them to receiver_depth); 0: read from receiver_depth
    receiver_depth: wp.array(dtype=wp.float32),  # (V*P*P,) the light's pilots' receiver depths [m], 0 = none (read,
    # or write)
    width: int,  # P
    height: int,
    aspects: wp.array(dtype=wp.float64),  # (V,) each pilot view's fx / fy (read)
    boxes: wp.array(dtype=wp.vec4d),  # (V*(FIT_STEPS+1),) per view and turn k < FIT_STEPS the useful texels' turned
    # box (min u, max u, min v, max v) [pilot pixels]; at k = FIT_STEPS (min depth, max depth, count, 0) (write)
):
    """One block per (pilot view, turn): the box of the useful texels (receiver depth > 0) turned by that angle
    (``views.fit_angle``), reduced with Warp tiles; each thread reads its columns' texels and turns only each column's
    first and last useful texel (:func:`_column_box`). Equal, bit for bit, to :func:`fit_reduce_angles_naive`, which
    turns every texel (a float64 division each). With ``from_branches`` every block takes each texel's nearer branch
    itself (:func:`pilot_nearest`'s rule) and the depth-range block (k = FIT_STEPS) writes the receiver depths that
    :func:`fit_reduce_cascades` reads: :func:`pilot_nearest`'s launch folded in."""
    b, k, lane = wp.tid()
    c = wp.cos(_step_angle(k))
    s = wp.sin(_step_angle(k))
    last_block = wp.where(k == FIT_STEPS, 1, 0)
    umin, umax, vmin, vmax, count, zmin, zmax = _column_box(receiver_depth, branch_depth, from_branches,
                                                            from_branches * last_block, b * width * height, width,
                                                            height, lane, wp.block_dim(), c, s, aspects[b],
                                                            wp.float64(PILOT_NONE), 1 - last_block)
    if k == FIT_STEPS:
        umin = zmin
        umax = zmax
    box = _box_reduce(umin, umax, vmin, vmax)
    total = wp.tile_sum(wp.tile(count))
    if lane == 0:
        if k == FIT_STEPS:
            box = wp.vec4d(box[0], box[1], total[0], wp.float64(0.0))
        boxes[b * (FIT_STEPS + 1) + k] = box


@wp.kernel
def fit_reduce_cascades(
    receiver_depth: wp.array(dtype=wp.float32),  # (V*P*P,) (read)
    width: int,
    height: int,
    aspects: wp.array(dtype=wp.float64),  # (V,) (read)
    cascades: int,
    boxes: wp.array(dtype=wp.vec4d),  # (V*(FIT_STEPS+1),) from fit_reduce_angles (read)
    cascade_boxes: wp.array(dtype=wp.vec4d),  # (V*cascades,) turned box of the texels nearer than each split (write)
    cascade_counts: wp.array(dtype=wp.float64),  # (V*cascades,) those texels (write)
    angles: wp.array(dtype=wp.float64),  # (V,) the fitted turn [rad] (write)
):
    """One block per (pilot view, cascade): the tightest turn (``views.fit_angle``), the cascade's depth split
    (``views.cascade_splits``) and the turned box of the useful texels it covers (``views.fit_windows``), by columns
    as :func:`fit_reduce_angles`. Equal, bit for bit, to :func:`fit_reduce_cascades_naive`."""
    b, ci, lane = wp.tid()
    angle = _fitted_angle(boxes, b)
    zs = boxes[b * (FIT_STEPS + 1) + FIT_STEPS]
    split = _split(zs[0], zs[1], ci, cascades)
    umin, umax, vmin, vmax, count, zmin, zmax = _column_box(receiver_depth, receiver_depth, 0, 0, b * width * height,
                                                            width, height, lane, wp.block_dim(), wp.cos(angle),
                                                            wp.sin(angle), aspects[b], split, 1)
    box = _box_reduce(umin, umax, vmin, vmax)
    total = wp.tile_sum(wp.tile(count))
    if lane == 0:
        cascade_boxes[b * cascades + ci] = box
        cascade_counts[b * cascades + ci] = total[0]
        if ci == 0:
            angles[b] = angle


@wp.func
def _round6(x: wp.float64) -> wp.float64:
    """``round(x, 6)``, as the host fit keeps its windows."""
    return wp.round(x * wp.float64(1.0e6)) / wp.float64(1.0e6)


@wp.func
def _area(w: wp.vec4d) -> wp.float64:
    return (w[2] - w[0]) * (w[3] - w[1])


@wp.func
def _same4(a: wp.vec4d, b: wp.vec4d) -> int:
    return int(a[0] == b[0] and a[1] == b[1] and a[2] == b[2] and a[3] == b[3])


@wp.func
def _f32(x: wp.float64) -> float:
    return wp.float32(x)


@wp.func
def _window_params(pilot: ViewParams, angle: wp.float64, win: wp.vec4d, size: int) -> ViewParams:
    """``views.window_view(views.rotated_view(pilot, angle), win, size)`` as kernels see it."""
    c = wp.cos(angle)
    s = wp.sin(angle)
    cf = _f32(c)
    sf = _f32(s)
    rz = wp.mat44(cf, -sf, 0.0, 0.0, sf, cf, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    v = ViewParams()
    v.view_to_world = pilot.view_to_world
    v.world_to_view = pilot.world_to_view
    if angle != wp.float64(0.0):
        v.view_to_world = pilot.view_to_world * rz
        v.world_to_view = wp.transpose(rz) * pilot.world_to_view
    sx = wp.float64(size) / (win[2] - win[0])
    sy = wp.float64(size) / (win[3] - win[1])
    v.fx = _f32(wp.float64(pilot.fx) * sx)
    v.fy = _f32(wp.float64(pilot.fy) * sy)
    v.cx = _f32((wp.float64(pilot.cx) - win[0]) * sx)
    v.cy = _f32((wp.float64(pilot.cy) - win[1]) * sy)
    v.near = pilot.near
    v.far = pilot.far
    v.width = size
    v.height = size
    v.orthographic = pilot.orthographic
    return v


@wp.func
def _same_view(a: ViewParams, b: ViewParams) -> int:
    same = int(a.fx == b.fx and a.fy == b.fy and a.cx == b.cx and a.cy == b.cy and a.near == b.near and a.far == b.far)
    for i in range(4):
        for j in range(4):
            if a.world_to_view[i, j] != b.world_to_view[i, j]:
                same = 0
    return same


@wp.func
def _view_windows(b: int, width: int, height: int, aspects: wp.array(dtype=wp.float64), cascades: int, margin: float,
                  cascade_boxes: wp.array(dtype=wp.vec4d), cascade_counts: wp.array(dtype=wp.float64),
                  angles: wp.array(dtype=wp.float64)):
    """Pilot view ``b``'s windows (``views.fit_windows``: grown by the margin and the turned texel's half extent,
    clipped to the turned pilot image, merged when a finer one covers more than ``MERGE_AREA`` of the next, repeats
    dropped), finest first. Returns (windows as rows of a mat44d, their count, the view's turn [rad])."""
    angle = angles[b]
    aspect = aspects[b]
    c = wp.cos(angle)
    s = wp.sin(angle)
    ca = wp.abs(c)
    sa = wp.abs(s)
    half_u = wp.float64(0.5) * (ca + sa * aspect)
    half_v = wp.float64(0.5) * (sa / aspect + ca)
    w = wp.float64(width)
    h = wp.float64(height)
    hw = wp.float64(0.5) * w
    hh = wp.float64(0.5) * h
    # the turned pilot image's box: its four corners turned about the centre
    lo_u = wp.float64(1.0e300)
    hi_u = -lo_u
    lo_v = lo_u
    hi_v = -lo_u
    for corner in range(4):
        px = wp.float64(0.0)
        py = wp.float64(0.0)
        if corner == 1 or corner == 2:
            px = w
        if corner >= 2:
            py = h
        tu = hw + c * (px - hw) - s * aspect * (py - hh)
        tv = hh + s * (px - hw) / aspect + c * (py - hh)
        lo_u = wp.min(lo_u, tu)
        hi_u = wp.max(hi_u, tu)
        lo_v = wp.min(lo_v, tv)
        hi_v = wp.max(hi_v, tv)
    wins = wp.mat44d()
    n_win = int(0)
    for ci in range(cascades):
        if cascade_counts[b * cascades + ci] > wp.float64(0.0):
            box = cascade_boxes[b * cascades + ci]
            x0 = box[0] - half_u
            x1 = box[1] + half_u
            y0 = box[2] - half_v
            y1 = box[3] + half_v
            gx = wp.float64(margin) + wp.float64(0.02) * (x1 - x0)
            gy = wp.float64(margin) + wp.float64(0.02) * (y1 - y0)
            wins[n_win] = wp.vec4d(_round6(wp.max(x0 - gx, lo_u)), _round6(wp.max(y0 - gy, lo_v)),
                                   _round6(wp.min(x1 + gx, hi_u)), _round6(wp.min(y1 + gy, hi_v)))
            n_win += 1
    # merge a finer window into the next coarser when it is not much smaller, then drop repeats
    kept = wp.mat44d()
    n_kept = int(0)
    for i in range(n_win):
        keep = int(1)
        if i < n_win - 1:
            keep = int(_area(wins[i]) <= wp.float64(MERGE_AREA) * _area(wins[i + 1]))
        if keep != 0:
            if n_kept == 0 or _same4(wins[i], kept[n_kept - 1]) == 0:
                kept[n_kept] = wins[i]
                n_kept += 1
    return kept, n_kept, angle


@wp.func
def _write_outside(b: int, kept: wp.mat44d, n_kept: int, angle: wp.float64, outside: wp.array(dtype=wp.vec4),
                   outside_angle: wp.array(dtype=wp.float32)):
    """Pilot view ``b``'s coarsest window (zeros when none) and its turn, as ``LightMaps.outside`` keeps them."""
    if n_kept > 0:
        last = kept[n_kept - 1]
        outside[b] = wp.vec4(_f32(last[0]), _f32(last[1]), _f32(last[2]), _f32(last[3]))
    else:
        outside[b] = wp.vec4(0.0)
    outside_angle[b] = _f32(angle)


@wp.func
def _cascade_view(pilot: ViewParams, old: ViewParams, ci: int, cascades: int, kept: wp.mat44d, n_kept: int,
                  angle: wp.float64, rsm_size: int):
    """Cascade ``ci``'s view and state (``active_views`` left 0) from its pilot view's windows, as
    ``LightMaps.set_windows`` writes them; ``old``: its view last frame (an inactive cascade keeps it with ``far`` =
    INACTIVE_FAR; ``changed`` compares with it)."""
    c_empty = cascades - n_kept
    st = CascadeState()
    st.texel_scale = 1.0
    st.skip_window = wp.vec4(0.0)
    if ci < c_empty:
        v = old
        v.far = INACTIVE_FAR
        st.active = 0
        st.changed = 1 - _same_view(v, old)
        return v, st
    win = kept[ci - c_empty]
    v = _window_params(pilot, angle, win, rsm_size)
    sx = wp.float64(rsm_size) / (win[2] - win[0])
    sy = wp.float64(rsm_size) / (win[3] - win[1])
    st.active = 1
    st.texel_scale = _f32(wp.float64(1.0) / (sx * sy))
    if ci > c_empty:
        f = kept[ci - c_empty - 1]
        st.skip_window = wp.vec4(_f32((f[0] - win[0]) * sx), _f32((f[1] - win[1]) * sy),
                                 _f32((f[2] - win[0]) * sx), _f32((f[3] - win[1]) * sy))
    st.changed = 1 - _same_view(v, old)
    return v, st


@wp.kernel
def fit_solve(
    pilot_views: wp.array(dtype=ViewParams),  # (V,) the light's pilot views (read)
    width: int,  # P
    height: int,
    aspects: wp.array(dtype=wp.float64),  # (V,) (read)
    n_views: int,  # V
    cascades: int,
    margin: float,  # pilot texels around each window (plus 2% of its size)
    rsm_size: int,
    cascade_boxes: wp.array(dtype=wp.vec4d),  # (V*cascades,) from fit_reduce_cascades (read)
    cascade_counts: wp.array(dtype=wp.float64),  # (V*cascades,) (read)
    angles: wp.array(dtype=wp.float64),  # (V,) (read)
    views: wp.array(dtype=ViewParams),  # (V*cascades,) LightMaps.views (read the last, write)
    states: wp.array(dtype=CascadeState),  # (V*cascades,) LightMaps.states (write)
    outside: wp.array(dtype=wp.vec4),  # (V,) LightMaps.outside: the coarsest window (write)
    outside_angle: wp.array(dtype=wp.float32),  # (V,) its turn [rad] (write)
):
    """One thread per light: every pilot view's windows (:func:`_view_windows`), then each cascade's view and state
    as ``LightMaps.set_windows`` writes them (:func:`_cascade_view`), one after another. The twin of
    :func:`fit_solve_cascades` (a thread a cascade)."""
    n_active = int(0)
    for b in range(n_views):
        kept, n_kept, angle = _view_windows(b, width, height, aspects, cascades, margin, cascade_boxes, cascade_counts,
                                            angles)
        _write_outside(b, kept, n_kept, angle, outside, outside_angle)
        for ci in range(cascades):
            k = b * cascades + ci
            v, st = _cascade_view(pilot_views[b], views[k], ci, cascades, kept, n_kept, angle, rsm_size)
            n_active += st.active
            views[k] = v
            states[k] = st
    for k in range(n_views * cascades):
        st = states[k]
        st.active_views = n_active
        states[k] = st


@wp.kernel
def fit_solve_cascades(
    pilot_views: wp.array(dtype=ViewParams),  # (V,) the light's pilot views (read)
    width: int,  # P
    height: int,
    aspects: wp.array(dtype=wp.float64),  # (V,) (read)
    n_views: int,  # V
    cascades: int,
    margin: float,  # pilot texels around each window (plus 2% of its size)
    rsm_size: int,
    cascade_boxes: wp.array(dtype=wp.vec4d),  # (V*cascades,) from fit_reduce_cascades (read)
    cascade_counts: wp.array(dtype=wp.float64),  # (V*cascades,) (read)
    angles: wp.array(dtype=wp.float64),  # (V,) (read)
    views: wp.array(dtype=ViewParams),  # (V*cascades,) LightMaps.views (read, write: thread k its own)
    states: wp.array(dtype=CascadeState),  # (V*cascades,) LightMaps.states (write)
    outside: wp.array(dtype=wp.vec4),  # (V,) LightMaps.outside: the coarsest window (write)
    outside_angle: wp.array(dtype=wp.float32),  # (V,) its turn [rad] (write)
):
    """:func:`fit_solve` with one thread per cascade (``dim = V*cascades``): thread k = b*cascades + ci counts every
    pilot view's windows (the light's active views: a few float64 operations a view), keeps its own view's and
    writes its cascade's view and state once, with ``active_views``; thread ci = 0 writes its view's ``outside``.
    The same functions of the same values as :func:`fit_solve` (its twin): the same bits; a light's solve is then
    one view's windows and one cascade long, not every cascade one after another."""
    k = wp.tid()
    b = k / cascades
    ci = k - b * cascades
    n_active = int(0)
    kept = wp.mat44d()
    n_kept = int(0)
    angle = wp.float64(0.0)
    for bb in range(n_views):
        kept_bb, n_bb, angle_bb = _view_windows(bb, width, height, aspects, cascades, margin, cascade_boxes,
                                                cascade_counts, angles)
        n_active += n_bb
        if bb == b:  # its own view's windows
            kept = kept_bb
            n_kept = n_bb
            angle = angle_bb
    if ci == 0:
        _write_outside(b, kept, n_kept, angle, outside, outside_angle)
    v, st = _cascade_view(pilot_views[b], views[k], ci, cascades, kept, n_kept, angle, rsm_size)
    st.active_views = n_active
    views[k] = v
    states[k] = st


class LightViewFitter:
    """Fits every light's cascades to the camera each frame; its pilot and fit buffers are allocated once.

    ``on_device`` (default): the fit runs in kernels and writes the cascades into each ``LightMaps``' device
    arrays, no host copy. ``on_device=False``: the naive twin (:meth:`fit_host`), which reads the receiver
    depths back and fits them in numpy."""

    #: True: trace the pilots with the kernel compiled for their view's and the camera's projections
    #: (:meth:`pilot_kernel`); False: the run-time one, :func:`pilot_branches` (the twin; the same bits)
    PROJECTED = True

    def __init__(self, scene: DeviceScene, gbuffer: GBuffer, lights: list[LightMaps], roughness_cutoff: float,
                 thickness: float, thickness_rel: float, max_bounces: int, t_max: float, seed: int = 0,
                 on_device: bool | None = None, inputs: FrameInputs | None = None):
        """``inputs``: the renderer's per-frame cameras and random streams (``frame.FrameInputs`` over ``lights``),
        written before :meth:`fit`; None: the fitter keeps and writes its own."""
        self.scene = scene
        self.inputs = inputs if inputs is not None else FrameInputs(lights, seed, scene.device)
        self.light_index = [i for i, lm in enumerate(lights) if lm.fitted]  #: each fitted light's index in ``lights``
        self.lights = [lm for lm in lights if lm.fitted]
        self.device = scene.device
        self.on_device = FIT_ON_DEVICE if on_device is None else bool(on_device)
        self.world = world_scene(scene) if self.lights else None
        self.cam = CameraBuffers()
        self.cam.depth, self.cam.position, self.cam.normal = gbuffer.depth, gbuffer.position, gbuffer.normal
        self.cam.solid_angle = wp.zeros(1, dtype=wp.float32, device=self.device)  # not read by the pilot
        d = self.device
        #: per light: its pilots' receiver depths [m], (V*P*P,) float32, and one slice per pilot view
        self.receiver_depth_all = [wp.zeros(sum(r.width * r.height for r in lm.pilot), dtype=wp.float32, device=d)
                                   for lm in self.lights]
        #: per light: its pilots' pilot_branches scratch, (V*2*P*P,) float32, and one (2*P*P,) slice per pilot view
        self.branch_depth_all = [wp.zeros(2 * sum(r.width * r.height for r in lm.pilot), dtype=wp.float32, device=d)
                                 for lm in self.lights]
        self.branch_depth = []
        for lm, whole in zip(self.lights, self.branch_depth_all):
            n = 2 * lm.pilot[0].width * lm.pilot[0].height
            self.branch_depth.append([whole[i * n : (i + 1) * n] for i in range(len(lm.pilot))])
        #: pilot_receivers (one thread per texel, both branches) instead of pilot_branches + pilot_nearest: the twin
        self.one_thread_per_texel = False
        #: per fitted light: its pilot traced into pilot_branches' scratch, not yet reduced to receiver depths (the
        #: device fit's fit_reduce_angles then takes the nearer branches itself: pilot_nearest folded in)
        self._branches_pending = [False] * len(self.lights)
        self.pilot_block = PILOT_BLOCK if self.device.is_cuda else 256
        self.receiver_depth = []
        for lm, whole in zip(self.lights, self.receiver_depth_all):
            n = lm.pilot[0].width * lm.pilot[0].height
            self.receiver_depth.append([whole[i * n : (i + 1) * n] for i in range(len(lm.pilot))])
        #: per light, the fit's scratch (see fit_reduce_angles, fit_reduce_cascades)
        self._aspects = [wp.array([r.view.fx / r.view.fy for r in lm.pilot], dtype=wp.float64, device=d)
                         for lm in self.lights]
        self._boxes = [wp.zeros(len(lm.pilot) * (FIT_STEPS + 1), dtype=wp.vec4d, device=d) for lm in self.lights]
        self._cascade_boxes = [wp.zeros(len(lm.pilot) * lm.cascades, dtype=wp.vec4d, device=d) for lm in self.lights]
        self._cascade_counts = [wp.zeros(len(lm.pilot) * lm.cascades, dtype=wp.float64, device=d) for lm in self.lights]
        self._angles = [wp.zeros(len(lm.pilot), dtype=wp.float64, device=d) for lm in self.lights]
        self.roughness_cutoff, self.thickness, self.thickness_rel = roughness_cutoff, thickness, thickness_rel
        self.max_bounces, self.t_max, self.seed = max_bounces, t_max, seed
        self.last_depth: list[list[np.ndarray]] = []  #: the pilots' receiver depths of the last host fit (host)
        #: threads per block of the fit's reductions (Warp runs CPU tiles one thread per block unless
        #: ``wp.config.enable_cpu_blocks`` is set; a test does, with blocks of 32)
        self.fit_block = FIT_BLOCK if self.device.is_cuda else 1
        #: the windows' solve with a thread per cascade (``fit_solve_cascades``); False: one thread a light
        #: (``fit_solve``, the twin)
        self.solve_per_cascade = True

    def fit(self, raster: Rasterizer, camera: wp.struct, frame: int) -> None:
        """Draw the pilots, trace them and fit every light's cascades (on the device, or :meth:`fit_host`)."""
        if not self.lights:
            return
        self.trace_pilots(raster, camera, frame)
        if self.on_device:
            self.fit_device()
        else:
            self.fit_host()

    def trace_pilots(self, raster: Rasterizer, camera: wp.struct, frame: int) -> None:
        """Draw the pilot views and trace their receiver depths (``receiver_depth``; on the device fit they are
        written by its first launch, :meth:`fit_light`). The camera and the seeds are read from ``inputs`` (written
        here when they do not hold ``frame`` yet and no graph is being captured)."""
        self.frame_inputs(camera, frame)
        for i in range(len(self.lights)):
            self.render_pilots(i, raster)
        for i in range(len(self.lights)):
            self.trace_light_pilots(i)

    def frame_inputs(self, camera: wp.struct, frame: int) -> None:
        """Make ``inputs`` hold ``frame`` (written here when they do not yet and no graph is being captured)."""
        if self.inputs.frame != frame and not (self.device.is_cuda and self.device.is_capturing):
            self.inputs.write(frame, camera, camera)
        self.cam.view = camera

    def render_pilots(self, i: int, raster: Rasterizer) -> None:
        """Draw fitted light ``i``'s pilot views (they read no camera: a renderer may draw them beside the G-buffer)."""
        self.lights[i].render_pilot(raster)

    def pilot_kernel(self, pilot_orthographic: bool):
        """The pilot trace for a pilot view of that projection: with ``PROJECTED``, :func:`pilot_branches` compiled for
        it and the camera's as :meth:`frame_inputs` last saw it (:func:`projected_pilot_branches`; a light keeps its
        kind, so its pilots their projection, and ``Renderer``'s captured frame is captured again when the camera's
        changes), else the run-time kernel."""
        if not self.PROJECTED:
            return pilot_branches
        return projected_pilot_branches(int(bool(pilot_orthographic)), int(bool(self.cam.view.orthographic)))

    def pilot_inputs(self, i: int, vi: int) -> list:
        """The pilot trace's inputs for fitted light ``i``'s pilot view ``vi``: :func:`pilot_branches`' arguments before
        its output ``branch_depth`` (:func:`pilot_receivers` takes the same before ``receiver_depth``)."""
        lm = self.lights[i]
        r = lm.pilot[vi]
        sp = r.specular
        return [r.view.params(), int(lm.light.kind), wp.vec3(*np.asarray(lm.light.position, np.float32)), sp.depth,
                lm.emission(r), sp.tri_id, self.scene.geometry, self.world, self.cam, self.inputs.cameras,
                float(self.roughness_cutoff), float(self.thickness), float(self.thickness_rel), float(self.t_max),
                int(self.max_bounces), self.inputs.randoms, self.inputs.pilot_stream(self.light_index[i], vi)]

    def trace_light_pilots(self, i: int) -> None:
        """Trace fitted light ``i``'s pilot texels to their receivers (reads the camera's G-buffer; the camera's
        projection as :meth:`frame_inputs` last saw it); with the fit on the device the branches are left for
        :meth:`fit_light` to take the nearer of (``_branches_pending``)."""
        lm, depths = self.lights[i], self.receiver_depth[i]
        for vi, (r, depth) in enumerate(zip(lm.pilot, depths)):
            inputs = self.pilot_inputs(i, vi)
            if self.one_thread_per_texel:
                wp.launch(pilot_receivers, dim=r.width * r.height, device=self.device, inputs=inputs + [depth])
            else:
                wp.launch(self.pilot_kernel(r.view.orthographic), dim=2 * r.width * r.height, device=self.device,
                          inputs=inputs + [self.branch_depth[i][vi]], block_dim=self.pilot_block)
        # the device fit keeps the nearer branches itself; the host fit needs the receiver depths now
        self._branches_pending[i] = not self.one_thread_per_texel and self.on_device
        if not self.one_thread_per_texel and not self._branches_pending[i]:
            p = lm.pilot[0]
            wp.launch(pilot_nearest, dim=self.receiver_depth_all[i].shape[0], device=self.device,
                      inputs=[self.branch_depth_all[i], p.width * p.height, self.receiver_depth_all[i]])

    def fit_device(self) -> None:
        """Fit every light's cascades to its pilots' receiver depths in three launches per light."""
        for i in range(len(self.lights)):
            self.fit_light(i)

    def fit_light(self, i: int) -> None:
        """Fit fitted light ``i``'s cascades to its pilots' receiver depths on the device (three launches; the first
        takes the nearer branches itself where :meth:`trace_light_pilots` left them in pilot_branches' scratch)."""
        block = self.fit_block
        lm = self.lights[i]
        vs = lm.view_settings
        p = lm.pilot[0]
        nv = len(lm.pilot)
        pending, self._branches_pending[i] = self._branches_pending[i], False
        wp.launch_tiled(fit_reduce_angles, dim=(nv, FIT_STEPS + 1), block_dim=block, device=self.device,
                        inputs=[self.branch_depth_all[i], int(pending), self.receiver_depth_all[i], p.width, p.height,
                                self._aspects[i], self._boxes[i]])
        wp.launch_tiled(fit_reduce_cascades, dim=(nv, lm.cascades), block_dim=block, device=self.device,
                        inputs=[self.receiver_depth_all[i], p.width, p.height, self._aspects[i], lm.cascades,
                                self._boxes[i], self._cascade_boxes[i], self._cascade_counts[i], self._angles[i]])
        solve = fit_solve_cascades if self.solve_per_cascade else fit_solve
        wp.launch(solve, dim=nv * lm.cascades if self.solve_per_cascade else 1, device=self.device, inputs=[
            lm.pilot_views, p.width, p.height, self._aspects[i], nv, lm.cascades, float(vs.margin), lm.rsm_size,
            self._cascade_boxes[i], self._cascade_counts[i], self._angles[i], lm.views, lm.states, lm.outside,
            lm.outside_angle])
        lm.refresh_cascade_solid_angles()

    def light_scratch(self, i: int) -> list[wp.array]:
        """The arrays fitted light ``i``'s pilot trace and fit write besides its own ``LightMaps``."""
        return [self.receiver_depth_all[i], self.branch_depth_all[i], self._boxes[i], self._cascade_boxes[i],
                self._cascade_counts[i], self._angles[i]]

    def fit_host(self) -> None:
        """The naive twin: read the receiver depths back (a host sync), fit in numpy, ``LightMaps.set_windows``."""
        self.last_depth = []
        for lm, depths in zip(self.lights, self.receiver_depth):
            vs = lm.view_settings
            host = [d.numpy().reshape(r.height, r.width) for d, r in zip(depths, lm.pilot)]
            self.last_depth.append(host)
            aspects = [r.view.fx / r.view.fy for r in lm.pilot]
            angles = [fit_angle(h, k) for h, k in zip(host, aspects)]
            lm.set_windows([fit_windows(h, vs.cascades, vs.margin, a, k) for h, a, k in zip(host, angles, aspects)],
                           angles)
