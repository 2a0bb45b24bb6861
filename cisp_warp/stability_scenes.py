"""Scenes and animations where screen-space caustics methods are known to fail (or must not), built in code:
the cases of ``tools/stability.py`` and ``tests/test_stability.py``.

A :class:`Case` is a scene as a function of the frame number (camera, lights and water may move) and the
region of the image whose caustic it is about. Water is a sum of travelling sinusoids over a floor
(:func:`wavy_water`): its heights and normals are analytic, so every frame is exact and cheap.

=========================  ==============================================================================
case                       what happens, and the stated limit it probes
=========================  ==============================================================================
``outside_light_frustum``  a spot grazes water; the reflection lands on a wall outside the spot's cone
                           (seed 004 cannot show it; seed 000's cascade is built for it)
``hidden_trail``           the same, with a screen hiding the photons' path from the camera (seed 000 §4.3:
                           CISP loses such trails; world-space SSPM does not)
``receiver_offscreen``     the same wall, now outside the camera view: a control; no method may lose the
                           visible caustic under the water or smear the off-screen one onto the frame
``grazing_light``          the sun 80° from the zenith: stretched light-view texels, long light-view marches
``ior_2_4``                water of IOR 2.4 (seed 000's choice): strong refraction, more total reflection
``deep_folding``           1.5 m deep water, past the waves' focal distance: the caustic folds over itself
``camera_pan``             the camera pans 0.03 m of aim per frame over a static caustic (seed 000 §4.3:
                           low-frequency noise under camera motion)
``moving_light``           the sun's azimuth turns 3° per frame
``fast_water``             waves travel at their deep-water phase speed (ω² = g k), 24 frames per second
=========================  ==============================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from . import analytic
from .analytic import FLOOR, quad
from .scene import Camera, Light, LightKind, Material, Scene
from .scene.model import MeshRange, look_at_matrix

G = 9.81  #: gravity [m/s²], for the deep-water dispersion ω² = g k


@dataclass(frozen=True)
class Wave:
    """One travelling sinusoid h = A sin(k·x − ω t + φ) of the water surface."""

    amplitude: float  #: A [m]
    wavevector: tuple[float, float]  #: (k_x, k_z) [rad/m]
    omega: float = 0.0  #: angular frequency ω [rad/s]; 0 = frozen
    phase: float = 0.0  #: φ [rad]

    def moving(self) -> "Wave":
        """The same wave at its deep-water angular frequency ω = sqrt(g |k|)."""
        return replace(self, omega=math.sqrt(G * math.hypot(*self.wavevector)))


def _wave(amplitude, wavelength, heading_deg, phase=0.0) -> Wave:
    k = 2 * math.pi / wavelength
    h = math.radians(heading_deg)
    return Wave(amplitude, (k * math.cos(h), k * math.sin(h)), 0.0, phase)


#: three crossing waves, 0.22–0.31 m long: local focal distances about 0.3–0.6 m under water of IOR 1.33
CHOPPY = (_wave(0.005, 0.31, 10.0), _wave(0.004, 0.25, 75.0, 1.0), _wave(0.003, 0.22, 140.0, 2.0))


def water_surface(n: int, size: float, waves, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Points [m] and unit normals of an n × n vertex grid over [−size/2, size/2]² at time ``t`` [s]:
    y = Σ A sin(k·x − ω t + φ), normal ∝ (−∂h/∂x, 1, −∂h/∂z). Vertex iz·n + ix; (n², 3) float64 each."""
    s = np.linspace(-0.5 * size, 0.5 * size, n)
    x, z = np.meshgrid(s, s)
    h, hx, hz = np.zeros_like(x), np.zeros_like(x), np.zeros_like(x)
    for w in waves:
        arg = w.wavevector[0] * x + w.wavevector[1] * z - w.omega * t + w.phase
        h += w.amplitude * np.sin(arg)
        hx += w.amplitude * w.wavevector[0] * np.cos(arg)
        hz += w.amplitude * w.wavevector[1] * np.cos(arg)
    pts = np.stack([x, h, z], -1).reshape(-1, 3)
    nrm = np.stack([-hx, np.ones_like(h), -hz], -1).reshape(-1, 3)
    return pts, nrm / np.linalg.norm(nrm, axis=-1, keepdims=True)


def grid_faces(n: int) -> np.ndarray:
    """Triangles of an n × n vertex grid (vertex iz·n + ix), counter-clockwise seen from +y, (2(n−1)², 3)."""
    ix, iz = np.meshgrid(np.arange(n - 1), np.arange(n - 1))
    a = (iz * n + ix).reshape(-1)
    b, c, d = a + n, a + 1, a + n + 1
    return np.concatenate([np.stack([a, b, c], -1), np.stack([c, b, d], -1)]).astype(np.int32)


def sun(zenith_deg: float, azimuth_deg: float = 0.0, irradiance: float = 1000.0) -> Light:
    """A distant light ``zenith_deg`` from the zenith, travelling towards +x at azimuth 0 [W/m² facing it]."""
    th, ph = math.radians(zenith_deg), math.radians(azimuth_deg)
    d = (math.sin(th) * math.cos(ph), -math.cos(th), math.sin(th) * math.sin(ph))
    return Light(LightKind.DISTANT, "sun", intensity=irradiance, direction=d)


def default_camera(width: int, height: int, target=(0.0, -0.4, 0.0)) -> Camera:
    """A perspective camera above and in front of the pool, looking down at the floor."""
    return Camera(look_at_matrix((0.0, 0.8, 0.95), target), fov_y=math.radians(50), width=width, height=height,
                  near=0.05, far=20.0)


