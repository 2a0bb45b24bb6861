"""Write ``scenes_usd/pool.usda``: an outdoor swimming pool with FFT-simulated water and a moving camera.

Geometry (Y up, metres, ``metersPerUnit`` 1; the still water surface is the plane y = 0):

* Basin: interior x in [-4, 4], z in [-2, 2], flat floor at y = -``--depth`` (1.2 m), walls up to the
  deck at y = 0.15. Floor and walls are 0.25 m tiles coloured per face (``primvars:displayColor``,
  uniform): two pale aqua tones in a checker, dark blue lane lines with T-ends on the floor, a dark
  blue band of waterline tiles at the top of the walls.
* Coping: a 0.35 m wide stone rim, 5 cm proud of the deck, around the basin; deck: a stone ring out
  to x in [-6.5, 6.5], z in [-4.5, 4.5].
* Steps: three tiled steps (tops at y = -0.3, -0.6, -0.9) in the corner x = -4, z in [0.6, 1.8].
* Ladder: two square 4 cm steel rails on the far wall (z = -2) that curve over the coping into the deck,
  three rungs under water; it shades part of the floor from the sun and hides part of it from the camera.
* Water: a regular grid of quads over the basin, vertex ``iz * nx + ix`` at rest at
  (x0 + ix (x1 - x0)/(nx - 1), 0, z0 + iz (z1 - z0)/(nz - 1)) with (nx, nz) from ``--water-spacing``.
  The points' default (un-sampled) value is this flat rest grid; ``cisp:water:<key>`` attributes hold
  every field of :class:`sim.WaterParams` (spectrum, wind, patch size, depth, choppiness, seed ...), from
  which the renderer simulates the surface (``cisp_warp.animation``). ``--bake N`` adds time samples of
  the simulated points, normals and extent at time codes start .. start + N - 1 for tools that do not
  know ``cisp:`` (the renderer still simulates; it reads the rest grid from the default value).
  UsdPreviewSurface: opacity 0, roughness 0, ior 1.333.

Lights (``inputs:intensity`` in cisp_warp's SI convention, see :mod:`cisp_warp.usd`):

* ``/World/Sun``: a DistantLight, elevation ``--sun-elevation`` (60 degrees), azimuth 20 degrees from +z
  towards +x (behind the camera). ``inputs:intensity`` = ``--sun-irradiance`` (900 W/m²), the clear-sky
  direct normal irradiance at sea level; ``inputs:angle`` 0.53 degrees (the sun's disc, for other tools).
* ``/World/Floodlight``: a spot (SphereLight + ShapingAPI) on a 4 m pole at the deck's corner aimed at the
  basin's centre, half angle 35 degrees, softness 0.2. 75 W/sr: a 400 W metal-halide floodlight gives
  about 36 klm, about 140 W of light at 250 lm/W; with 60 % of it in the 1.14 sr cone, 140 × 0.6 / 1.14
  ≈ 75 W/sr. By day it adds about 0.3 % to the sun; ``--night`` hides the sun (``visibility =
  invisible``), so the floodlight alone lights the pool.

Camera ``/World/Camera``: 28 mm lens on a 36 × 20.25 aperture (16:9, 40 degrees vertical field of view),
clipping (0.1, 100) m. Over time codes 0 .. 120 (24 per second, 5 s) it dollies from (-3.5, 4.2, 6.0)
to (2.5, 3.4, 5.0) while panning its aim from (-1.0, -1.2, -0.6) to (1.2, -1.2, -0.9), eased in and out;
``xformOp:translate`` and ``xformOp:rotateXYZ`` (pitch then yaw) are sampled at every time code, so the
interpolated pose between codes stays rigid. ``/Render/Settings``: 640 × 360 through the camera.

* ``/World/Sky``: a DomeLight with the lat-long image ``pool_sky.exr`` (written beside the stage), a clear
  sky whose ``inputs:intensity`` makes it deliver ``--sky-irradiance`` (100 W/m²) to an open level surface.

Usage: ``cisp-make-pool [--out PATH] [--bake N] [--night] [--seed 7] ...`` (or ``python tools/make_pool_scene.py``,
which writes ``scenes_usd/pool.usda``; ``--help``).
The written stage is checked with every registered ``UsdValidation`` validator (usd-core 26 replaced
``UsdUtils.ComplianceChecker``, what ``usdchecker`` ran, by that framework) and with
``UsdUtils.ComplianceChecker`` too where the installed usd-core still has it; it must load through
:func:`cisp_warp.usd.load_usd`. Exit status 0 when it passes, 1 with validation errors, 2 for bad
flags.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

from sim import WaterParams

from .image_io import write_exr
from .usd_check import author_render_settings, compliance_checker_errors, define_material, export, validation_errors

DEFAULT_OUT = Path("pool.usda")  #: ``cisp-make-pool``'s default; tools/make_pool_scene.py writes scenes_usd/pool.usda

POOL_HALF = (4.0, 2.0)  #: basin interior half extents in x and z [m]
DECK_Y = 0.15  #: deck level above still water [m]
COPING = (0.35, 0.05)  #: coping width and height above the deck [m]
DECK_HALF = (6.5, 4.5)  #: deck outer half extents [m]
TILE = 0.25  #: tile edge [m]
WALL_ROWS = 6  #: tile rows on the walls; the top row is the dark waterline band
STEP_RISE, STEP_RUN = 0.3, 0.3  #: [m]
STEP_Z = (0.6, 1.8)  #: the steps' extent across the basin [m]
LADDER_X = (2.25, 2.75)  #: rail positions [m]
LADDER_BAR = 0.04  #: square rail and rung section [m]
SUN_AZIMUTH_DEG = 20.0  #: from +z towards +x
SUN_ANGLE_DEG = 0.53  #: angular diameter of the sun's disc (not used by cisp_warp)
SPOT_POSITION = (6.0, 4.0, 4.0)  #: top of the floodlight pole, at the deck's corner [m]
SPOT_TARGET = (0.0, -1.2, 0.0)
SPOT_CONE_DEG, SPOT_SOFTNESS = 35.0, 0.2
SPOT_INTENSITY = 75.0  #: [W/sr], see the module docstring
FOCAL_LENGTH = 28.0
HORIZONTAL_APERTURE, VERTICAL_APERTURE = 36.0, 20.25
RESOLUTION = (640, 360)
TIME_CODES_PER_SECOND = 24.0
START, END = 0, 120
CAMERA_EYE = ((-3.5, 4.2, 6.0), (2.5, 3.4, 5.0))  #: dolly: eye at the first and last time code [m]
CAMERA_AIM = ((-1.0, -1.2, -0.6), (1.2, -1.2, -0.9))  #: pan: aim point at the first and last time code [m]

#: Colours of the tiles (linear RGB albedo).
TILE_LIGHT = (0.62, 0.80, 0.86)
TILE_DARK_CHECK = (0.52, 0.72, 0.80)
TILE_LANE = (0.04, 0.12, 0.40)
TILE_WATERLINE = (0.06, 0.22, 0.50)
STEP_TOP = (0.80, 0.82, 0.82)

#: The water simulation written as ``cisp:water:<key>`` (every WaterParams field; see sim/params.py).
#: Phillips spectrum, 2 m/s breeze along the pool: peak wavelength about 3 m, 1.5 cm rms height, rms
#: slope 0.09 after the 0.15 m cutoff; a 4 m patch tiles the 8 m x 4 m basin twice.
WATER_DOCS = {
    "resolution": "FFT grid size N of the simulation (N x N)",
    "patch_size": "side of the square periodic simulation patch [m]; anchored at the world origin",
    "depth": "still-water depth [m] in the dispersion relation: the basin's depth",
    "wind_speed": "wind speed [m/s]",
    "wind_direction": "direction the wind blows towards [rad], from +x towards +z",
    "fetch": "distance the wind blows over water [m] (JONSWAP only): the pool's length",
    "spectrum": "wave spectrum model: phillips or jonswap",
    "amplitude": "scale of the wave heights (1 = the physical spectrum)",
    "small_wave_cutoff": "waves shorter than this are suppressed [m]",
    "choppiness": "horizontal displacement scale (0 = height field only)",
    "seed": "seed of the spectrum's Gaussian draw",
}


SKY_IMAGE = "pool_sky.exr"  #: lat-long sky image written beside the stage
SKY_IRRADIANCE = 100.0  #: diffuse horizontal irradiance of a clear sky with the sun at 60° [W/m²]
SKY_SIZE = (64, 128)  #: (height, width) of the sky image [texels]
SKY_ZENITH = (0.30, 0.50, 1.00)  #: relative colour of the clear sky at the zenith (linear RGB)
SKY_HORIZON = (0.85, 0.90, 1.00)  #: and at the horizon
GROUND_ALBEDO = (0.22, 0.24, 0.16)  #: below the horizon: distant land (dry grass and stone), lit by sun and sky


def sky_texture(opts: "PoolOptions", size=SKY_SIZE) -> tuple[np.ndarray, float]:
    """The clear-sky lat-long image (H, W, 3) float32 and its ``inputs:intensity``.

    Above the horizon a smooth zenith-to-horizon gradient, whiter towards the horizon, scaled so that an
    open level surface receives ``opts.sky_irradiance`` [W/m²] (Rec. 709 luminance) from it; below it the
    distant land, a Lambertian ground of ``GROUND_ALBEDO`` lit by the sun and the sky:
    L = ρ (E_sun sin(elevation) + E_sky) / π. No sun disc: the sun is its own DistantLight.
    """
    from .scene.model import Sky
    from .sky import sh_basis, sky_sh_irradiance

    h, w = size
    lat = 0.5 * math.pi - math.pi * (np.arange(h) + 0.5) / h
    t = np.clip(np.sin(lat), 0.0, 1.0)[:, None]
    blend = (1.0 - t) ** 3
    rows = np.asarray(SKY_ZENITH) * (1.0 - blend) + np.asarray(SKY_HORIZON) * blend
    rows[lat < 0.0] = 0.0
    tex = np.repeat(rows[:, None, :], w, axis=1)
    e = sh_basis(np.array([0.0, 1.0, 0.0])) @ sky_sh_irradiance(Sky("sky", (1.0, 1.0, 1.0), tex))
    intensity = float(opts.sky_irradiance / max(e @ np.array([0.2126, 0.7152, 0.0722]), 1e-12)) if opts.sky_irradiance else 1.0
    e_ground = opts.sun_irradiance * math.sin(math.radians(opts.sun_elevation)) + opts.sky_irradiance
    ground = np.asarray(GROUND_ALBEDO) * e_ground / math.pi / intensity
    tex[lat < 0.0] = ground
    if not opts.sky_irradiance:
        tex[lat >= 0.0] = 0.0
    return tex.astype(np.float32), intensity


@dataclass(frozen=True)
class PoolOptions:
    """What the command line can change; every field is documented in ``--help``."""

    depth: float = 1.2
    water_spacing: float = 0.0625
    seed: int = 7
    wind_speed: float = 2.0
    choppiness: float = 0.5
    sun_elevation: float = 60.0
    sun_irradiance: float = 900.0
    spot_intensity: float = SPOT_INTENSITY
    night: bool = False
    bake: int = 0
    sky_irradiance: float = SKY_IRRADIANCE

    def water_params(self) -> WaterParams:
        return WaterParams(resolution=64, patch_size=4.0, depth=self.depth, wind_speed=self.wind_speed,
                           wind_direction=0.3, fetch=2.0 * POOL_HALF[0], spectrum="phillips", amplitude=1.0,
                           small_wave_cutoff=0.15, choppiness=self.choppiness, seed=self.seed)

    def water_counts(self) -> tuple[int, int]:
        """(nx, nz): water vertices along x and z, the spacing rounded so the grid ends on the walls."""
        return tuple(int(round(2.0 * h / self.water_spacing)) + 1 for h in POOL_HALF)


class Quads:
    """A mesh built as a list of quads, each with its own four corners (hard edges, per-face colour)."""

    def __init__(self):
        self.points, self.normals, self.colors = [], [], []

    def add(self, corners, normal, color=None) -> None:
        """One quad; ``corners`` in any order around it; wound counter-clockwise about ``normal``."""
        p = np.asarray(corners, dtype=np.float64)
        n = np.asarray(normal, dtype=np.float64)
        if np.dot(np.cross(p[1] - p[0], p[2] - p[0]), n) < 0.0:
            p = p[::-1]
        self.points.append(p)
        self.normals.append(np.tile(n / np.linalg.norm(n), (4, 1)))
        self.colors.append(color)

    def box(self, lo, hi, color=None, skip=()) -> None:
        """The faces of the axis-aligned box [lo, hi] except those named in ``skip`` (e.g. "-y")."""
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        for axis in range(3):
            u, v = (axis + 1) % 3, (axis + 2) % 3
            for sign, level in ((-1.0, lo[axis]), (1.0, hi[axis])):
                if f"{'-' if sign < 0 else '+'}{'xyz'[axis]}" in skip:
                    continue
                corners = []
                for a, b in ((lo[u], lo[v]), (hi[u], lo[v]), (hi[u], hi[v]), (lo[u], hi[v])):
                    c = np.zeros(3)
                    c[axis], c[u], c[v] = level, a, b
                    corners.append(c)
                n = np.zeros(3)
                n[axis] = sign
                self.add(corners, n, color)

    def arrays(self):
        """points (4Q, 3), normals (4Q, 3), faceVertexCounts (Q,), faceVertexIndices (4Q,), colours (Q, 3)."""
        q = len(self.points)
        colors = None if self.colors[0] is None else np.asarray(self.colors, dtype=np.float64)
        return (np.concatenate(self.points), np.concatenate(self.normals), np.full(q, 4, np.int32),
                np.arange(4 * q, dtype=np.int32), colors)


def _vec3f_array(a) -> Vt.Vec3fArray:
    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32))


def define_mesh(stage, path, points, normals, counts, indices, doc, material=None, colors=None) -> UsdGeom.Mesh:
    """A polygon mesh with vertex normals, bound to ``material`` or coloured per face by ``colors``."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.GetPrim().SetDocumentation(doc)
    mesh.CreatePointsAttr(_vec3f_array(points))
    mesh.CreateNormalsAttr(_vec3f_array(normals))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.asarray(counts, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(indices, dtype=np.int32)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(_vec3f_array(points)))
    if material is not None:
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    if colors is not None:
        mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set(_vec3f_array(colors))
    return mesh


