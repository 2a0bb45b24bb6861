"""UsdLux lights -> :class:`Light` (point, spot and directional), and a ``DomeLight`` -> :class:`Sky`.

* ``DistantLight``: ``Light.direction`` is the world direction the light travels (its local -Z).
* ``SphereLight``: a point light at its origin. ``treatAsPoint`` or a world radius of at most
  ``POINT_RADIUS_M`` is taken as is; a larger radius is ignored with a :class:`SceneWarning`.
  With ``ShapingAPI`` (or an authored ``inputs:shaping:cone:angle``) below 180 degrees it is a spot:
  ``cone_angle`` = that half angle [rad] off its -Z, ``cone_softness`` = ``inputs:shaping:cone:softness``.
* ``Light.intensity`` = ``inputs:intensity`` × 2^``inputs:exposure``, ``Light.color`` = ``inputs:color``,
  interpreted in the model's SI units (W/m² for distant, W/sr for point and spot): see
  :mod:`cisp_warp.usd`.
* ``DomeLight``: the sky (:func:`read_dome`): radiance [W/(m² sr)] = ``inputs:color`` × ``inputs:intensity``
  × 2^``inputs:exposure``, times the lat-long image ``inputs:texture:file`` when one is given (OpenEXR
  linear, or PNG/JPEG/TIFF decoded from sRGB); only ``inputs:texture:format`` latlong (or automatic) is read.
* Any other light type (Rect, Disk, Cylinder, Geometry, Portal, plugin) -> one warning, ignored.
"""

from __future__ import annotations

import math
import os

import numpy as np
from pxr import UsdLux

from ..errors import SceneError
from ..scene.model import Light, LightKind, Sky
from .stage import StageContext, finite_float, finite_vec3, typed_get

#: Largest intensity × 2^exposure × max(color) accepted [W/m² or W/sr]: 1e20 is 17 orders of magnitude above
#: sunlight (1.4e3 W/m²) and leaves float32 (3.4e38) room for the products the photon kernels form with it.
MAX_LIGHT_POWER = 1e20
MAX_EXPOSURE = 128.0  #: |inputs:exposure| [stops] above this is refused (2^128 is beyond float32)
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
            f"{prim.GetTypeName() or 'this'} light is not supported (only distant, sphere, spot and dome "
            "lights cast light here): ignored",
            path,
        )
        return None

    color, power = _color_power(ctx, prim, path)
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
    radius = finite_float(typed_get(ctx, sphere.GetRadiusAttr(), "real", path), "inputs:radius", path,
                          0.0) * radius_scale
    if not typed_get(ctx, sphere.GetTreatAsPointAttr(), "bool", path) and radius > POINT_RADIUS_M:
        ctx.warn(f"sphere light radius {radius:.4g} m is ignored: imported as a point light whose "
                 "intensity is in W/sr", path)
    cone_attr = prim.GetAttribute("inputs:shaping:cone:angle")
    if prim.HasAPI(UsdLux.ShapingAPI) or (cone_attr and cone_attr.HasAuthoredValue()):
        angle = finite_float(typed_get(ctx, cone_attr, "real", path), "inputs:shaping:cone:angle", path)
        if not 0.0 < angle <= 180.0:
            raise SceneError(f"inputs:shaping:cone:angle = {angle:g} degrees: a spot's half angle must lie in (0, 180] "
                             "(180: a point light)", prim=path)
        if angle < 180.0:
            softness_attr = prim.GetAttribute("inputs:shaping:cone:softness")
            softness = finite_float(typed_get(ctx, softness_attr, "real", path) if softness_attr else 0.0,
                                    "inputs:shaping:cone:softness", path)
            if not 0.0 <= softness <= 1.0:
                ctx.warn(f"inputs:shaping:cone:softness = {softness:g} lies outside [0, 1]: clamped", path)
            light.kind = LightKind.SPOT
            light.cone_angle = math.radians(angle)
            light.cone_softness = min(max(softness, 0.0), 1.0)
        focus = prim.GetAttribute("inputs:shaping:focus")
        ies = prim.GetAttribute("inputs:shaping:ies:file")
        if (focus and focus.HasAuthoredValue() and typed_get(ctx, focus, "real", path)) or (
            ies and ies.HasAuthoredValue()
        ):
            ctx.warn("inputs:shaping:focus and IES profiles are not supported: ignored", path)
    return light


