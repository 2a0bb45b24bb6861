"""Host-side scene model: the static description of a frame that every pass reads.

World frame: right-handed, **Y up**, metres. A USD stage is brought to this frame on import
(``metersPerUnit`` and ``upAxis``). Cameras and light views look down their local **-Z** axis
with +Y up (the USD / OpenGL convention); view-space depth is the positive distance along -Z.

Radiometric units (SI):

======================  ==========================================================
distant light           ``intensity`` is the irradiance [W/m²] it delivers to a
                        surface facing it, per unit of ``color``
point and spot light    ``intensity`` is the radiant intensity [W/sr] along the
                        axis, per unit of ``color``
dome light (sky)        ``color × intensity`` (× the texture, when it has one) is
                        the radiance [W/(m² sr)] arriving from each direction
======================  ==========================================================
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import SceneError

# Raster layer bits (per triangle). A triangle is drawn into the views of each layer whose bit it has.
LAYER_OPAQUE = 1  #: blocks light and the camera: depth of the opaque G-buffer / RSM
LAYER_SPECULAR = 2  #: reflects or refracts specularly: the RSM specular layer, the camera water layer


@dataclass(frozen=True)
class Material:
    """A UsdPreviewSurface reduced to what caustics need.

    ``opacity < 1`` means a dielectric that transmits (water, glass): it is not in the opaque layer.
    ``metallic > 0`` or transmission puts the surface in the specular layer; whether it is specular
    *enough* to cast caustics is decided by the photon pass's roughness cutoff (and booked in its ledger).
    """

    name: str = "default"
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)  #: diffuse reflectance, linear RGB in [0, 1]
    roughness: float = 0.5  #: perceptual roughness in [0, 1]
    metallic: float = 0.0  #: in [0, 1]
    opacity: float = 1.0  #: 1 = opaque, < 1 = transmissive dielectric
    ior: float = 1.5  #: index of refraction of the medium behind the surface (outside is air, 1.0)

    @property
    def transmissive(self) -> bool:
        return self.opacity < 1.0

    @property
    def layers(self) -> int:
        mask = 0 if self.transmissive else LAYER_OPAQUE
        if self.transmissive or self.metallic > 0.0:
            mask |= LAYER_SPECULAR
        return mask


class LightKind(enum.IntEnum):
    DISTANT = 0
    POINT = 1
    SPOT = 2


@dataclass
class Light:
    """A light that a reflective shadow map can be rendered from (seed 000, section 4.3)."""

    kind: LightKind
    name: str  #: prim path or a short name, used in AOV file names (``rsm_<name>_*``)
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)  #: linear RGB multiplier of ``intensity``
    intensity: float = 1.0  #: W/m² (distant) or W/sr (point, spot); USD intensity × 2^exposure
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: [m], point and spot
    direction: tuple[float, float, float] = (0.0, -1.0, 0.0)  #: unit vector the light travels along (distant, spot axis)
    cone_angle: float = math.pi  #: spot half-angle [rad] off ``direction``
    cone_softness: float = 0.0  #: in [0, 1]: fraction of the cone over which intensity falls smoothly to 0

    @property
    def radiometric_rgb(self) -> np.ndarray:
        """Irradiance [W/m²] (distant) or intensity [W/sr] (point, spot) per RGB channel."""
        return np.asarray(self.color, dtype=np.float64) * float(self.intensity)

    @property
    def safe_name(self) -> str:
        """``name`` reduced to characters that are safe in a file name."""
        s = "".join(c if c.isalnum() else "_" for c in self.name).strip("_")
        return s or "light"


@dataclass
class Sky:
    """A dome light: radiance [W/(m² sr)] arriving from every direction of an infinitely distant sphere.

    The radiance from world direction ω (pointing from the scene towards the sky) is
    ``radiance × texture(to_local · ω)``. ``texture`` is a lat-long map in the OpenEXR convention that
    UsdLux prescribes for dome lights: column ``x`` has longitude π − 2π (x + ½)/W, row ``y`` latitude
    π/2 − π (y + ½)/H, and (latitude, longitude) is the dome-local direction
    (cos lat · sin lon, sin lat, cos lat · cos lon): +Y up, longitude 0 along +Z. Without a texture the
    sky is uniform.
    """

    name: str  #: prim path
    radiance: tuple[float, float, float] = (1.0, 1.0, 1.0)  #: colour × intensity × 2^exposure [W/(m² sr)]
    texture: np.ndarray | None = None  #: (H, W, 3) float32 linear RGB multiplier, lat-long; None = uniform
    to_world: np.ndarray = field(default_factory=lambda: np.eye(3))  #: rotation, dome-local -> world

    def radiance_map(self) -> np.ndarray:
        """(H, W, 3) float64 lat-long radiance [W/(m² sr)] in dome-local directions ((1, 2, 3) when uniform)."""
        rgb = np.asarray(self.radiance, dtype=np.float64)
        if self.texture is None:
            return np.broadcast_to(rgb, (1, 2, 3)).copy()
        return np.asarray(self.texture, dtype=np.float64) * rgb


@dataclass
class Camera:
    """A pinhole (or orthographic) camera looking down its local -Z axis.

    ``to_world`` is the 4x4 camera-to-world matrix acting on column vectors: columns 0, 1, 2 are the
    camera's right, up and backward (+Z) axes in world space, column 3 its position [m].
    """

    to_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    fov_y: float = math.radians(45.0)  #: full vertical field of view [rad] (perspective)
    ortho_height: float = 2.0  #: full vertical extent of the view [m] (orthographic)
    near: float = 0.01  #: [m]
    far: float = 100.0  #: [m]
    width: int = 640  #: [pixels]
    height: int = 360  #: [pixels]
    orthographic: bool = False

    @staticmethod
    def look_at(eye, target, up=(0.0, 1.0, 0.0), **kwargs) -> "Camera":
        """A camera at ``eye`` [m] looking at ``target`` [m]."""
        return Camera(to_world=look_at_matrix(eye, target, up), **kwargs)

    @property
    def position(self) -> np.ndarray:
        return np.asarray(self.to_world, dtype=np.float64)[:3, 3]

    @property
    def forward(self) -> np.ndarray:
        return -np.asarray(self.to_world, dtype=np.float64)[:3, 2]

    @property
    def aspect(self) -> float:
        return self.width / self.height

    def validate(self, where: str = "camera") -> None:
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise SceneError(f"resolution must be positive, got {self.width}x{self.height}", prim=where)
        m = np.asarray(self.to_world, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise SceneError("camera transform is not a finite 4x4 matrix", prim=where)
        if abs(np.linalg.det(m[:3, :3])) < 1e-12:
            raise SceneError("camera transform is singular (zero scale)", prim=where)
        if not (np.isfinite(self.near) and np.isfinite(self.far) and 0.0 < self.near < self.far):
            raise SceneError(f"clipping range must satisfy 0 < near < far, got ({self.near}, {self.far})", prim=where)
        if self.orthographic:
            if not (np.isfinite(self.ortho_height) and self.ortho_height > 0.0):
                raise SceneError(f"orthographic extent must be positive, got {self.ortho_height}", prim=where)
        elif not (np.isfinite(self.fov_y) and 0.0 < self.fov_y < math.pi):
            raise SceneError(f"field of view must lie in (0, 180) degrees, got {math.degrees(self.fov_y)}", prim=where)


def look_at_matrix(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Camera-to-world matrix of a view at ``eye`` looking at ``target`` (-Z forward, +Y up)."""
    eye = np.asarray(eye, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64) - eye
    f /= np.linalg.norm(f)
    up = np.asarray(up, dtype=np.float64)
    if abs(np.dot(f, up / np.linalg.norm(up))) > 0.999:
        up = np.array([1.0, 0.0, 0.0]) if abs(f[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = r, u, -f, eye
    return m


@dataclass
class MeshRange:
    """Where one imported mesh lives in the scene's concatenated arrays."""

    path: str  #: USD prim path
    vertex_start: int
    vertex_count: int
    triangle_start: int
    triangle_count: int
    dynamic: bool = False  #: points change over time (water driven by ``sim/``, or time-sampled points)
    water: dict | None = None  #: ``cisp:water:*`` simulation parameters when this mesh is simulated water


@dataclass
class Scene:
    """Everything a frame needs, on the host, in world space (Y up, metres).

    ==================  ===============  =======  =============================================
    array               shape            dtype    meaning
    ==================  ===============  =======  =============================================
    points              (V, 3)           float32  vertex positions [m]
    normals             (V, 3)           float32  unit shading normals per vertex
    indices             (T, 3)           int32    vertex indices per triangle, counter-clockwise
    triangle_material   (T,)             int32    index into ``materials``
    ==================  ===============  =======  =============================================
    """

    points: np.ndarray
    normals: np.ndarray
    indices: np.ndarray
    triangle_material: np.ndarray
    materials: list[Material]
    lights: list[Light]
    camera: Camera
    meshes: list[MeshRange] = field(default_factory=list)
    sky: Sky | None = None  #: the dome light, lighting diffuse surfaces and seen where nothing else is
    time: float = 0.0  #: stage time [s] (time code / timeCodesPerSecond)
    time_code: float = 0.0
    source: str = ""  #: file the scene came from, for messages

    @property
    def triangle_count(self) -> int:
        return int(self.indices.shape[0])

    @property
    def vertex_count(self) -> int:
        return int(self.points.shape[0])

    def triangle_layers(self) -> np.ndarray:
        """Layer mask per triangle, shape (T,), int32 (``LAYER_OPAQUE | LAYER_SPECULAR`` bits)."""
        per_material = np.array([m.layers for m in self.materials], dtype=np.int32)
        return per_material[self.triangle_material]

    def bounds(self, layer: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds [m] of the triangles of ``layer`` (all when None); (lo, hi) float64."""
        idx = self.indices
        if layer is not None:
            idx = idx[(self.triangle_layers() & layer) != 0]
        if idx.size == 0:
            raise SceneError("no triangles in the requested layer", file=self.source)
        p = self.points[np.unique(idx)].astype(np.float64)
        return p.min(axis=0), p.max(axis=0)

    def validate(self) -> None:
        """Raise :class:`SceneError` if an array is malformed; cheap, run once after import."""
        src = self.source or None
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise SceneError(f"points must have shape (V, 3), got {self.points.shape}", file=src)
        if self.normals.shape != self.points.shape:
            raise SceneError(f"normals shape {self.normals.shape} differs from points {self.points.shape}", file=src)
        if self.indices.ndim != 2 or self.indices.shape[1] != 3 or self.indices.shape[0] == 0:
            raise SceneError("the scene has no triangles: nothing to render", file=src)
        if not np.all(np.isfinite(self.points)):
            raise SceneError("points contain NaN or Inf", file=src)
        if self.indices.min() < 0 or self.indices.max() >= self.points.shape[0]:
            raise SceneError("triangle indices out of range", file=src)
        if self.triangle_material.shape != (self.indices.shape[0],):
            raise SceneError("triangle_material must have one entry per triangle", file=src)
        if not self.materials or self.triangle_material.max() >= len(self.materials):
            raise SceneError("triangle material index out of range", file=src)
        if not self.lights and self.sky is None:
            raise SceneError("the scene has no light: add a DistantLight, SphereLight, spot light or DomeLight", file=src)
        self.camera.validate()