def define_quads(stage, path, quads: Quads, doc, material=None) -> UsdGeom.Mesh:
    points, normals, counts, indices, colors = quads.arrays()
    return define_mesh(stage, path, points, normals, counts, indices, doc, material, colors)


# ---------------------------------------------------------------------------------------------- geometry


def floor_tiles(depth: float) -> Quads:
    """The basin floor: one quad per tile, checker of two aqua tones, two dark lane lines with T-ends."""
    hx, hz = POOL_HALF
    q = Quads()
    nx, nz = int(round(2 * hx / TILE)), int(round(2 * hz / TILE))
    lanes = (-1.0, 1.0)  # lane line centres [m]: the middles of two 2 m lanes
    for iz in range(nz):
        for ix in range(nx):
            x0, z0 = -hx + ix * TILE, -hz + iz * TILE
            xc, zc = x0 + 0.5 * TILE, z0 + 0.5 * TILE
            on_line = any(abs(zc - c) < TILE for c in lanes) and abs(xc) < hx - 1.0  # two tiles wide
            on_tee = any(abs(zc - c) < 2 * TILE for c in lanes) and hx - 1.0 - TILE < abs(xc) < hx - 1.0
            color = TILE_LANE if (on_line or on_tee) else (TILE_LIGHT if (ix + iz) % 2 == 0 else TILE_DARK_CHECK)
            q.add([(x0, -depth, z0), (x0 + TILE, -depth, z0), (x0 + TILE, -depth, z0 + TILE),
                   (x0, -depth, z0 + TILE)], (0, 1, 0), color)
    return q