def grid_for(width: int) -> int:
    """Water vertices per side for an image ``width`` pixels wide: about one per 4 pixels, 64 to 256."""
    return int(min(256, max(64, width // 4)))


def wavy_water(width: int = 64, height: int = 48, n: int | None = None, size: float = 1.0, depth: float = 0.4,
               waves=CHOPPY, ior: float = 1.33, lights=None, camera: Camera | None = None, t: float = 0.0) -> Scene:
    """A ``size`` m square of water (``waves`` at time ``t``, ``n`` × ``n`` vertices, default
    :func:`grid_for`) over a floor ``depth`` m below, lit by
    ``lights`` (default: the sun 25° from the zenith) and seen by ``camera`` (default: :func:`default_camera`).
    The water is a dynamic mesh (``MeshRange.dynamic``): :meth:`Renderer.update_scene` moves it."""
    n = grid_for(width) if n is None else n
    pts, nrm = water_surface(n, size, waves, t)
    faces = grid_faces(n)
    floor_p, floor_f = quad(0, -depth, 0, (2 * size, 0, 0), (0, 0, -2 * size))
    water = Material("water", albedo=(1, 1, 1), roughness=0.0, opacity=0.0, ior=ior)
    v, tcount = len(pts), len(faces)
    scene = Scene(np.vstack([pts, floor_p]).astype(np.float32),
                  np.vstack([nrm, np.tile([0.0, 1.0, 0.0], (4, 1))]).astype(np.float32),
                  np.vstack([faces, floor_f + v]).astype(np.int32),
                  np.concatenate([np.ones(tcount), np.zeros(len(floor_f))]).astype(np.int32),
                  [FLOOR, water], list(lights) if lights is not None else [sun(25.0)],
                  camera if camera is not None else default_camera(width, height),
                  meshes=[MeshRange("/water", 0, v, 0, tcount, dynamic=True), MeshRange("/floor", v, 4, tcount, 2)])
    return scene


def offscreen_wall_scene(width: int = 64, height: int = 48) -> Scene:
    """:func:`analytic.wall_scene` seen by a camera turned away from the wall (x = 1 m), which it no longer
    sees, while it still sees the water's floor caustic."""
    s = analytic.wall_scene(width=width, height=height)
    s.camera = Camera(look_at_matrix((-0.9, 1.3, 2.2), (-0.5, -0.3, 0.0)), fov_y=math.radians(50), width=width,
                      height=height, near=0.05, far=20)
    return s


@dataclass(frozen=True)
class Case:
    """A stability case: ``scene_at(frame, width, height)`` is the whole scene at a frame (same topology and
    lights of the same kind every frame); ``region(aovs)`` the receiver it is about (None: every pixel)."""

    name: str
    summary: str
    scene_at: Callable[[int, int, int], Scene]
    region: Callable[[dict], np.ndarray] | None = None
    animated: bool = False  #: False: only the frame's random numbers change
    expect: dict = field(default_factory=dict)  #: method -> what the papers' stated limits predict, in words


def _static(build):
    return lambda frame, w, h: build(w, h)


def _pan(frame, w, h):
    return wavy_water(w, h, camera=default_camera(w, h, target=(-0.12 + 0.03 * frame, -0.4, 0.0)))


def _moving_light(frame, w, h):
    return wavy_water(w, h, lights=[sun(30.0, azimuth_deg=3.0 * frame)])


FAST_WAVES = tuple(w.moving() for w in CHOPPY)
FRAME_TIME = 1.0 / 24.0  #: [s] between frames of the animated cases


def _fast_water(frame, w, h):
    return wavy_water(w, h, waves=FAST_WAVES, t=frame * FRAME_TIME)


CASES: tuple[Case, ...] = (
    Case("outside_light_frustum", "reflection onto a wall outside the spot's cone",
         _static(lambda w, h: analytic.wall_scene(width=w, height=h)), analytic.wall_mask,
         expect={"caustics_map": "loses the wall caustic (light space only)", "cisp": "finds it (cascade)",
                 "sspm": "finds it"}),
    Case("hidden_trail", "the photons' path to the wall hidden from the camera by a screen",
         _static(lambda w, h: analytic.wall_scene(occluder=True, width=w, height=h)), analytic.wall_mask,
         expect={"cisp": "loses it (trail occluded in the camera view)", "sspm": "finds it",
                 "caustics_map": "loses it"}),
    Case("receiver_offscreen", "the wall caustic outside the camera view (control)",
         _static(offscreen_wall_scene)),
    Case("grazing_light", "the sun 80° from the zenith", _static(lambda w, h: wavy_water(w, h, lights=[sun(80.0)]))),
    Case("ior_2_4", "water of IOR 2.4", _static(lambda w, h: wavy_water(w, h, ior=2.4))),
    Case("deep_folding", "1.5 m deep water: folded caustics", _static(lambda w, h: wavy_water(w, h, depth=1.5))),
    Case("camera_pan", "camera aim pans 0.03 m per frame", _pan, animated=True),
    Case("moving_light", "sun azimuth turns 3° per frame", _moving_light, animated=True),
    Case("fast_water", "waves at deep-water phase speed, 24 fps", _fast_water, animated=True),
)


def frozen(c: Case, frame: int) -> Case:
    """The static twin of an animated case: its scene at ``frame``, held still (only the photons' random
    numbers change), for the error a method reaches on the same caustic when nothing moves."""
    return replace(c, name=f"{c.name}@{frame}", summary=f"{c.summary}, held still at frame {frame}",
                   scene_at=lambda f, w, h: c.scene_at(frame, w, h), animated=False)


def case(name: str) -> Case:
    for c in CASES:
        if c.name == name:
            return c
    raise KeyError(f"no stability case {name!r}; one of {', '.join(c.name for c in CASES)}")
