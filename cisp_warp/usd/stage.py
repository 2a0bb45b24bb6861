"""Opening a USD stage safely and bringing its prims to the model's world frame (Y up, metres).

Shared by the reader's parts (``load``, ``mesh``, ``material``,
``lights``). Everything here raises :class:`SceneError`; nothing lets a ``pxr`` exception out.
"""

from __future__ import annotations

import math
import os
import re
import reprlib
import sys
import warnings
from dataclasses import dataclass, field

import numpy as np
from pxr import Sdf, Tf, Usd, UsdGeom

from ..errors import SceneError, SceneWarning

# Z-up stages are turned -90 degrees about X so that +Z becomes +Y and +Y becomes -Z (right-handed kept).
_Z_UP_TO_Y_UP = np.array(
    [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)

_USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")

#: Everything the renderer draws lies within this distance of the origin [m]: float32 positions keep
#: millimetre precision there (ulp 0.06 m at 1e6 m is the coarsest a caustic footprint tolerates), and
#: squared distances stay far inside float32 range.
MAX_EXTENT_M = 1e6
MIN_METERS_PER_UNIT = 1e-6  #: stage metersPerUnit below this (micrometre units) is refused
MAX_METERS_PER_UNIT = 1e4  #: and above this (10 km units)
FLOAT32_MAX = float(np.finfo(np.float32).max)

#: What a typed read accepts: kind -> (C++ value types, words for the message).
_KINDS = {
    "real": ({"float", "double", "pxr_half::half"}, "a float, double or half"),
    "int": ({"int", "long", "unsigned int", "unsigned char", "long long", "unsigned long"}, "an int"),
    "bool": ({"bool"}, "a bool"),
    "token": ({"TfToken", "string"}, "a token or string"),
    "vec2": ({"GfVec2f", "GfVec2d", "GfVec2h"}, "a float2 or double2"),
    "int2": ({"GfVec2i"}, "an int2"),
    "vec3": ({"GfVec3f", "GfVec3d", "GfVec3h"}, "a float3, double3, color3f or similar"),
    "vec3[]": ({"VtArray<GfVec3f>", "VtArray<GfVec3d>", "VtArray<GfVec3h>"},
               "an array of 3-vectors (point3f[], normal3f[], color3f[], float3[])"),
    "int[]": ({"VtArray<int>"}, "an int[]"),
    "asset": ({"SdfAssetPath"}, "an asset path"),
}
_PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # cisp_warp/


def tf_reason(exc: BaseException) -> str:
    """The human part of a ``pxr.Tf.ErrorException`` (drops the C++ function, file and line)."""
    try:
        text = str(exc)
    except UnicodeDecodeError:  # USD quotes the file's bytes in its message, and they need not be UTF-8
        text = "USD's error text is not valid UTF-8 (the file holds bytes that are not text)"
    quoted = re.findall(r":\s*'(.*?)'\s*(?:\n|$)", text, flags=re.S)
    reason = "; ".join(q.strip() for q in quoted if q.strip()) or text.strip() or type(exc).__name__
    return " ".join(reason.split())[:500]


def open_stage(path: str) -> Usd.Stage:
    """Open ``path`` as a USD stage, or raise :class:`SceneError` saying why it cannot be read.

    Before USD composes anything, :func:`~cisp_warp.usd.guard.check_layers` parses the file and every
    layer it pulls in (sublayers, references, payloads) in a guarded step: each must be a regular file
    within the size caps, and a parse that hangs, crashes or exhausts memory ends in a SceneError.
    """
    from .guard import check_layers

    if not os.path.exists(path):
        raise SceneError("file not found", file=path)
    if not os.path.isfile(path):
        raise SceneError("not a regular file (a directory, FIFO or device?)", file=path)
    if os.path.getsize(path) == 0:
        raise SceneError("the file is empty: not a USD file", file=path)
    if not path.lower().endswith(_USD_SUFFIXES):
        raise SceneError(f"not a USD file: the name must end in one of {', '.join(_USD_SUFFIXES)}", file=path)
    check_layers(path)
    try:
        stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise SceneError(f"not a readable USD file ({tf_reason(exc)})", file=path) from None
    except UnicodeDecodeError:
        raise SceneError("not a readable USD file (USD's error text is not UTF-8: the file holds bytes that "
                         "are not text)", file=path) from None
    if stage is None:
        raise SceneError("USD could not open the file (not a USD file, truncated or unreadable)", file=path)
    return stage


@dataclass
class StageContext:
    """A stage read at one time code, with the map from its units and up axis to Y-up metres."""

    stage: Usd.Stage
    path: str
    time: Usd.TimeCode
    meters_per_unit: float = 0.01
    up_axis: str = "Y"
    on_cpu: bool = False  #: the frame is rendered on the CPU (limits what would take minutes there)
    xform_cache: UsdGeom.XformCache = field(init=False)
    stage_to_world: np.ndarray = field(init=False)  #: 4x4, column vectors: stage units and up axis -> Y-up metres

    def __post_init__(self):
        self.xform_cache = UsdGeom.XformCache(self.time)
        m = np.diag([self.meters_per_unit] * 3 + [1.0])
        self.stage_to_world = m @ _Z_UP_TO_Y_UP if self.up_axis == "Z" else m

    @staticmethod
    def from_stage(stage: Usd.Stage, path: str, time: Usd.TimeCode) -> "StageContext":
        if stage.HasAuthoredMetadata("metersPerUnit"):
            mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
        else:
            mpu = 0.01  # the USD spec's fallback: centimetres
        if not (math.isfinite(mpu) and MIN_METERS_PER_UNIT <= mpu <= MAX_METERS_PER_UNIT):
            raise SceneError(f"stage metadata metersPerUnit = {mpu}: it must be a number in "
                             f"[{MIN_METERS_PER_UNIT:g}, {MAX_METERS_PER_UNIT:g}] (1 = metres, 0.01 = centimetres)",
                             file=path, prim="/")
        up = str(UsdGeom.GetStageUpAxis(stage))
        if up not in ("Y", "Z"):
            raise SceneError(f"stage upAxis must be 'Y' or 'Z', got '{up}'", file=path)
        return StageContext(stage, path, time, mpu, up)

    def to_world(self, prim: Usd.Prim) -> np.ndarray:
        """4x4 local-to-world matrix of ``prim`` acting on column vectors, in Y-up metres (float64)."""
        try:
            local = np.array(self.xform_cache.GetLocalToWorldTransform(prim), dtype=np.float64).T
        except Tf.ErrorException as exc:
            raise SceneError(f"the transform (xformOp stack) cannot be evaluated: {tf_reason(exc)}",
                             prim=str(prim.GetPath())) from None
        if not np.all(np.isfinite(local)):
            raise SceneError("the transform (xformOp stack) contains NaN or Inf", prim=str(prim.GetPath()))
        world = self.stage_to_world @ local
        if not np.all(np.abs(world) <= MAX_EXTENT_M):
            raise SceneError(f"the transform (xformOp stack, with metersPerUnit {self.meters_per_unit:g}) has an "
                             f"entry of {np.abs(world).max():.3g}: translations must lie within {MAX_EXTENT_M:g} m "
                             f"of the origin and scales below {MAX_EXTENT_M:g}", prim=str(prim.GetPath()))
        return world

    def get(self, attr: Usd.Attribute):
        """``attr``'s value at this context's time (None when neither authored nor with a fallback)."""
        if not attr:
            return None
        return attr.Get(self.time)

    def warn(self, reason: str, prim: str | None = None) -> None:
        """Emit a :class:`SceneWarning` naming the file and ``prim``, attributed to the importer's caller."""
        where = f"file '{self.path}'" + (f", prim '{prim}'" if prim else "")
        frame, level = sys._getframe(0), 1
        while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE_DIR):
            frame, level = frame.f_back, level + 1
        warnings.warn(SceneWarning(f"{where}: {reason}"), stacklevel=level)


