"""Small scenes with known answers, built in code: what tests, the evaluation and the stability suite
measure every method against.

=====================  ======================================================================
scene                  known answer
=====================  ======================================================================
``flat_water``         floor irradiance E⊥ · cos θ · (1 − F(θ)) under the water
``sinusoidal_water``   floor irradiance profile from the analytic refraction ray map
``wall_scene``         a reflected caustic on a wall outside the spot light's cone
``wavy_water``         smooth 2-D waves over a floor, a camera close over part of it: the converged
                       caustic must not depend on the RSM size, and light views fitted to the
                       camera must leave it unchanged
=====================  ======================================================================
"""

from __future__ import annotations

import math

import numpy as np

from .optics import fresnel_dielectric_np
from .scene import Camera, Light, LightKind, Material, Scene
from .scene.model import look_at_matrix

FLOOR = Material("floor", albedo=(0.8, 0.8, 0.8), roughness=1.0)
WATER = Material("water", albedo=(1, 1, 1), roughness=0.0, opacity=0.0, ior=1.33)


def quad(cx, cy, cz, ax, bx):
    """Quad centred at c spanned by half-vectors ax, bx, counter-clockwise around ax × bx."""
    c, a, b = np.array([cx, cy, cz]), np.asarray(ax, float), np.asarray(bx, float)
    return np.array([c - a - b, c + a - b, c + a + b, c - a + b]), np.array([[0, 1, 2], [0, 2, 3]])


def build(parts, camera, lights, materials=(FLOOR, WATER)) -> Scene:
    """A scene of flat-shaded parts ``[((points, faces), material index), ...]``."""
    pts, nrm, idx, mat, off = [], [], [], [], 0
    for (p, f), m in parts:
        n = np.cross(p[f[0, 1]] - p[f[0, 0]], p[f[0, 2]] - p[f[0, 0]])
        pts.append(p)
        nrm.append(np.tile(n / np.linalg.norm(n), (len(p), 1)))
        idx.append(f + off)
        mat.append(np.full(len(f), m))
        off += len(p)
    return Scene(np.vstack(pts).astype(np.float32), np.vstack(nrm).astype(np.float32), np.vstack(idx).astype(np.int32),
                 np.concatenate(mat).astype(np.int32), list(materials), lights, camera)


def flat_water(theta_deg: float, E: float = 1000.0, size: int = 48, ior: float = 1.33) -> Scene:
    """A 1 m square of flat water 0.5 m above a floor, a sun at ``theta_deg`` from the zenith."""
    th = math.radians(theta_deg)
    water = (quad(0, 0, 0, (0.5, 0, 0), (0, 0, -0.5)), 1)
    floor = (quad(0, -0.5, 0, (2, 0, 0), (0, 0, -2)), 0)
    cam = Camera(look_at_matrix((0.2, 1.2, 0.0001), (0.2, -0.5, 0)), fov_y=math.radians(45), width=size, height=size,
                 near=0.05, far=10)
    sun = Light(LightKind.DISTANT, "sun", intensity=E, direction=(math.sin(th), -math.cos(th), 0.0))
    water_mat = Material("water", albedo=(1, 1, 1), roughness=0.0, opacity=0.0, ior=ior)
    return build([water, floor], cam, [sun], (FLOOR, water_mat))


def flat_water_answer(theta_deg: float, E: float = 1000.0, ior: float = 1.33) -> tuple[float, float]:
    """(floor irradiance E⊥·cos θ·(1 − F(θ)) [W/m²], x offset of the refracted beam on the floor [m])."""
    th = math.radians(theta_deg)
    sin_t = math.sin(th) / ior
    shift = 0.5 * sin_t / math.sqrt(1 - sin_t ** 2)
    return E * math.cos(th) * (1.0 - fresnel_dielectric_np(math.cos(th), ior)), shift


def flat_water_interior(aovs: dict, theta_deg: float, ior: float = 1.33, half: float = 0.4) -> np.ndarray:
    """Mask of floor pixels well inside the refracted beam of :func:`flat_water`."""
    _, shift = flat_water_answer(theta_deg, ior=ior)
    x = aovs["position"]
    return (np.abs(x[..., 0] - shift) < half) & (np.abs(x[..., 2]) < half) & (aovs["depth"] > 0)


SINUSOID = dict(A=0.01, k=2 * math.pi / 0.25, D=0.3, E=1000.0, eta=1.33)


