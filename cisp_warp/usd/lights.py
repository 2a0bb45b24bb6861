"""UsdLux lights -> :class:`Light` (point, spot and directional only: seed 000, section 4.3).

* ``DistantLight``: ``Light.direction`` is the world direction the light travels (its local -Z).
* ``SphereLight``: a point light at its origin. ``treatAsPoint`` or a world radius of at most
  ``POINT_RADIUS_M`` is taken as is; a larger radius is ignored with a :class:`SceneWarning`.
  With ``ShapingAPI`` (or an authored ``inputs:shaping:cone:angle``) below 180 degrees it is a spot:
  ``cone_angle`` = that half angle [rad] off its -Z, ``cone_softness`` = ``inputs:shaping:cone:softness``.
* ``Light.intensity`` = ``inputs:intensity`` × 2^``inputs:exposure``, ``Light.color`` = ``inputs:color``,
  interpreted in the model's SI units (W/m² for distant, W/sr for point and spot): see
  :mod:`cisp_warp.usd`.
* Any other light type (Rect, Disk, Dome, Cylinder, Geometry, Portal, plugin) -> one warning, ignored.
"""

from __future__ import annotations

import math

import numpy as np
from pxr import UsdLux

from ..errors import SceneError
from ..scene.model import Light, LightKind
from .stage import StageContext, finite_float, finite_vec3

POINT_RADIUS_M = 0.01  #: a SphereLight no larger than this [m] is a point light without a warning


def read_light(ctx: StageContext, prim) -> Light | None:
    """The :class:`Light` of a UsdLux light prim, or None (with a warning) for unsupported types."""
    path = str(prim.GetPath())
    if prim.IsA(UsdLux.DistantLight):
        kind = LightKind.DISTANT
    elif prim.IsA(UsdLux.SphereLight):
        kind = LightKind.POINT
    else:
        ctx.warn(
            f"{prim.GetTypeName() or 'this'} light is not supported (only point, spot and directional "
            "lights, seed 000 section 4.3): ignored",
            path,
        )
        return None

    api = UsdLux.LightAPI(prim)
    intensity = finite_float(ctx.get(api.GetIntensityAttr()), "inputs:intensity", path)
    if intensity < 0.0:
        raise SceneError(f"inputs:intensity = {intensity}: a light's intensity must not be negative", prim=path)
    exposure = finite_float(ctx.get(api.GetExposureAttr()), "inputs:exposure", path)
    power = intensity * 2.0**exposure if exposure < 1024 else math.inf
    if not math.isfinite(power):
        raise SceneError(f"intensity × 2^exposure = {intensity} × 2^{exposure} overflows", prim=path)
    color = finite_vec3(ctx.get(api.GetColorAttr()), "inputs:color", path)
    if np.any(color < 0.0):
        raise SceneError(f"inputs:color = {tuple(color)} has a negative channel", prim=path)
    if ctx.get(api.GetEnableColorTemperatureAttr()):
        ctx.warn("inputs:enableColorTemperature is on: colour temperature is not supported, "
                 "only inputs:color is used", path)

    M = ctx.to_world(prim)
    axis = M[:3, :3] @ np.array([0.0, 0.0, -1.0])
    norm = float(np.linalg.norm(axis))
    if not norm > 0.0:
        raise SceneError("the light's transform collapses its -Z axis (zero scale)", prim=path)
    light = Light(
        kind=kind,
        name=path,
        color=tuple(float(c) for c in color),
        intensity=float(power),
        direction=tuple(float(a) for a in axis / norm),
    )
    if kind == LightKind.DISTANT:
        return light

    light.position = tuple(float(x) for x in M[:3, 3])
    sphere = UsdLux.SphereLight(prim)
    radius_scale = float(np.max(np.linalg.norm(M[:3, :3], axis=0)))
    radius = finite_float(ctx.get(sphere.GetRadiusAttr()), "inputs:radius", path) * radius_scale
    if not ctx.get(sphere.GetTreatAsPointAttr()) and radius > POINT_RADIUS_M:
        ctx.warn(f"sphere light radius {radius:.4g} m is ignored: imported as a point light whose "
                 "intensity is in W/sr", path)
    cone_attr = prim.GetAttribute("inputs:shaping:cone:angle")
    if prim.HasAPI(UsdLux.ShapingAPI) or (cone_attr and cone_attr.HasAuthoredValue()):
        angle = finite_float(ctx.get(cone_attr), "inputs:shaping:cone:angle", path)
        if angle <= 0.0:
            raise SceneError(f"inputs:shaping:cone:angle = {angle} degrees: a spot cone must be wider than 0",
                             prim=path)
        if angle < 180.0:
            softness_attr = prim.GetAttribute("inputs:shaping:cone:softness")
            softness = finite_float(ctx.get(softness_attr) if softness_attr else 0.0,
                                    "inputs:shaping:cone:softness", path)
            light.kind = LightKind.SPOT
            light.cone_angle = math.radians(angle)
            light.cone_softness = min(max(softness, 0.0), 1.0)
        focus = prim.GetAttribute("inputs:shaping:focus")
        ies = prim.GetAttribute("inputs:shaping:ies:file")
        if (focus and focus.HasAuthoredValue() and ctx.get(focus)) or (ies and ies.HasAuthoredValue()):
            ctx.warn("inputs:shaping:focus and IES profiles are not supported: ignored", path)
    return light
