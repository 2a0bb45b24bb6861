"""Opening a USD stage safely and bringing its prims to the model's world frame (Y up, metres).

Shared by the reader's parts (``load``, ``mesh``, ``material``,
``lights``). Everything here raises :class:`SceneError`; nothing lets a ``pxr`` exception out.
"""

from __future__ import annotations

import math
import os
import re
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
_PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # cisp_warp/


def tf_reason(exc: BaseException) -> str:
    """The human part of a ``pxr.Tf.ErrorException`` (drops the C++ function, file and line)."""
    text = str(exc)
    quoted = re.findall(r":\s*'(.*?)'\s*(?:\n|$)", text, flags=re.S)
    reason = "; ".join(q.strip() for q in quoted if q.strip()) or text.strip() or type(exc).__name__
    return " ".join(reason.split())[:500]


def open_stage(path: str) -> Usd.Stage:
    """Open ``path`` as a USD stage, or raise :class:`SceneError` saying why it cannot be read."""
    if not os.path.exists(path):
        raise SceneError("file not found", file=path)
    if not os.path.isfile(path):
        raise SceneError("not a file (a directory?)", file=path)
    if os.path.getsize(path) == 0:
        raise SceneError("the file is empty: not a USD file", file=path)
    if not path.lower().endswith(_USD_SUFFIXES):
        raise SceneError(f"not a USD file: the name must end in one of {', '.join(_USD_SUFFIXES)}", file=path)
    try:
        stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise SceneError(f"not a readable USD file ({tf_reason(exc)})", file=path) from None
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
        if not (math.isfinite(mpu) and mpu > 0.0):
            raise SceneError(f"stage metersPerUnit must be a positive number, got {mpu}", file=path)
        up = str(UsdGeom.GetStageUpAxis(stage))
        if up not in ("Y", "Z"):
            raise SceneError(f"stage upAxis must be 'Y' or 'Z', got '{up}'", file=path)
        return StageContext(stage, path, time, mpu, up)

    def to_world(self, prim: Usd.Prim) -> np.ndarray:
        """4x4 local-to-world matrix of ``prim`` acting on column vectors, in Y-up metres (float64)."""
        local = np.array(self.xform_cache.GetLocalToWorldTransform(prim), dtype=np.float64).T
        if not np.all(np.isfinite(local)):
            raise SceneError("the transform (xformOp stack) contains NaN or Inf", prim=str(prim.GetPath()))
        return self.stage_to_world @ local

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


def finite_float(value, what: str, prim: str, lo: float | None = None, hi: float | None = None) -> float:
    """``value`` as a float, or :class:`SceneError` when it is missing, NaN/Inf or outside [lo, hi]."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise SceneError(f"{what} must be a number, got {value!r}", prim=prim) from None
    if not math.isfinite(x):
        raise SceneError(f"{what} is {x}: it must be finite", prim=prim)
    if (lo is not None and x < lo) or (hi is not None and x > hi):
        raise SceneError(f"{what} = {x} lies outside [{lo}, {hi}]", prim=prim)
    return x


def finite_vec3(value, what: str, prim: str) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise SceneError(f"{what} must be three finite numbers, got {value!r}", prim=prim)
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
