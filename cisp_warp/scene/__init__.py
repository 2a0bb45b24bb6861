"""Scene model: what caustics need (triangles, normals, materials, lights, camera, time) and nothing more."""

from .model import (
    LAYER_OPAQUE,
    LAYER_SPECULAR,
    Camera,
    Light,
    LightKind,
    Material,
    MeshRange,
    Scene,
    Sky,
)
from .device import DeviceScene

__all__ = [
    "LAYER_OPAQUE",
    "LAYER_SPECULAR",
    "Camera",
    "DeviceScene",
    "Light",
    "LightKind",
    "Material",
    "MeshRange",
    "Scene",
    "Sky",
]
