"""Write ``scenes_usd/cornell_flooded.usda``: seed 000's Cornell box, flooded with water of IOR 2.4.

The scene of seed 000, section 4 and Fig. 8 (row 1): a Cornell box with an open front, flooded so
that a spot light under the ceiling casts refractive caustics on the floor and reflective caustics on
the walls. The IOR of the water is 2.4 (diamond) "to emphasize caustics", as in the paper.

Geometry (Y up, metres, ``metersPerUnit`` 1):

* Box interior 1 m × 1 m × 1 m: floor y = 0, ceiling y = 1, x in [-0.5, 0.5], z in [-0.5, 0.5];
  open at +z, towards the camera. Left wall (x = -0.5) red, right wall (x = +0.5) green, floor, back
  wall and ceiling white; diffuse albedo about 0.7, roughness 1.
* A yellow diffuse ball (trimesh icosphere, radius 0.12 m) standing on the floor, under water.
* Water: a ``--water-resolution``² quad grid covering the box at rest height 0.35 m, displaced by a
  few seeded sinusoidal waves (total amplitude below 10 mm) with analytic per-vertex normals, so the
  static file already casts caustics. Its ``cisp:water:*`` attributes hand the FFT simulation its
  parameters (``sim/`` replaces the points at run time). UsdPreviewSurface: opacity 0, roughness 0,
  ior ``--ior``.

Light (one spot, as in the paper): at (0, 0.95, 0) pointing straight down, cone half-angle 38°. The
cone meets the water (y = 0.35, 0.6 m below) in a disc of radius 0.6·tan 38° = 0.47 m and meets the
side and back walls only below y = 0.95 - 0.5/tan 38° = 0.31 m, i.e. under the water line: no direct
light reaches the upper walls, so the caustics reflected there lie outside the light frustum (the
effect CISP shows and caustics mapping cannot). Intensity 2 W/sr: flat water transmits
1 - F(0) = 1 - ((2.4 - 1)/(2.4 + 1))² = 0.83 and, paraxially, spreads the beam as if the floor were
0.6 + 0.35/2.4 = 0.746 m from the light, so the floor under the light receives
2 × 0.83 / 0.746² ≈ 3.0 W/m² (a bare floor would get 2 / 0.95² ≈ 2.2 W/m²).

Camera: at (0, 0.55, 2.2) looking at the box centre (0, 0.5, 0); focal length 35 with a 16:9 aperture
45.3 × 25.48 (same units), so the vertical field of view is 2·atan(25.48 / 70) = 40°; clipping range
(0.05, 20) m. ``/Render/Settings``: 640 × 360.

Usage: ``python tools/make_cornell_flooded.py [--out PATH] [--ior 2.4] [--water-resolution 96] [--seed 0]``.
The written stage is checked with every registered ``UsdValidation`` validator (usd-core 26 replaced
``UsdUtils.ComplianceChecker`` by that framework) and must load through :func:`cisp_warp.usd.load_usd`.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

ROOT_DIR = Path(__file__).resolve().parents[1]
if str(ROOT_DIR) not in sys.path:
    sys.path.insert(0, str(ROOT_DIR))

from cisp_warp.usd_check import (author_render_settings, define_material, export,  # noqa: E402, F401
                                 validation_errors)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "scenes_usd" / "cornell_flooded.usda"

WATER_HEIGHT = 0.35  #: rest height of the water surface [m]
BALL_RADIUS = 0.12  #: [m]
BALL_CENTER = (0.17, BALL_RADIUS, -0.05)  #: standing on the floor, right of centre [m]
SPOT_POSITION = (0.0, 0.95, 0.0)  #: [m]
SPOT_CONE_DEG = 38.0  #: half angle; tan(38°)·0.6 m < 0.5 m keeps the cone off the walls above the water
SPOT_INTENSITY = 2.0  #: [W/sr]
CAMERA_EYE = (0.0, 0.55, 2.2)
CAMERA_TARGET = (0.0, 0.5, 0.0)
FOCAL_LENGTH = 35.0
VERTICAL_APERTURE = 2.0 * FOCAL_LENGTH * math.tan(math.radians(20.0))  #: 40° vertical field of view
HORIZONTAL_APERTURE = VERTICAL_APERTURE * 16.0 / 9.0
RESOLUTION = (640, 360)
WAVE_COUNT = 4
WAVE_AMPLITUDE_TOTAL = 0.008  #: sum of the wave amplitudes [m]: the surface stays within ±8 mm

WATER_ATTRIBUTES = {  # name: (value, Sdf type, doc)
    "resolution": (64, Sdf.ValueTypeNames.Int, "FFT grid size of the simulation (N × N)"),
    "patch_size": (1.0, Sdf.ValueTypeNames.Double, "side of the simulated ocean patch [m]"),
    "depth": (WATER_HEIGHT, Sdf.ValueTypeNames.Double, "water depth [m] (dispersion relation)"),
    "wind_speed": (2.0, Sdf.ValueTypeNames.Double, "wind speed [m/s]"),
    "wind_direction": (0.0, Sdf.ValueTypeNames.Double, "wind direction [rad] from +x towards +z"),
    "spectrum": ("phillips", Sdf.ValueTypeNames.String, "wave spectrum model"),
    "choppiness": (0.0, Sdf.ValueTypeNames.Double, "horizontal displacement scale (0 = height field only)"),
    "amplitude": (1.0, Sdf.ValueTypeNames.Double, "scale of the spectrum's amplitude"),
    "small_wave_cutoff": (0.005, Sdf.ValueTypeNames.Double, "waves shorter than this are suppressed [m]"),
    "fetch": (10.0, Sdf.ValueTypeNames.Double, "fetch: distance the wind blows over water [m]"),
}


def water_waves(seed: int) -> list[tuple[float, float, float, float]]:
    """Seeded waves (amplitude [m], kx, kz [rad/m], phase [rad]) with wavelengths of 0.12 to 0.4 m."""
    rng = np.random.default_rng(seed)
    weights = rng.uniform(0.5, 1.0, WAVE_COUNT)
    amps = WAVE_AMPLITUDE_TOTAL * weights / weights.sum()
    waves = []
    for a in amps:
        wavelength = rng.uniform(0.12, 0.4)
        angle = rng.uniform(0.0, 2.0 * math.pi)
        k = 2.0 * math.pi / wavelength
        waves.append((float(a), k * math.cos(angle), k * math.sin(angle), float(rng.uniform(0.0, 2.0 * math.pi))))
    return waves


def water_grid(n: int, seed: int):
    """Points (V, 3), analytic unit normals (V, 3), faceVertexCounts, faceVertexIndices of the water."""
    s = np.linspace(-0.5, 0.5, n + 1)
    x, z = np.meshgrid(s, s)  # x varies along columns j, z along rows i
    h = np.full_like(x, WATER_HEIGHT)
    dhdx = np.zeros_like(x)
    dhdz = np.zeros_like(x)
    for a, kx, kz, phase in water_waves(seed):
        arg = kx * x + kz * z + phase
        h += a * np.sin(arg)
        dhdx += a * kx * np.cos(arg)
        dhdz += a * kz * np.cos(arg)
    points = np.stack([x, h, z], axis=-1).reshape(-1, 3)
    normals = np.stack([-dhdx, np.ones_like(x), -dhdz], axis=-1).reshape(-1, 3)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    v = (i * (n + 1) + j).reshape(-1)
    quads = np.stack([v, v + n + 1, v + n + 2, v + 1], axis=1)  # counter-clockwise seen from +y
    return points, normals, np.full(n * n, 4, dtype=np.int32), quads.reshape(-1)


def _vec3f_array(a) -> Vt.Vec3fArray:
    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32))


def define_mesh(stage, path, points, normals, counts, indices, doc, material):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.GetPrim().SetDocumentation(doc)
    mesh.CreatePointsAttr(_vec3f_array(points))
    mesh.CreateNormalsAttr(_vec3f_array(normals))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.asarray(counts, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(indices, dtype=np.int32)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(_vec3f_array(points)))
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def quad(corners, normal):
    """A one-quad mesh: points (4, 3), normals (4, 3), counts, indices (counter-clockwise about ``normal``)."""
    p = np.asarray(corners, dtype=np.float64)
    if np.dot(np.cross(p[1] - p[0], p[2] - p[0]), normal) < 0.0:
        p = p[::-1]
    return p, np.tile(normal, (4, 1)), [4], [0, 1, 2, 3]


def build(out: Path, ior: float, water_resolution: int, seed: int) -> Usd.Stage:
    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    stage.SetMetadata("comment", "Generated by tools/make_cornell_flooded.py: do not edit by hand.")
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(24.0)
    stage.SetFramesPerSecond(24.0)
    stage.SetStartTimeCode(0.0)
    stage.SetEndTimeCode(240.0)

    world = UsdGeom.Xform.Define(stage, "/World")
    world.GetPrim().SetDocumentation(
        "Seed 000's Cornell box (section 4, Fig. 8), flooded with water of IOR "
        f"{ior:g}. Y up, metres. Interior: floor y=0, ceiling y=1, x and z in [-0.5, 0.5], open at +z."
    )
    Usd.ModelAPI(world).SetKind(Kind.Tokens.assembly)
    stage.SetDefaultPrim(world.GetPrim())
    looks = UsdGeom.Scope.Define(stage, "/World/Looks")
    looks.GetPrim().SetDocumentation("UsdPreviewSurface materials: diffuse walls and ball, specular water.")
    white = define_material(stage, "White", "Diffuse white, albedo 0.7.", (0.7, 0.7, 0.7))
    red = define_material(stage, "Red", "Diffuse red of the left wall.", (0.7, 0.06, 0.05))
    green = define_material(stage, "Green", "Diffuse green of the right wall.", (0.08, 0.6, 0.08))
    yellow = define_material(stage, "Yellow", "Diffuse yellow of the ball.", (0.75, 0.65, 0.08))
    water_mat = define_material(
        stage, "Water", f"Water: a smooth transmissive dielectric of IOR {ior:g} (seed 000 uses 2.4 to "
        "emphasize caustics).", (1.0, 1.0, 1.0), roughness=0.0, opacity=0.0, ior=ior)

    box = UsdGeom.Xform.Define(stage, "/World/Box")
    box.GetPrim().SetDocumentation("The five walls of the box, normals facing inwards; the front (+z) is open.")
    lo, hi = -0.5, 0.5
    walls = {
        "Floor": ([(lo, 0, lo), (hi, 0, lo), (hi, 0, hi), (lo, 0, hi)], (0, 1, 0), white, "Floor, y = 0."),
        "Ceiling": ([(lo, 1, lo), (hi, 1, lo), (hi, 1, hi), (lo, 1, hi)], (0, -1, 0), white, "Ceiling, y = 1."),
        "BackWall": ([(lo, 0, lo), (hi, 0, lo), (hi, 1, lo), (lo, 1, lo)], (0, 0, 1), white, "Back wall, z = -0.5."),
        "LeftWall": ([(lo, 0, lo), (lo, 0, hi), (lo, 1, hi), (lo, 1, lo)], (1, 0, 0), red,
                     "Left wall, x = -0.5, red."),
        "RightWall": ([(hi, 0, lo), (hi, 0, hi), (hi, 1, hi), (hi, 1, lo)], (-1, 0, 0), green,
                      "Right wall, x = +0.5, green."),
    }
    for name, (corners, normal, mat, doc) in walls.items():
        define_mesh(stage, f"/World/Box/{name}", *quad(corners, np.asarray(normal, float)), doc, mat)

    import trimesh  # only the generator needs it

    ico = trimesh.creation.icosphere(subdivisions=3, radius=BALL_RADIUS)
    ball_normals = ico.vertices / np.linalg.norm(ico.vertices, axis=1, keepdims=True)
    ball = define_mesh(
        stage, "/World/Ball", ico.vertices, ball_normals, np.full(len(ico.faces), 3), ico.faces.reshape(-1),
        f"Yellow diffuse ball, radius {BALL_RADIUS} m, standing on the floor under the water.", yellow)
    UsdGeom.XformCommonAPI(ball).SetTranslate(Gf.Vec3d(*BALL_CENTER))

    points, normals, counts, indices = water_grid(water_resolution, seed)
    water = define_mesh(
        stage, "/World/Water", points, normals, counts, indices,
        f"Water surface: {water_resolution}x{water_resolution} quads at rest height {WATER_HEIGHT} m, displaced "
        f"by {WAVE_COUNT} seeded sine waves (seed {seed}, amplitudes summing to {WAVE_AMPLITUDE_TOTAL * 1000:g} mm) "
        "with analytic normals. cisp:water:* attributes parameterise the simulation that animates it.", water_mat)
    for key, (value, vtype, doc) in {**WATER_ATTRIBUTES, "seed": (seed, Sdf.ValueTypeNames.Int, "seed of the "
                                     "spectrum's random phases and of the static waves")}.items():
        attr = water.GetPrim().CreateAttribute(f"cisp:water:{key}", vtype, custom=True)
        attr.Set(value)
        attr.SetDocumentation(doc)

    spot = UsdLux.SphereLight.Define(stage, "/World/Spot")
    spot.GetPrim().SetDocumentation(
        f"The one light: a spot at {SPOT_POSITION} pointing down (-Y), half angle {SPOT_CONE_DEG} degrees, so "
        "its cone reaches the walls only below the water line. inputs:intensity is the radiant intensity "
        f"[W/sr] along the axis in cisp_warp's convention: {SPOT_INTENSITY} W/sr puts about 3 W/m2 on the "
        "floor under flat water.")
    spot.CreateTreatAsPointAttr(True)
    spot.CreateRadiusAttr(0.0)
    spot.CreateIntensityAttr(SPOT_INTENSITY)
    spot.CreateExposureAttr(0.0)
    spot.CreateColorAttr(Gf.Vec3f(1.0, 1.0, 1.0))
    shaping = UsdLux.ShapingAPI.Apply(spot.GetPrim())
    shaping.CreateShapingConeAngleAttr(SPOT_CONE_DEG)
    shaping.CreateShapingConeSoftnessAttr(0.0)
    xf = UsdGeom.XformCommonAPI(spot)
    xf.SetTranslate(Gf.Vec3d(*SPOT_POSITION))
    xf.SetRotate(Gf.Vec3f(-90.0, 0.0, 0.0))  # local -Z (the emission axis) -> world -Y

    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.GetPrim().SetDocumentation(
        f"Looks into the open front from {CAMERA_EYE} at {CAMERA_TARGET}; 40 degrees vertical field of view, "
        "16:9 aperture.")
    cam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
    cam.CreateFocalLengthAttr(FOCAL_LENGTH)
    cam.CreateHorizontalApertureAttr(HORIZONTAL_APERTURE)
    cam.CreateVerticalApertureAttr(VERTICAL_APERTURE)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.05, 20.0))
    eye, target = np.asarray(CAMERA_EYE), np.asarray(CAMERA_TARGET)
    look = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(0, 1, 0)).GetInverse()
    cam.AddTransformOp().Set(look)

    author_render_settings(stage, cam, RESOLUTION)
    return export(layer, out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT,
                    help=f"output .usda (default: {DEFAULT_OUT.relative_to(ROOT)})")
    ap.add_argument("--ior", type=float, default=2.4,
                    help="index of refraction of the water (default: 2.4, as in seed 000)")
    ap.add_argument("--water-resolution", type=int, default=96, help="water grid quads per side (default: 96)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the static waves and of cisp:water:seed (default: 0)")
    args = ap.parse_args(argv)
    if not (args.ior > 0.0 and math.isfinite(args.ior)):
        ap.error("--ior must be a positive number")
    if args.water_resolution < 1:
        ap.error("--water-resolution must be at least 1")

    stage = build(args.out, args.ior, args.water_resolution, args.seed)
    errors = validation_errors(stage)
    for e in errors:
        print(f"validation error: {e}", file=sys.stderr)

    from cisp_warp.usd import load_usd

    scene = load_usd(args.out)
    print(f"wrote {args.out}: {scene.triangle_count} triangles, {len(scene.materials)} materials, "
          f"{len(scene.lights)} light(s), camera fov_y {math.degrees(scene.camera.fov_y):.1f} deg, "
          f"{scene.camera.width}x{scene.camera.height}")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
