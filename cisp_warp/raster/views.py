"""Views: the camera and the light views (reflective shadow maps), as one Warp struct.

A view looks down its local -Z axis with +Y up. Pixel (column i, row j) has its centre at
(i + 0.5, j + 0.5); rows grow downwards. With view-space point (x, y, z) and linear depth
``depth = -z`` (metres, positive in front of the view):

=============  =========================================  =====================================
projection     pixel of a view-space point                ray through pixel (px, py)
=============  =========================================  =====================================
perspective    px = cx + fx·x/depth,  py = cy − fy·y/depth  origin 0, dir ((px−cx)/fx, −(py−cy)/fy, −1)
orthographic   px = cx + fx·x,        py = cy − fy·y        origin ((px−cx)/fx, −(py−cy)/fy, 0), dir (0, 0, −1)
=============  =========================================  =====================================

With these rays the ray parameter *t* equals the linear depth for both projections.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..errors import SceneError
from ..scene.model import LAYER_SPECULAR, Camera, Light, LightKind, Scene, look_at_matrix


@wp.struct
class ViewParams:
    """One view, as kernels see it."""

    world_to_view: wp.mat44  #: rigid transform, world [m] -> view [m]
    view_to_world: wp.mat44  #: its inverse
    fx: float  #: pixels per unit of x/depth (perspective) or per metre (orthographic)
    fy: float
    cx: float  #: principal point [pixels]
    cy: float
    near: float  #: nearest depth drawn [m]
    far: float  #: farthest depth drawn [m]
    width: int
    height: int
    orthographic: int  #: 1 for orthographic, 0 for perspective


@wp.func
def view_point(view: ViewParams, p_world: wp.vec3) -> wp.vec3:
    """World point -> view-space point [m]."""
    return wp.transform_point(view.world_to_view, p_world)


@wp.func
def view_project(view: ViewParams, p_view: wp.vec3) -> wp.vec3:
    """View-space point -> (px, py, depth): continuous pixel coordinates and linear depth [m]."""
    depth = -p_view[2]
    # the division outside any branch and both projections' values selected: the same bits as a return in each
    # branch, with no division's slow path merged through local memory where a kernel is at its register bound
    inv = 1.0 / wp.max(depth, 1.0e-20)
    ortho = view.orthographic != 0
    return wp.vec3(wp.where(ortho, view.cx + view.fx * p_view[0], view.cx + view.fx * p_view[0] * inv),
                   wp.where(ortho, view.cy - view.fy * p_view[1], view.cy - view.fy * p_view[1] * inv), depth)


@wp.func
def world_project(view: ViewParams, p_world: wp.vec3) -> wp.vec3:
    """World point -> (px, py, depth)."""
    return view_project(view, view_point(view, p_world))


@wp.func
def pixel_ray_view(view: ViewParams, px: float, py: float):
    """View-space ray (origin, direction) through continuous pixel coordinates; t along it is depth."""
    x = (px - view.cx) / view.fx
    y = -(py - view.cy) / view.fy
    if view.orthographic != 0:
        return wp.vec3(x, y, 0.0), wp.vec3(0.0, 0.0, -1.0)
    return wp.vec3(0.0, 0.0, 0.0), wp.vec3(x, y, -1.0)


@wp.func
def pixel_ray_world(view: ViewParams, px: float, py: float):
    """World-space ray (origin, direction) through continuous pixel coordinates; t along it is depth."""
    o, d = pixel_ray_view(view, px, py)
    return wp.transform_point(view.view_to_world, o), wp.transform_vector(view.view_to_world, d)


@wp.func
def view_eye_world(view: ViewParams, p_world: wp.vec3) -> wp.vec3:
    """Unit vector from ``p_world`` towards the view (the eye point, or the ortho view plane)."""
    if view.orthographic != 0:
        return wp.transform_vector(view.view_to_world, wp.vec3(0.0, 0.0, 1.0))
    return wp.normalize(wp.transform_point(view.view_to_world, wp.vec3(0.0, 0.0, 0.0)) - p_world)


@wp.func
def read_again(views: wp.array(dtype=ViewParams), index: int, anchor: int) -> ViewParams:
    """``views[index]`` read from memory once more, for a kernel that read it before a march and needs it again
    after: ``anchor`` is any value the caller knows to be >= 0, so the index is ``index`` while the compiler cannot
    prove the address that of the earlier read. It then loads the view again (a few L1/L2 hits) instead of keeping
    the earlier read's fields live through the march, where CISP's trace and the composite spill them at their
    register bounds."""
    return views[index + wp.min(anchor, 0)]


def _fixed_projection_func(ortho: int):
    @wp.func
    def projected(view: ViewParams) -> ViewParams:
        v = view
        if wp.static(ortho >= 0):
            v.orthographic = ortho
        return v

    return projected


_FIXED_PROJECTION = {o: _fixed_projection_func(o) for o in (-1, 0, 1)}


def fixed_projection(orthographic: int):
    """A func ``(view) -> view``: with ``orthographic`` 0 or 1 the view with its ``orthographic`` field replaced by
    that constant, which the compiler folds through everything the kernel then does with the view (a kernel compiled
    for one projection: docs/perf_notes.md sections 51, 56, 57); with -1 the view as it is (its projection read at run
    time, the twin). The same values wherever the constant equals the view's field: the same bits."""
    return _FIXED_PROJECTION[int(orthographic)]