def wall_tiles(depth: float) -> Quads:
    """The four basin walls, facing the water: tiles in ``WALL_ROWS`` rows, the top row dark blue."""
    hx, hz = POOL_HALF
    q = Quads()
    ys = np.linspace(-depth, DECK_Y, WALL_ROWS + 1)
    for axis, half, other in ((0, hx, hz), (2, hz, hx)):  # walls at x = ±hx span z, at z = ±hz span x
        cols = int(round(2 * other / TILE))
        for sign in (-1.0, 1.0):
            for row in range(WALL_ROWS):
                for c in range(cols):
                    a0, a1 = -other + c * TILE, -other + (c + 1) * TILE
                    corners = []
                    for a, y in ((a0, ys[row]), (a1, ys[row]), (a1, ys[row + 1]), (a0, ys[row + 1])):
                        p = [0.0, y, 0.0]
                        p[axis], p[2 - axis] = sign * half, a
                        corners.append(p)
                    n = [0.0, 0.0, 0.0]
                    n[axis] = -sign  # faces the water
                    top = row == WALL_ROWS - 1
                    color = TILE_WATERLINE if top else (TILE_LIGHT if (row + c) % 2 == 0 else TILE_DARK_CHECK)
                    q.add(corners, n, color)
    return q


def steps(depth: float) -> Quads:
    """Three steps against the wall x = -hx: white treads, blue risers and sides, no hidden faces."""
    hx, _ = POOL_HALF
    z0, z1 = STEP_Z
    q = Quads()
    for k in range(1, 4):
        xa, xb = -hx + STEP_RUN * (k - 1), -hx + STEP_RUN * k
        top = -STEP_RISE * k
        below = -STEP_RISE * (k + 1) if k < 3 else -depth  # the riser reaches down to the next tread
        q.add([(xa, top, z0), (xb, top, z0), (xb, top, z1), (xa, top, z1)], (0, 1, 0), STEP_TOP)
        q.add([(xb, below, z0), (xb, top, z0), (xb, top, z1), (xb, below, z1)], (1, 0, 0), TILE_WATERLINE)
        for z, nz in ((z0, -1.0), (z1, 1.0)):
            q.add([(xa, -depth, z), (xb, -depth, z), (xb, top, z), (xa, top, z)], (0, 0, nz), TILE_WATERLINE)
    return q