def sinusoidal_water(width: int = 64, height: int = 32, nx: int = 400, **kw) -> Scene:
    """Water h(x) = A sin(kx) over a floor at depth D, a vertical sun, an orthographic camera looking
    down (0.4 m high view: 1 pixel = 0.4/height m)."""
    p = {**SINUSOID, **kw}
    A, k, D, E = p["A"], p["k"], p["D"], p["E"]
    xs = np.linspace(-0.5, 0.5, nx + 1)
    h = A * np.sin(k * xs)
    slope = A * k * np.cos(k * xs)
    pts = np.concatenate([np.stack([xs, h, np.full_like(xs, z)], -1) for z in (-0.5, 0.5)])
    nrm = np.stack([-slope, np.ones_like(xs), np.zeros_like(xs)], -1)
    nrm = np.concatenate([nrm, nrm]) / np.concatenate([np.linalg.norm(nrm, axis=-1)] * 2)[:, None]
    q = np.arange(nx)
    faces = np.concatenate([np.stack([q, q + nx + 1, q + 1], -1), np.stack([q + 1, q + nx + 1, q + nx + 2], -1)])
    floor_p, floor_f = quad(0, -D, 0, (2, 0, 0), (0, 0, -2))
    to_world = np.eye(4)
    to_world[:3, 0], to_world[:3, 1], to_world[:3, 2], to_world[:3, 3] = (1, 0, 0), (0, 0, -1), (0, 1, 0), (0, 1, 0)
    cam = Camera(to_world, orthographic=True, ortho_height=0.4, width=width, height=height, near=0.05, far=5.0)
    sun = Light(LightKind.DISTANT, "sun", intensity=E, direction=(0.0, -1.0, 0.0))
    water = Material("water", albedo=(1, 1, 1), roughness=0.0, opacity=0.0, ior=p["eta"])
    return Scene(np.vstack([pts, floor_p]).astype(np.float32),
                 np.vstack([nrm, np.tile([0, 1, 0], (4, 1))]).astype(np.float32),
                 np.vstack([faces, floor_f + len(pts)]).astype(np.int32),
                 np.concatenate([np.full(len(faces), 1), np.zeros(2)]).astype(np.int32), [FLOOR, water], [sun], cam)


def sinusoidal_answer(width: int = 64, height: int = 32, samples: int = 2_000_001, **kw) -> np.ndarray:
    """Floor irradiance [W/m²] per pixel column of :func:`sinusoidal_water`: dense surface samples
    refracted by the analytic ray map X(x) = x + (h + D)·t_x/(−t_y), weighted by (1 − F), binned."""
    p = {**SINUSOID, **kw}
    A, k, D, E, eta = p["A"], p["k"], p["D"], p["E"], p["eta"]
    x = np.linspace(-0.5, 0.5, samples)
    s = A * k * np.cos(k * x)
    n = np.stack([-s, np.ones_like(s)], -1) / np.sqrt(1 + s * s)[:, None]
    cos_i = n[:, 1]
    sin2_t = (1 - cos_i ** 2) / eta ** 2
    t = np.stack([0 * s, -np.ones_like(s)], -1) / eta + n * (cos_i / eta - np.sqrt(1 - sin2_t))[:, None]
    X = x + (A * np.sin(k * x) + D) * t[:, 0] / (-t[:, 1])
    weight = E * (1 - fresnel_dielectric_np(cos_i, eta)) * (x[1] - x[0])
    px = 0.4 / height  # metres per pixel
    edges = (np.arange(width + 1) - width / 2) * px
    return np.histogram(X, bins=edges, weights=weight)[0] / px


def wall_scene(occluder: bool = False, width: int = 64, height: int = 48) -> Scene:
    """A spot light grazes the water; the reflection lands on a wall (x = 1 m) far outside the spot's cone.

    ``occluder``: a screen between the camera and the water hides the photons' path in the camera view
    but leaves the wall's caustic visible.
    """
    water = (quad(0, 0, 0, (0.6, 0, 0), (0, 0, -0.6)), 1)
    floor = (quad(0, -0.4, 0, (1.2, 0, 0), (0, 0, -1.2)), 0)
    wall = (quad(1.0, 0.8, 0, (0, 1.2, 0), (0, 0, -1.2)), 0)  # x = 1, facing -x
    parts = [water, floor, wall]
    if occluder:
        parts.append((quad(0.2, 0.3, 1.0, (1.0, 0, 0), (0, 0.15, 0)), 0))
    pos = np.array([-0.8, 1.0, 0.0])
    axis = -pos / np.linalg.norm(pos)
    cam = Camera(look_at_matrix((-0.6, 1.0, 3.4), (0.6, 0.9, 0.0)), fov_y=math.radians(60), width=width,
                 height=height, near=0.05, far=20)
    spot = Light(LightKind.SPOT, "spot", intensity=50.0, position=tuple(pos), direction=tuple(axis),
                 cone_angle=math.radians(8))
    return build(parts, cam, [spot])