@dataclass(frozen=True)
class View:
    """Host-side description of a view; ``params`` builds the kernel struct."""

    to_world: np.ndarray  #: 4x4 view-to-world, rigid
    width: int
    height: int
    near: float
    far: float
    fx: float
    fy: float
    orthographic: bool = False
    name: str = "camera"
    principal: tuple[float, float] | None = None  #: principal point [pixels]; None = the image centre

    @property
    def cx(self) -> float:
        return 0.5 * self.width if self.principal is None else float(self.principal[0])

    @property
    def cy(self) -> float:
        return 0.5 * self.height if self.principal is None else float(self.principal[1])

    def params(self) -> ViewParams:
        v = ViewParams()
        m = np.asarray(self.to_world, dtype=np.float64)
        inv = np.linalg.inv(m)
        v.view_to_world = wp.mat44(*m.astype(np.float32).flatten())
        v.world_to_view = wp.mat44(*inv.astype(np.float32).flatten())
        v.fx, v.fy, v.cx, v.cy = float(self.fx), float(self.fy), float(self.cx), float(self.cy)
        v.near, v.far = float(self.near), float(self.far)
        v.width, v.height = int(self.width), int(self.height)
        v.orthographic = 1 if self.orthographic else 0
        return v

    def project(self, p_world: np.ndarray) -> np.ndarray:
        """numpy twin of ``world_project``: (..., 3) world points -> (..., 3) (px, py, depth)."""
        inv = np.linalg.inv(np.asarray(self.to_world, dtype=np.float64))
        p = np.asarray(p_world, dtype=np.float64) @ inv[:3, :3].T + inv[:3, 3]
        depth = -p[..., 2]
        if self.orthographic:
            return np.stack([self.cx + self.fx * p[..., 0], self.cy - self.fy * p[..., 1], depth], -1)
        return np.stack([self.cx + self.fx * p[..., 0] / depth, self.cy - self.fy * p[..., 1] / depth, depth], -1)

    def texel_solid_angle(self) -> np.ndarray:
        """Exact solid angle [sr] of every pixel of a perspective view, shape (height, width), float64.

        The solid angle of the rectangle [x0, x1] x [y0, y1] on the plane at unit depth is
        F(x1, y1) − F(x0, y1) − F(x1, y0) + F(x0, y0) with F(x, y) = atan(x·y / sqrt(1 + x² + y²)),
        so the pixels of a view tile its frustum's solid angle exactly.
        """
        xs = (np.arange(self.width + 1) - self.cx) / self.fx
        ys = (np.arange(self.height + 1) - self.cy) / self.fy
        X, Y = np.meshgrid(xs, ys)
        F = np.arctan(X * Y / np.sqrt(1.0 + X * X + Y * Y))
        return F[1:, 1:] - F[1:, :-1] - F[:-1, 1:] + F[:-1, :-1]


def camera_view(camera: Camera) -> View:
    """The camera's view. Square pixels; ``fov_y`` (or ``ortho_height``) sets the vertical extent."""
    camera.validate()
    m = np.asarray(camera.to_world, dtype=np.float64).copy()
    for k in range(3):  # strip scale: views are rigid
        m[:3, k] /= np.linalg.norm(m[:3, k])
    if camera.orthographic:
        f = camera.height / camera.ortho_height
    else:
        f = 0.5 * camera.height / math.tan(0.5 * camera.fov_y)
    return View(m, int(camera.width), int(camera.height), float(camera.near), float(camera.far), f, f,
                bool(camera.orthographic), "camera")