def coping_and_deck() -> tuple[Quads, Quads]:
    """The coping (raised rim around the basin) and the deck ring around it."""
    hx, hz = POOL_HALF
    w, h = COPING
    top = DECK_Y + h
    coping, deck = Quads(), Quads()
    # four slabs: along x at z = ±(hz..hz+w), along z at x = ±(hx..hx+w) (corners owned by the x slabs)
    for s in (-1.0, 1.0):
        z0, z1 = sorted((s * hz, s * (hz + w)))
        coping.box((-hx - w, DECK_Y, z0), (hx + w, top, z1), skip=("-y",))
        x0, x1 = sorted((s * hx, s * (hx + w)))
        coping.box((x0, DECK_Y, -hz), (x1, top, hz), skip=("-y", "-z", "+z"))
    dx, dz = DECK_HALF
    ox, oz = hx + w, hz + w  # deck starts outside the coping
    for s in (-1.0, 1.0):
        z0, z1 = sorted((s * oz, s * dz))
        deck.add([(-dx, DECK_Y, z0), (dx, DECK_Y, z0), (dx, DECK_Y, z1), (-dx, DECK_Y, z1)], (0, 1, 0))
        x0, x1 = sorted((s * ox, s * dx))
        deck.add([(x0, DECK_Y, -oz), (x1, DECK_Y, -oz), (x1, DECK_Y, oz), (x0, DECK_Y, oz)], (0, 1, 0))
    return coping, deck