def typed_get(ctx: "StageContext", attr: Usd.Attribute, kind: str, prim: str | None = None):
    """``attr``'s value at ``ctx``'s time (None when it has none), or :class:`SceneError` when the attribute
    is authored with a type other than ``kind`` (a key of ``_KINDS``: "real", "int", "vec3[]" ...)."""
    if not attr:
        return None
    cpp_types, words = _KINDS[kind]
    type_name = attr.GetTypeName()
    value = ctx.get(attr) if type_name.type.typeName in cpp_types else _MISMATCH
    if value is not None and (value is _MISMATCH or not _VALUE_CHECKS[kind](value)):
        # the declared type, or (where a schema overrides it) the value USD hands back, is not of this kind
        shown = type_name if value is _MISMATCH else type(value).__name__
        raise SceneError(f"attribute '{attr.GetName()}' is authored as {shown or 'an unknown type'}; it must be "
                         f"{words}", prim=prim or str(attr.GetPrim().GetPath()))
    return value


_MISMATCH = object()
_VALUE_CHECKS = {
    "real": lambda v: isinstance(v, (float, int)) and not isinstance(v, bool),
    "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "bool": lambda v: isinstance(v, bool),
    "token": lambda v: isinstance(v, str),
    "vec2": lambda v: type(v).__name__ in ("Vec2f", "Vec2d", "Vec2h"),
    "int2": lambda v: type(v).__name__ == "Vec2i",
    "vec3": lambda v: type(v).__name__ in ("Vec3f", "Vec3d", "Vec3h"),
    "vec3[]": lambda v: type(v).__name__ in ("Vec3fArray", "Vec3dArray", "Vec3hArray"),
    "int[]": lambda v: type(v).__name__ == "IntArray",
    "asset": lambda v: type(v).__name__ == "AssetPath",
}


def finite_float(value, what: str, prim: str, lo: float | None = None, hi: float | None = None) -> float:
    """``value`` as a float, or :class:`SceneError` when it is missing, NaN/Inf or outside [lo, hi]."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise SceneError(f"{what} must be a number, got {reprlib.repr(value)}", prim=prim) from None
    if not math.isfinite(x):
        raise SceneError(f"{what} is {x}: it must be finite", prim=prim)
    if (lo is not None and x < lo) or (hi is not None and x > hi):
        raise SceneError(f"{what} = {x:g} lies outside [{'-inf' if lo is None else f'{lo:g}'}, "
                         f"{'inf' if hi is None else f'{hi:g}'}]", prim=prim)
    return x


def finite_vec3(value, what: str, prim: str, bound: float = FLOAT32_MAX) -> np.ndarray:
    """``value`` as three float64, or :class:`SceneError` unless they are finite and within ±``bound``."""
    try:
        v = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise SceneError(f"{what} must be three finite numbers, got {reprlib.repr(python_value(value))}", prim=prim)
    if np.any(np.abs(v) > bound):
        raise SceneError(f"{what} = {tuple(float(c) for c in v)} has a component beyond ±{bound:g}", prim=prim)
    return v


def python_value(value):
    """A ``pxr`` value (Gf vector, Vt array, token, asset path) as plain Python (tuple, list, str, float...)."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Sdf.AssetPath):
        return value.path
    name = type(value).__name__
    if name.endswith("Array"):
        return [python_value(v) for v in value]
    if name.startswith(("Vec", "Quat")):
        return tuple(float(v) for v in value)
    if name.startswith("Matrix"):
        return [list(map(float, row)) for row in np.array(value)]
    return str(value)