def _scene_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _ortho_fit(direction: np.ndarray, fit_lo, fit_hi, scene_lo, scene_hi, size: int, name: str) -> View:
    """Orthographic view along ``direction`` whose image covers the box ``fit`` and whose depth covers the scene."""
    d = direction / np.linalg.norm(direction)
    centre = 0.5 * (np.asarray(fit_lo) + np.asarray(fit_hi))
    basis = look_at_matrix(centre - d, centre)
    r, u = basis[:3, 0], basis[:3, 1]
    fit = _scene_corners(np.asarray(fit_lo), np.asarray(fit_hi)) - centre
    xr = np.abs(fit @ r).max()
    yr = np.abs(fit @ u).max()
    span = max(xr, yr, 1e-6)
    # a margin of one texel on each side, and never a degenerate extent
    xr = max(xr, 1e-3 * span) * (1.0 + 2.0 / size)
    yr = max(yr, 1e-3 * span) * (1.0 + 2.0 / size)
    along = (_scene_corners(np.asarray(scene_lo), np.asarray(scene_hi)) - centre) @ d
    diag = float(np.linalg.norm(np.asarray(scene_hi) - np.asarray(scene_lo)))
    back = -along.min() + 0.01 * diag + 1e-3
    m = basis.copy()
    m[:3, 3] = centre - d * back
    far = back + along.max() + 0.01 * diag + 1e-3
    return View(m, size, size, 1e-4 * far, far, size / (2.0 * xr), size / (2.0 * yr), True, name)