def ladder() -> Quads:
    """Two rails up the far wall, over the coping into the deck, and three rungs under water."""
    hz = POOL_HALF[1]
    b = 0.5 * LADDER_BAR
    z_in = -hz + 0.12  # rails stand 12 cm off the wall
    z_out = -hz - COPING[0] - 0.2  # and come down into the deck behind the coping
    y_bottom, y_top = -1.0, DECK_Y + 0.9
    q = Quads()
    for x in LADDER_X:
        q.box((x - b, y_bottom, z_in - b), (x + b, y_top, z_in + b), skip=("+y",))  # up the wall
        q.box((x - b, y_top - LADDER_BAR, z_out - b), (x + b, y_top, z_in + b), skip=("+z",))  # over the coping
        q.box((x - b, DECK_Y, z_out - b), (x + b, y_top - LADDER_BAR, z_out + b), skip=("-y", "+y"))  # into the deck
    for y in (-0.8, -0.5, -0.2):
        q.box((LADDER_X[0] + b, y - b, z_in - b), (LADDER_X[1] - b, y + b, z_in + b), skip=("-x", "+x"))
    return q


def water_rest_grid(counts: tuple[int, int]):
    """Rest points (nx*nz, 3) of the water grid at y = 0 (vertex iz*nx + ix), counts, quad indices."""
    nx, nz = counts
    hx, hz = POOL_HALF
    x, z = np.meshgrid(np.linspace(-hx, hx, nx), np.linspace(-hz, hz, nz))  # [iz, ix]
    points = np.stack([x, np.zeros_like(x), z], axis=-1).reshape(-1, 3)
    iz, ix = np.meshgrid(np.arange(nz - 1), np.arange(nx - 1), indexing="ij")
    v = (iz * nx + ix).reshape(-1)
    quads = np.stack([v, v + nx, v + nx + 1, v + 1], axis=1)  # counter-clockwise seen from +y
    return points, np.full(len(v), 4, dtype=np.int32), quads.reshape(-1)


def baked_water(params: WaterParams, counts: tuple[int, int], codes) -> list[tuple[np.ndarray, np.ndarray]]:
    """(points, normals) of the simulated water at each time code, exactly as the renderer computes them."""
    import warp as wp

    from sim import FFTWater, WaterMesh

    wp.config.quiet = True
    hx, hz = POOL_HALF
    water = FFTWater(params, device="cpu")
    mesh = WaterMesh(water, rect=(-hx, -hz, hx, hz), y0=0.0, vertex_counts=counts)
    out = []
    for code in codes:
        mesh.update(code / TIME_CODES_PER_SECOND)
        out.append((mesh.points.numpy().copy(), mesh.normals.numpy().copy()))
    return out


# ---------------------------------------------------------------------------------------------- lights, camera