def read_dome(ctx: StageContext, prim) -> Sky:
    """The :class:`Sky` of a ``DomeLight`` prim (see the module docstring)."""
    path = str(prim.GetPath())
    color, power = _color_power(ctx, prim, path)
    M = ctx.to_world(prim)[:3, :3]
    scale = np.linalg.norm(M, axis=0)
    if not np.all(scale > 0.0):
        raise SceneError("the dome light's transform has a zero scale", prim=path)
    rotation = M / scale  # the dome's orientation; its scale means nothing for an infinitely distant sphere
    dome = UsdLux.DomeLight(prim)
    texture = None
    asset = typed_get(ctx, dome.GetTextureFileAttr(), "asset", path)
    if asset is not None and asset.path:
        fmt = str(typed_get(ctx, dome.GetTextureFormatAttr(), "token", path) or "automatic")
        if fmt not in ("automatic", "latlong"):
            raise SceneError(f"inputs:texture:format = '{fmt}': only latlong sky images are supported", prim=path)
        file = asset.resolvedPath or asset.path
        if not os.path.isabs(file):
            file = os.path.join(os.path.dirname(os.path.abspath(ctx.path)), file)
        texture = read_latlong(file, path)
    return Sky(name=path, radiance=tuple(float(c * power) for c in color), texture=texture, to_world=rotation)


def read_latlong(file: str, prim: str) -> np.ndarray:
    """A lat-long sky image as (H, W, 3) float32 linear RGB: OpenEXR as stored, 8/16-bit images from sRGB."""
    where = "inputs:texture:file"
    if not os.path.exists(file):
        raise SceneError(f"{where}: the sky image '{file}' does not exist", prim=prim)
    if not os.path.isfile(file):
        raise SceneError(f"{where}: the sky image '{file}' is not a regular file (a directory, FIFO or device)",
                         prim=prim)
    try:
        if file.lower().endswith(".exr"):
            from ..image_io import read_exr

            rgb = np.asarray(read_exr(file), dtype=np.float32)
            if rgb.ndim == 2:
                rgb = np.repeat(rgb[..., None], 3, axis=-1)
        else:
            from PIL import Image

            with Image.open(file) as im:
                a = np.asarray(im.convert("RGB") if im.mode not in ("I;16", "RGB") else im)
            scale = 65535.0 if a.dtype == np.uint16 else 255.0
            c = a.astype(np.float64) / scale
            if c.ndim == 2:
                c = np.repeat(c[..., None], 3, axis=-1)
            rgb = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)
    except (OSError, ValueError, RuntimeError) as exc:
        raise SceneError(f"{where}: cannot read the sky image '{file}' ({exc})", prim=prim) from None
    rgb = rgb[..., :3]
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] < 1 or rgb.shape[1] < 1:
        raise SceneError(f"{where}: the sky image '{file}' is not an RGB image", prim=prim)
    if not np.all(np.isfinite(rgb)) or np.any(rgb < 0.0):
        raise SceneError(f"{where}: the sky image '{file}' has negative, NaN or Inf pixels", prim=prim)
    return rgb


def _color_power(ctx: StageContext, prim, path: str):
    """(inputs:color, inputs:intensity × 2^inputs:exposure) of any UsdLux light, checked: types, signs, and
    intensity × 2^exposure × max(color) at most ``MAX_LIGHT_POWER``."""
    api = UsdLux.LightAPI(prim)
    intensity = finite_float(typed_get(ctx, api.GetIntensityAttr(), "real", path), "inputs:intensity", path)
    if intensity < 0.0:
        raise SceneError(f"inputs:intensity = {intensity}: a light's intensity must not be negative", prim=path)
    exposure = finite_float(typed_get(ctx, api.GetExposureAttr(), "real", path), "inputs:exposure", path,
                            -MAX_EXPOSURE, MAX_EXPOSURE)
    power = intensity * 2.0**exposure
    color = finite_vec3(typed_get(ctx, api.GetColorAttr(), "vec3", path), "inputs:color", path)
    if np.any(color < 0.0):
        raise SceneError(f"inputs:color = {tuple(color)} has a negative channel", prim=path)
    if power * float(color.max()) > MAX_LIGHT_POWER:
        unit = ("W/m²" if prim.IsA(UsdLux.DistantLight) else "W/(m² sr)" if prim.IsA(UsdLux.DomeLight)
                else "W/sr")
        raise SceneError(f"inputs:intensity × 2^exposure × color = {intensity:g} × 2^{exposure:g} × {color.max():g} = "
                         f"{power * float(color.max()):.3g} {unit}, above {MAX_LIGHT_POWER:g}: the photon powers would "
                         "overflow float32", prim=path)
    if typed_get(ctx, api.GetEnableColorTemperatureAttr(), "bool", path):
        ctx.warn("inputs:enableColorTemperature is on: colour temperature is not supported, "
                 "only inputs:color is used", path)
    return color, power