_CUBE_FACES = (
    ("px", (1.0, 0.0, 0.0), (0.0, -1.0, 0.0)),
    ("nx", (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0)),
    ("py", (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    ("ny", (0.0, -1.0, 0.0), (0.0, 0.0, -1.0)),
    ("pz", (0.0, 0.0, 1.0), (0.0, -1.0, 0.0)),
    ("nz", (0.0, 0.0, -1.0), (0.0, -1.0, 0.0)),
)


def light_views(scene: Scene, light: Light, size: int) -> list[View]:
    """The reflective-shadow-map views of one light.

    * distant: one orthographic view fitted to the caustic-casting (specular) geometry — seed 003's
      projection volume — whose depth range spans the whole scene; all geometry when nothing is specular;
    * spot: one perspective view along the cone axis whose field of view is the cone (six cube faces
      when the cone is wider than 170°);
    * point: six 90° cube faces.
    """
    if size <= 0:
        raise SceneError(f"RSM size must be positive, got {size}", prim=light.name)
    lo, hi = scene.bounds()
    diag = float(np.linalg.norm(hi - lo))
    if light.kind == LightKind.DISTANT:
        try:
            flo, fhi = scene.bounds(LAYER_SPECULAR)
        except SceneError:
            flo, fhi = lo, hi
        return [_ortho_fit(np.asarray(light.direction, dtype=np.float64), flo, fhi, lo, hi, size, f"rsm_{light.safe_name}")]
    pos = np.asarray(light.position, dtype=np.float64)
    far = float(np.linalg.norm(_scene_corners(lo, hi) - pos, axis=1).max()) + 0.01 * diag
    near = max(1e-4 * far, 1e-4)
    if light.kind == LightKind.SPOT and light.cone_angle < math.radians(85.0):
        half = min(light.cone_angle * 1.02 + 1e-3, math.radians(85.0))
        f = 0.5 * size / math.tan(half)
        m = look_at_matrix(pos, pos + np.asarray(light.direction, dtype=np.float64))
        return [View(m, size, size, near, far, f, f, False, f"rsm_{light.safe_name}")]
    f = 0.5 * size  # tan(45°) = 1
    return [View(look_at_matrix(pos, pos + np.asarray(fwd), up), size, size, near, far, f, f, False,
                 f"rsm_{light.safe_name}_{tag}") for tag, fwd, up in _CUBE_FACES]


def shadow_view(scene: Scene, light: Light, size: int) -> View | None:
    """For a distant light, an orthographic shadow-map view fitted to the whole scene (its RSM covers
    only the specular geometry); None for point and spot lights, whose RSM views see everything lit."""
    if light.kind != LightKind.DISTANT:
        return None
    lo, hi = scene.bounds()
    return _ortho_fit(np.asarray(light.direction, dtype=np.float64), lo, hi, lo, hi, size, f"shadow_{light.safe_name}")


# --------------------------------------------------------------------------------------------------------
# Light views fitted to the camera (cascaded shadow maps for photons)


@dataclass(frozen=True)
class LightViewSettings:
    """How a light's RSM views are placed; every field reaches the fit.

    ``fit="scene"`` keeps one view per light (per cube face) over all the specular geometry, as before.
    ``fit="camera"`` fits ``cascades`` views of each such view to the part of the specular surfaces whose
    light reaches what the camera sees: a pilot of one photon per texel of a ``pilot_size``² whole view,
    traced in world space, marks the texels whose light lands on a visible pixel; the finest cascade
    covers those whose receiver is nearest the camera, each coarser one those further out as well.
    """

    fit: str = "camera"  #: "camera" (fitted cascades) or "scene" (one whole view, for comparison)
    cascades: int = 2  #: fitted views per whole view, finest (nearest the camera) first
    pilot_size: int = 128  #: edge of the whole pilot view [texels]
    margin: float = 2.0  #: pilot texels added around each fitted window (plus 2% of its size)

    def validate(self) -> None:
        """Raise :class:`SceneError` naming the first field (``fit must be ...``) whose value cannot be used."""
        if self.fit not in ("camera", "scene"):
            raise SceneError(f"fit must be 'camera' or 'scene', got {self.fit!r}")
        if not isinstance(self.cascades, (int, np.integer)) or isinstance(self.cascades, bool) or not 1 <= self.cascades <= 4:
            raise SceneError(f"cascades must be an integer in [1, 4], got {self.cascades!r}")
        if not isinstance(self.pilot_size, (int, np.integer)) or not 8 <= self.pilot_size <= 4096:
            raise SceneError(f"pilot_size must be an integer in [8, 4096], got {self.pilot_size!r}")
        if not np.isfinite(self.margin) or self.margin < 0:
            raise SceneError(f"margin must be a finite number >= 0, got {self.margin!r}")


def resized_view(view: View, size: int, name: str | None = None) -> View:
    """The same view (pose, frustum) drawn with ``size``² pixels."""
    return View(view.to_world, size, size, view.near, view.far, view.fx * size / view.width,
                view.fy * size / view.height, view.orthographic, name or view.name,
                None if view.principal is None else (view.cx * size / view.width, view.cy * size / view.height))


def rotated_view(view: View, angle: float) -> View:
    """The view turned by ``angle`` [rad] about its own axis (same pixel scales; its pixels map by
    :func:`rotate_pixels`)."""
    if angle == 0.0:
        return view
    c, s = math.cos(angle), math.sin(angle)
    rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float64)
    return View(np.asarray(view.to_world, np.float64) @ rz, view.width, view.height, view.near, view.far, view.fx,
                view.fy, view.orthographic, view.name, view.principal)


def rotate_pixels(px, py, cx: float, cy: float, angle: float, aspect: float = 1.0):
    """Pixel coordinates in ``rotated_view(view, angle)`` of pixel (px, py) of ``view``, whose principal
    point is (cx, cy) and ``aspect`` = fx / fy: with dx = px − cx, dy = py − cy,
    u = cx + cos·dx − sin·aspect·dy, v = cy + sin·dx / aspect + cos·dy (a turn of the image plane; the
    map keeps areas)."""
    c, s = math.cos(angle), math.sin(angle)
    dx, dy = np.asarray(px, np.float64) - cx, np.asarray(py, np.float64) - cy
    return cx + c * dx - s * aspect * dy, cy + s * dx / aspect + c * dy


def window_view(view: View, window, size: int, name: str) -> View:
    """A ``size``² view of the pixel rectangle ``window = (x0, y0, x1, y1)`` of ``view``: same pose and
    image plane, pixels scaled by size/(x1 − x0) across and size/(y1 − y0) down, principal point moved.
    Pixel (px, py) of ``view`` is pixel ((px − x0)·sx, (py − y0)·sy) of the window view, perspective or
    orthographic alike (texels need not be square)."""
    x0, y0, x1, y1 = (float(v) for v in window)
    sx, sy = size / (x1 - x0), size / (y1 - y0)
    return View(view.to_world, size, size, view.near, view.far, view.fx * sx, view.fy * sy, view.orthographic, name,
                ((view.cx - x0) * sx, (view.cy - y0) * sy))


def cascade_splits(z_near: float, z_far: float, cascades: int, blend: float = 0.5) -> np.ndarray:
    """Receiver depths [m] that end each cascade (the last is ``z_far``): the practical split scheme of
    parallel-split shadow maps, ``blend`` between logarithmic and uniform splits."""
    i = np.arange(1, cascades + 1) / cascades
    z_near = max(z_near, 1e-6)
    log = z_near * (z_far / z_near) ** i
    uni = z_near + (z_far - z_near) * i
    return blend * log + (1.0 - blend) * uni


#: a finer cascade is kept only where its window covers at most this share of the next coarser one: the
#: coarser cascade's samples inside it are left to the finer one (spent, not traced), so a share f costs
#: f/2 of two cascades' photons for a texel (and photon) density 1/f times higher near the camera
MERGE_AREA = 0.25


def fit_angle(receiver_depth: np.ndarray, aspect: float = 1.0, steps: int = 18) -> float:
    """The turn [rad] of a pilot view about its axis, among ``steps`` in [0, 90°), whose axis-aligned box
    around the useful texels (receiver depth > 0) is smallest: a camera that looks across the light's
    view sees a diagonal band of it, which a turned window covers tightly (0 when nothing is useful).
    ``aspect``: the pilot view's fx / fy."""
    h, w = receiver_depth.shape
    jj, ii = np.nonzero(receiver_depth > 0)
    if ii.size == 0:
        return 0.0
    best, best_area = 0.0, np.inf
    for k in range(steps):
        a = 0.5 * math.pi * k / steps
        u, v = rotate_pixels(ii + 0.5, jj + 0.5, 0.5 * w, 0.5 * h, a, aspect)
        area = (np.ptp(u) + 1.0) * (np.ptp(v) + 1.0)
        if area < best_area * 0.98:  # prefer the smaller turn unless clearly tighter
            best, best_area = a, area
    return best


def fit_windows(receiver_depth: np.ndarray, cascades: int, margin: float, angle: float = 0.0,
                aspect: float = 1.0) -> list[tuple[float, float, float, float]]:
    """Windows (x0, y0, x1, y1) in the pixels of the pilot view turned by ``angle`` (:func:`rotated_view`),
    finest first and nested, from a pilot view's ``receiver_depth`` (H, W): the camera depth [m] where each
    texel's light lands on a visible pixel, 0 where it lands on none. Cascade c covers the texels whose
    receiver is nearer than its split (:func:`cascade_splits`), each window grown by ``margin`` texels plus
    2% (and by the turned texels' own extent) and clipped to the box of the turned pilot image. A cascade whose window
    would cover more than ``MERGE_AREA`` of the next coarser one is merged into it. Empty when no texel's
    light is seen."""
    h, w = receiver_depth.shape
    useful = receiver_depth > 0
    if not useful.any():
        return []
    z = receiver_depth[useful]
    splits = cascade_splits(float(z.min()), float(z.max()), cascades)
    splits[-1] = np.inf
    jj, ii = np.nonzero(useful)
    u, v = rotate_pixels(ii + 0.5, jj + 0.5, 0.5 * w, 0.5 * h, angle, aspect)
    c, s = abs(math.cos(angle)), abs(math.sin(angle))
    half_u, half_v = 0.5 * (c + s * aspect), 0.5 * (s / aspect + c)  # half extents of a turned texel
    cu, cv = rotate_pixels(np.array([0.0, w, w, 0.0]), np.array([0.0, 0.0, h, h]), 0.5 * w, 0.5 * h, angle, aspect)
    lo_u, hi_u, lo_v, hi_v = cu.min(), cu.max(), cv.min(), cv.max()  # the turned pilot image's box
    windows = []
    for zs in splits:
        m = z <= zs
        if not m.any():
            continue
        x0, x1, y0, y1 = u[m].min() - half_u, u[m].max() + half_u, v[m].min() - half_v, v[m].max() + half_v
        gx, gy = margin + 0.02 * (x1 - x0), margin + 0.02 * (y1 - y0)
        win = (max(x0 - gx, lo_u), max(y0 - gy, lo_v), min(x1 + gx, hi_u), min(y1 + gy, hi_v))
        windows.append(tuple(float(round(c, 6)) for c in win))
    area = [(x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in windows]
    kept = [windows[c] for c in range(len(windows) - 1) if area[c] <= MERGE_AREA * area[c + 1]] + [windows[-1]]
    out = []
    for win in kept:  # drop repeats (a cascade with the same texels as the next)
        if not out or win != out[-1]:
            out.append(win)
    return out