def _aim_rotation(direction) -> Gf.Vec3f:
    """rotateXYZ angles [deg] (pitch about X, then yaw about Y) that turn local -Z onto ``direction``."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    pitch = math.degrees(math.asin(float(np.clip(d[1], -1.0, 1.0))))
    yaw = math.degrees(math.atan2(-d[0], -d[2]))
    return Gf.Vec3f(pitch, yaw, 0.0)


def sun_direction(elevation_deg: float) -> np.ndarray:
    """Unit vector the sunlight travels along (from the sky down to the pool)."""
    el, az = math.radians(elevation_deg), math.radians(SUN_AZIMUTH_DEG)
    to_sun = np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    return -to_sun


def camera_pose(code: float) -> tuple[np.ndarray, np.ndarray]:
    """(eye, aim point) [m] at time ``code``: linear dolly and pan, eased in and out (smoothstep)."""
    s = min(max((code - START) / (END - START), 0.0), 1.0)
    s = s * s * (3.0 - 2.0 * s)
    eye = (1.0 - s) * np.asarray(CAMERA_EYE[0]) + s * np.asarray(CAMERA_EYE[1])
    aim = (1.0 - s) * np.asarray(CAMERA_AIM[0]) + s * np.asarray(CAMERA_AIM[1])
    return eye, aim


# ---------------------------------------------------------------------------------------------- stage


def build(out: Path, opts: PoolOptions = PoolOptions()) -> Usd.Stage:
    """Write the pool stage to ``out`` and return it, opened from disk."""
    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    stage.SetMetadata("comment", "Generated by cisp-make-pool (tools/make_pool_scene.py): do not edit by hand.")
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(TIME_CODES_PER_SECOND)
    stage.SetFramesPerSecond(TIME_CODES_PER_SECOND)
    stage.SetStartTimeCode(START)
    stage.SetEndTimeCode(END)

    world = UsdGeom.Xform.Define(stage, "/World")
    world.GetPrim().SetDocumentation(
        f"An outdoor swimming pool: basin 8 m x 4 m x {opts.depth:g} m with the still water at y = 0, coping, "
        "deck, steps and a ladder; FFT-simulated water; sun and floodlight; a camera that dollies and pans. "
        "Y up, metres.")
    Usd.ModelAPI(world).SetKind(Kind.Tokens.assembly)
    stage.SetDefaultPrim(world.GetPrim())

    looks = UsdGeom.Scope.Define(stage, "/World/Looks")
    looks.GetPrim().SetDocumentation("UsdPreviewSurface materials; the tiles are coloured by displayColor.")
    stone = define_material(stage, "Stone", "Deck stone, warm grey, matte.", (0.50, 0.45, 0.38), roughness=0.9)
    coping_mat = define_material(stage, "Coping", "Coping stone, pale, matte.", (0.78, 0.76, 0.70), roughness=0.8)
    steel = define_material(stage, "Steel", "Ladder steel, treated as a diffuse grey (only the water is specular).",
                            (0.60, 0.61, 0.63), roughness=0.4)
    water_mat = define_material(stage, "Water", "Water: a smooth transmissive dielectric, IOR 1.333.",
                                (1.0, 1.0, 1.0), roughness=0.0, opacity=0.0, ior=1.333)

    basin = UsdGeom.Xform.Define(stage, "/World/Basin")
    basin.GetPrim().SetDocumentation("The tiled basin; every tile is one quad with its colour (displayColor, uniform).")
    define_quads(stage, "/World/Basin/Floor", floor_tiles(opts.depth),
                 f"Floor at y = -{opts.depth:g}: 0.25 m tiles, aqua checker, two dark lane lines with T-ends.")
    define_quads(stage, "/World/Basin/Walls", wall_tiles(opts.depth),
                 f"The four walls from the floor to the deck (y = {DECK_Y}), facing the water; dark waterline band.")
    define_quads(stage, "/World/Basin/Steps", steps(opts.depth),
                 "Three steps in the corner x = -4, z in [0.6, 1.8]: white treads, blue risers.")
    coping, deck = coping_and_deck()
    define_quads(stage, "/World/Coping", coping, f"Stone rim {COPING[0]} m wide, {COPING[1]} m above the deck.",
                 coping_mat)
    define_quads(stage, "/World/Deck", deck, f"Deck at y = {DECK_Y} out to x = ±{DECK_HALF[0]}, z = ±{DECK_HALF[1]}.",
                 stone)
    define_quads(stage, "/World/Ladder", ladder(),
                 "Ladder on the far wall (z = -2): two 4 cm rails over the coping into the deck, three rungs.", steel)

    params = opts.water_params()
    counts = opts.water_counts()
    rest, fcounts, findices = water_rest_grid(counts)
    up = np.tile([0.0, 1.0, 0.0], (len(rest), 1))
    water = define_mesh(
        stage, "/World/Water", rest, up, fcounts, findices,
        f"Water surface: {counts[0]} x {counts[1]} vertex grid over the basin, vertex iz*nx + ix; the default "
        "points are the flat rest grid at y = 0, cisp:water:* parameterise the FFT simulation (sim/) that "
        "moves them" + (f"; time samples at codes {START}..{START + opts.bake - 1} hold the simulated surface"
                        if opts.bake else "") + ".", water_mat)
    for key, value in params.to_dict().items():
        vtype = {int: Sdf.ValueTypeNames.Int, str: Sdf.ValueTypeNames.String}.get(type(value), Sdf.ValueTypeNames.Double)
        attr = water.GetPrim().CreateAttribute(f"cisp:water:{key}", vtype, custom=True)
        attr.Set(value)
        attr.SetDocumentation(WATER_DOCS[key])
    if opts.bake:
        codes = range(START, START + opts.bake)
        for code, (p, n) in zip(codes, baked_water(params, counts, codes)):
            water.GetPointsAttr().Set(_vec3f_array(p), Usd.TimeCode(code))
            water.GetNormalsAttr().Set(_vec3f_array(n), Usd.TimeCode(code))
            water.GetExtentAttr().Set(UsdGeom.PointBased.ComputeExtent(_vec3f_array(p)), Usd.TimeCode(code))

    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.GetPrim().SetDocumentation(
        f"The sun at {opts.sun_elevation:g} degrees elevation, azimuth {SUN_AZIMUTH_DEG:g} degrees from +z towards "
        f"+x. inputs:intensity is the irradiance [W/m2] on a surface facing it (cisp_warp's convention): "
        f"{opts.sun_irradiance:g} W/m2, clear-sky direct normal irradiance." + (" Hidden: night." if opts.night else ""))
    sun.CreateIntensityAttr(float(opts.sun_irradiance))
    sun.CreateExposureAttr(0.0)
    sun.CreateColorAttr(Gf.Vec3f(1.0, 1.0, 1.0))
    sun.CreateAngleAttr(SUN_ANGLE_DEG)
    UsdGeom.XformCommonAPI(sun).SetRotate(_aim_rotation(sun_direction(opts.sun_elevation)))
    if opts.night:
        UsdGeom.Imageable(sun).CreateVisibilityAttr(UsdGeom.Tokens.invisible)

    spot = UsdLux.SphereLight.Define(stage, "/World/Floodlight")
    spot.GetPrim().SetDocumentation(
        f"Floodlight on a pole at {SPOT_POSITION} aimed at {SPOT_TARGET}, half angle {SPOT_CONE_DEG:g} degrees. "
        f"inputs:intensity is the radiant intensity [W/sr] along the axis (cisp_warp's convention): "
        f"{opts.spot_intensity:g} W/sr, a 400 W metal-halide floodlight.")
    spot.CreateTreatAsPointAttr(True)
    spot.CreateRadiusAttr(0.0)
    spot.CreateIntensityAttr(float(opts.spot_intensity))
    spot.CreateExposureAttr(0.0)
    spot.CreateColorAttr(Gf.Vec3f(1.0, 1.0, 1.0))
    shaping = UsdLux.ShapingAPI.Apply(spot.GetPrim())
    shaping.CreateShapingConeAngleAttr(SPOT_CONE_DEG)
    shaping.CreateShapingConeSoftnessAttr(SPOT_SOFTNESS)
    xf = UsdGeom.XformCommonAPI(spot)
    xf.SetTranslate(Gf.Vec3d(*SPOT_POSITION))
    xf.SetRotate(_aim_rotation(np.subtract(SPOT_TARGET, SPOT_POSITION)))

    texture, intensity = sky_texture(opts)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    write_exr(str(Path(out).parent / SKY_IMAGE), texture)
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.GetPrim().SetDocumentation(
        f"The clear sky: the lat-long image {SKY_IMAGE} (zenith blue, whiter towards the horizon, sunlit land below) "
        f"times inputs:intensity is the radiance [W/(m2 sr)] from each direction; scaled so that an unoccluded "
        f"level surface receives {opts.sky_irradiance:g} W/m2 from the sky (diffuse horizontal irradiance)."
        + (" Hidden: night." if opts.night else ""))
    dome.CreateIntensityAttr(intensity)
    dome.CreateExposureAttr(0.0)
    dome.CreateColorAttr(Gf.Vec3f(1.0, 1.0, 1.0))
    dome.CreateTextureFileAttr(Sdf.AssetPath(f"./{SKY_IMAGE}"))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    if opts.night:
        UsdGeom.Imageable(dome).CreateVisibilityAttr(UsdGeom.Tokens.invisible)

    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.GetPrim().SetDocumentation(
        f"Dollies from {CAMERA_EYE[0]} to {CAMERA_EYE[1]} and pans its aim from {CAMERA_AIM[0]} to {CAMERA_AIM[1]} "
        f"over time codes {START}..{END} (eased); 28 mm lens, 16:9, 40 degrees vertical field of view.")
    cam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
    cam.CreateFocalLengthAttr(FOCAL_LENGTH)
    cam.CreateHorizontalApertureAttr(HORIZONTAL_APERTURE)
    cam.CreateVerticalApertureAttr(VERTICAL_APERTURE)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.1, 100.0))
    translate = cam.AddTranslateOp()
    rotate = cam.AddRotateXYZOp()
    for code in range(START, END + 1):
        eye, aim = camera_pose(code)
        translate.Set(Gf.Vec3d(*eye), Usd.TimeCode(code))
        rotate.Set(_aim_rotation(aim - eye), Usd.TimeCode(code))

    author_render_settings(stage, cam, RESOLUTION)
    return export(layer, out)


# ---------------------------------------------------------------------------------------------- checks


def _positive(text: str) -> float:
    v = float(text)
    if not (math.isfinite(v) and v > 0.0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return v


def _non_negative_int(text: str) -> int:
    v = int(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text!r}")
    return v


def parse_args(argv=None, default_out: Path = DEFAULT_OUT, prog: str = "cisp-make-pool") -> tuple[Path, PoolOptions]:
    d = PoolOptions()
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0],
                                 epilog="The full description of the scene is this file's docstring.")
    ap.add_argument("--out", type=Path, default=default_out,
                    help=f"output .usda; the sky image {SKY_IMAGE} is written beside it (default: {default_out})")
    ap.add_argument("--depth", type=_positive, default=d.depth,
                    help=f"basin depth below the still water [m] (default: {d.depth})")
    ap.add_argument("--water-spacing", type=_positive, default=d.water_spacing,
                    help=f"water grid spacing [m]; 8 m x 4 m of water (default: {d.water_spacing}: 129 x 65 vertices)")
    ap.add_argument("--seed", type=_non_negative_int, default=d.seed,
                    help=f"cisp:water:seed, the seed of the wave spectrum (default: {d.seed})")
    ap.add_argument("--wind-speed", type=_positive, default=d.wind_speed,
                    help=f"cisp:water:wind_speed [m/s] (default: {d.wind_speed})")
    ap.add_argument("--choppiness", type=float, default=d.choppiness,
                    help=f"cisp:water:choppiness, >= 0 (default: {d.choppiness})")
    ap.add_argument("--sun-elevation", type=float, default=d.sun_elevation,
                    help=f"sun elevation above the horizon [deg], in (0, 90] (default: {d.sun_elevation})")
    ap.add_argument("--sun-irradiance", type=float, default=d.sun_irradiance,
                    help=f"sun irradiance on a surface facing it [W/m2], >= 0 (default: {d.sun_irradiance})")
    ap.add_argument("--spot-intensity", type=float, default=d.spot_intensity,
                    help=f"floodlight radiant intensity [W/sr], >= 0 (default: {d.spot_intensity})")
    ap.add_argument("--sky-irradiance", type=float, default=d.sky_irradiance,
                    help=f"irradiance from the sky on an open level surface [W/m2], >= 0 (default: {d.sky_irradiance})")
    ap.add_argument("--night", action="store_true", help="hide the sun and the sky (visibility invisible): "
                    "floodlight only")
    ap.add_argument("--bake", type=_non_negative_int, default=0, metavar="N",
                    help="also write the simulated water points at time codes 0..N-1 as time samples (default: 0)")
    args = ap.parse_args(argv)
    if not 0.0 < args.sun_elevation <= 90.0:
        ap.error(f"--sun-elevation must lie in (0, 90] degrees, got {args.sun_elevation}")
    for name in ("choppiness", "sun_irradiance", "spot_intensity", "sky_irradiance"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v >= 0.0):
            ap.error(f"--{name.replace('_', '-')} must be a finite number >= 0, got {v}")
    if args.water_spacing > 2.0:
        ap.error(f"--water-spacing must be at most 2 m (a vertex per wall corner), got {args.water_spacing}")
    if args.out.suffix.lower() not in (".usda", ".usd", ".usdc"):
        ap.error(f"--out must end in .usda, .usd or .usdc, got '{args.out}'")
    opts = PoolOptions(**{f.name: getattr(args, f.name) for f in fields(PoolOptions)})
    counts = opts.water_counts()
    if counts[0] * counts[1] > 1 << 22:
        ap.error(f"--water-spacing {args.water_spacing} gives {counts[0]} x {counts[1]} water vertices: too many")
    return args.out, opts


def main(argv=None, default_out: Path = DEFAULT_OUT, prog: str = "cisp-make-pool") -> int:
    """``cisp-make-pool``: write the pool stage (and its sky image), check it, print a summary."""
    out, opts = parse_args(argv, default_out, prog)
    try:
        stage = build(out, opts)
    except (OSError, RuntimeError) as exc:  # a folder that cannot be made, a file that cannot be written
        reason = getattr(exc, "strerror", None) or str(exc).strip().splitlines()[-1]
        print(f"{prog}: error: cannot write '{out}' or its sky image: {reason}", file=sys.stderr)
        return 2
    errors = validation_errors(stage)
    checker = compliance_checker_errors(out)
    for e in errors + (checker or []):
        print(f"validation error: {e}", file=sys.stderr)

    from .usd import load_usd

    scene = load_usd(out)
    checked = "UsdValidation" + (" and UsdUtils.ComplianceChecker" if checker is not None else
                                 " (UsdUtils.ComplianceChecker is not in this usd-core)")
    print(f"wrote {out}: {scene.triangle_count} triangles, {len(scene.materials)} materials, "
          f"{len(scene.lights)} light(s), water {'x'.join(map(str, opts.water_counts()))} vertices"
          f"{f', {opts.bake} baked time codes' if opts.bake else ''}; {checked}: "
          f"{len(errors) + len(checker or [])} errors")
    return 1 if errors or checker else 0


if __name__ == "__main__":
    sys.exit(main())