def wall_mask(aovs: dict) -> np.ndarray:
    """Pixels of :func:`wall_scene`'s wall."""
    return (aovs["position"][..., 0] > 0.99) & (aovs["depth"] > 0)


def footprint_area(aovs: dict, view) -> np.ndarray:
    """numpy twin of the exact pixel footprint Ω_p · r² / |cos θ| [m²] (perspective views)."""
    omega = view.texel_solid_angle()
    x, n = aovs["position"].astype(np.float64), aovs["normal"].astype(np.float64)
    to_eye = view.to_world[:3, 3] - x
    r2 = (to_eye ** 2).sum(-1)
    cos_t = np.abs((n * to_eye).sum(-1)) / np.sqrt(r2)
    return omega * r2 / np.maximum(cos_t, 1e-6)


WAVY = dict(A=0.012, kx=2 * math.pi / 0.31, kz=2 * math.pi / 0.23, D=0.45, E=1000.0, eta=1.33, half=1.0)


def wavy_water(width: int = 64, height: int = 64, grid: int = 96, closeup: float = 0.3, sun_deg: float = 10.0,
               **kw) -> Scene:
    """Smooth crossed waves h(x, z) = A sin(kx·x) sin(kz·z + 0.7) over a white floor at depth D, under a sun
    ``sun_deg`` from the zenith; a perspective camera 0.35 m over the water looks down at a ``closeup`` m
    wide patch of floor near one corner, so most of the water's light lands where the camera does not look.

    The water is a ``grid``² vertex sheet of half-width ``half`` with analytic (exact) vertex normals; the
    caustic folds at this depth, so a photon's normal, not its texel's, decides where it lands.
    """
    p = {**WAVY, **kw}
    A, kx, kz, D, E, half = p["A"], p["kx"], p["kz"], p["D"], p["E"], p["half"]
    t = np.linspace(-half, half, grid)
    X, Z = np.meshgrid(t, t, indexing="ij")
    H = A * np.sin(kx * X) * np.sin(kz * Z + 0.7)
    hx = A * kx * np.cos(kx * X) * np.sin(kz * Z + 0.7)
    hz = A * kz * np.sin(kx * X) * np.cos(kz * Z + 0.7)
    pts = np.stack([X, H, Z], -1).reshape(-1, 3)
    nrm = np.stack([-hx, np.ones_like(hx), -hz], -1).reshape(-1, 3)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    q = (np.arange(grid - 1)[:, None] * grid + np.arange(grid - 1)[None, :]).reshape(-1)
    # counter-clockwise seen from above (+y): (i, j) -> (i, j+1) -> (i+1, j)
    faces = np.concatenate([np.stack([q, q + 1, q + grid], -1), np.stack([q + 1, q + grid + 1, q + grid], -1)])
    floor_p, floor_f = quad(0, -D, 0, (1.5 * half, 0, 0), (0, 0, -1.5 * half))
    th = math.radians(sun_deg)
    sun = Light(LightKind.DISTANT, "sun", intensity=E, direction=(math.sin(th), -math.cos(th), 0.0))
    target = np.array([0.45 * half, -D, 0.35 * half])
    fov = math.radians(40.0)
    dist = 0.5 * closeup / math.tan(0.5 * fov)
    eye = target + np.array([0.0, dist, 0.25 * dist])
    cam = Camera(look_at_matrix(tuple(eye), tuple(target)), fov_y=fov, width=width, height=height, near=0.02, far=10.0)
    water = Material("water", albedo=(1, 1, 1), roughness=0.0, opacity=0.0, ior=p["eta"])
    return Scene(np.vstack([pts, floor_p]).astype(np.float32),
                 np.vstack([nrm, np.tile([0, 1, 0], (4, 1))]).astype(np.float32),
                 np.vstack([faces, floor_f + len(pts)]).astype(np.int32),
                 np.concatenate([np.full(len(faces), 1), np.zeros(2)]).astype(np.int32), [FLOOR, water], [sun], cam)
