"""USD stage -> :class:`~cisp_warp.scene.Scene` (Y up, metres, SI light units), or a clear :class:`SceneError`.

``load_usd(path, time_code=None, width=None, height=None, camera_path=None, device=None)``

Frame and time
    Stage units are scaled by ``metersPerUnit`` (0.01, the USD fallback, when not authored). A Z-up
    stage is rotated -90 degrees about X (+Z -> +Y, +Y -> -Z). The stage is read at ``time_code``;
    by default at its ``startTimeCode`` when authored, else at ``Usd.TimeCode.EarliestTime()`` (same as
    ``Default()`` for attributes without samples, and the first sample for attributes that only have
    samples, where ``Default()`` would read nothing); ``Scene.time_code`` is then 0.
    ``Scene.time`` = time code / ``timeCodesPerSecond`` [s].

What is imported
    ``UsdGeom.Mesh`` prims (see :mod:`cisp_warp.usd.mesh`) with materials
    (:mod:`cisp_warp.usd.material`), UsdLux lights (:mod:`cisp_warp.usd.lights`), one
    ``UsdGeom.Camera`` and a ``UsdRender.Settings`` resolution. Prims that are invisible
    (``ComputeVisibility``) or of purpose ``guide`` / ``proxy`` are skipped (``default`` and ``render``
    are drawn); instance proxies are traversed. Other gprims (Sphere, Cube, Points, curves) and point
    instancers are skipped with a :class:`SceneWarning`.

Light units (deliberately not UsdLux's)
    ``Light.intensity`` = ``inputs:intensity`` × 2^``inputs:exposure``, per unit of ``inputs:color``:

    * DistantLight: the irradiance [W/m²] on a surface facing the light.
    * SphereLight (point) and SphereLight + ShapingAPI (spot): the radiant intensity [W/sr] along the
      axis. UsdLux defines a sphere light's intensity as *radiance* of its surface, so its brightness
      grows with the radius; here the radius is ignored and the number is W/sr, so a scene's brightness
      does not depend on a radius the renderer cannot use anyway.

Camera
    ``camera_path``, else the ``UsdRender.Settings`` camera, else the first camera in traversal order.
    ``focalLength`` and apertures share one unit (tenths of a scene unit), so
    fov_y = 2·atan(aperture_v / 2 / focalLength) is unit-free. The aperture is first conformed to the
    image aspect by the settings' ``aspectRatioConformPolicy`` (default ``expandAperture``, as in
    UsdRender): when aperture and image have the same aspect, aperture_v is the authored
    ``verticalAperture``. Orthographic: ``ortho_height`` = aperture_v / 10 × metersPerUnit.
    ``clippingRange`` [scene units] -> near/far [m]. ``Camera.to_world`` is the world transform with
    scale and shear removed (forward and up kept). Resolution: ``width``/``height``, else the
    settings' ``resolution``, else 640×360; when only one of width/height is given the other follows
    that aspect ratio.

Errors
    Anything unusable raises :class:`SceneError` whose message names the file, the prim, the attribute
    and what was expected; USD's own errors (``pxr.Tf.ErrorException``) are re-raised as
    :class:`SceneError`. What is ignored or clamped is a :class:`SceneWarning` naming the same. Every
    attribute is checked where it is read (:func:`~cisp_warp.usd.stage.typed_get`: its type, then element
    counts and ranges): positions within ``MAX_EXTENT_M`` of the origin, light power within float32
    headroom (``lights.MAX_LIGHT_POWER``), ``cisp:water`` parameters within ``sim.params``' bounds and their
    rest grid regular (:mod:`cisp_warp.usd.water`), image edges at most ``MAX_EDGE``. Before USD composes
    the stage, :mod:`cisp_warp.usd.guard` checks every layer it would read (regular files, size caps) and
    parses them in a guarded step (deadline, memory cap). A resolution is checked against device memory
    (``GBUFFER_BYTES_PER_PIXEL``) before anything is allocated.
"""

from __future__ import annotations

import math
import os

import numpy as np
from pxr import Tf, Usd, UsdGeom, UsdLux, UsdRender

from ..errors import SceneError
from ..scene.device import check_memory
from ..scene.model import Camera, MeshRange, Scene
from .lights import read_dome, read_light
from .material import MaterialTable
from .mesh import MeshPart, read_mesh
from .stage import MAX_EXTENT_M, StageContext, finite_float, open_stage, tf_reason, typed_get

DEFAULT_RESOLUTION = (640, 360)
CONFORM_POLICIES = ("expandAperture", "cropAperture", "adjustApertureWidth", "adjustApertureHeight",
                    "adjustPixelAspectRatio")
GBUFFER_BYTES_PER_PIXEL = 64  #: G-buffer + photon map + denoiser history, an upper estimate per camera pixel
MAX_PIXELS = 2**31 - 1  #: Warp indexes arrays with 32-bit ints
MAX_EDGE = 65536  #: widest or tallest image [pixels] (16K video is 15360)
MAX_OPTICS = 1e6  #: focalLength and apertures [tenths of a scene unit] above this are refused
MIN_APERTURE_RATIO = 1e-3  #: apertures thinner than 1:1000 are refused
MAX_CLIP_RATIO = 1e9  #: clippingRange far / near above this is warned about
MAX_FAR_M = 1e7  #: a farther clippingRange far [m] is clamped to this, with a warning (float32 depths)

__all__ = ["load_usd", "GBUFFER_BYTES_PER_PIXEL"]


def load_usd(path, time_code=None, width=None, height=None, camera_path=None, device=None) -> Scene:
    """Read the USD file ``path`` into a validated :class:`Scene` (see the module docstring).

    ``time_code``: stage time code to read (default: ``startTimeCode``); ``width``/``height``: image
    size in pixels (default: the ``UsdRender.Settings`` resolution, else 640×360); ``camera_path``:
    prim path of the camera; ``device``: Warp device the frame will be rendered on, for the memory
    check (default: Warp's default device).
    """
    path = os.fspath(path)
    try:
        return _load(path, time_code, width, height, camera_path, device)
    except SceneError as exc:
        if not exc.file:
            raise SceneError(exc.reason, file=path, prim=exc.prim) from None
        if os.path.abspath(exc.file) != os.path.abspath(path):  # a layer the stage pulls in
            raise SceneError(f"{exc.reason} (in a layer of '{path}')", file=exc.file, prim=exc.prim) from None
        raise
    except Tf.ErrorException as exc:
        raise SceneError(f"USD error: {tf_reason(exc)}", file=path) from None


def _load(path, time_code, width, height, camera_path, device) -> Scene:
    stage = open_stage(path)
    tcps = finite_float(stage.GetTimeCodesPerSecond(), "timeCodesPerSecond", "/")
    if tcps <= 0.0:
        raise SceneError(f"timeCodesPerSecond must be positive, got {tcps}", prim="/")
    if time_code is not None:
        code = finite_float(time_code, "time_code", "time_code")
        time = Usd.TimeCode(code)
    elif stage.HasAuthoredMetadata("startTimeCode"):
        code = finite_float(stage.GetStartTimeCode(), "startTimeCode", "/")
        time = Usd.TimeCode(code)
    else:
        code, time = 0.0, Usd.TimeCode.EarliestTime()
    ctx = StageContext.from_stage(stage, path, time)
    ctx.on_cpu = _is_cpu(device)
    for err in stage.GetCompositionErrors():  # e.g. a missing referenced file: its prims are absent
        ctx.warn(f"composition error, the scene may be incomplete: {err}")
    table = MaterialTable(ctx)

    parts: list[MeshPart] = []
    skipped: list[tuple[str, str]] = []
    lights, unsupported_lights, cameras, settings = [], [], [], []
    sky = None
    it = iter(Usd.PrimRange(stage.GetPseudoRoot(), Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
    for prim in it:
        if prim.IsA(UsdGeom.Camera):
            cameras.append(prim)
            continue
        if prim.IsA(UsdRender.Settings):
            settings.append(prim)
            continue
        is_light = prim.HasAPI(UsdLux.LightAPI)
        is_mesh = prim.IsA(UsdGeom.Mesh)
        if not (is_light or prim.IsA(UsdGeom.Gprim) or prim.IsA(UsdGeom.PointInstancer)):
            continue
        img = UsdGeom.Imageable(prim)
        if img.ComputeVisibility(time) == UsdGeom.Tokens.invisible or img.ComputePurpose() in (
            UsdGeom.Tokens.guide,
            UsdGeom.Tokens.proxy,
        ):
            it.PruneChildren()
            continue
        pp = str(prim.GetPath())
        if is_mesh:
            if is_light:
                ctx.warn("mesh lights (MeshLightAPI) are not supported: its emission is ignored", pp)
            part, reason = read_mesh(ctx, UsdGeom.Mesh(prim), table)
            if part is None:
                ctx.warn(f"mesh skipped: {reason}", pp)
                skipped.append((pp, reason))
            else:
                parts.append(part)
        elif is_light and prim.IsA(UsdLux.DomeLight):
            if sky is None:
                sky = read_dome(ctx, prim)
            else:
                ctx.warn(f"a second DomeLight is ignored: the sky is '{sky.name}'", pp)
        elif is_light:
            light = read_light(ctx, prim)
            (lights if light is not None else unsupported_lights).append(light or pp)
        else:
            ctx.warn(f"{prim.GetTypeName()} is not imported (only UsdGeom.Mesh): skipped", pp)
            it.PruneChildren()

    if not parts:
        detail = "; ".join(f"'{p}': {r}" for p, r in skipped)
        raise SceneError(
            "the stage has no renderable triangles" + (f" (skipped {detail})" if detail else " (no UsdGeom.Mesh)"),
            prim=skipped[0][0] if skipped else None,
        )
    if not lights and sky is None:
        if unsupported_lights:
            raise SceneError(
                "no usable light: only unsupported light types (" + ", ".join(unsupported_lights)
                + "); add a DistantLight, SphereLight or a SphereLight with ShapingAPI (spot)",
                prim=unsupported_lights[0],
            )
        raise SceneError("the stage has no light: add a DistantLight, SphereLight, a SphereLight with "
                         "ShapingAPI (spot) or a DomeLight")

    rs = _render_settings(stage, settings)
    cam_prim = _pick_camera(stage, cameras, camera_path, rs)
    w, h, where = _resolution(ctx, rs, width, height)
    try:
        check_memory(w * h * GBUFFER_BYTES_PER_PIXEL, f"a {w}x{h} G-buffer", device)
    except SceneError as exc:
        raise SceneError(exc.reason, prim=where) from None
    if w * h > MAX_PIXELS:
        raise SceneError(f"resolution {w}x{h} has more than 2^31 pixels, beyond 32-bit indexing", prim=where)
    policy = str(typed_get(ctx, rs.GetAspectRatioConformPolicyAttr(), "token")) if rs else "expandAperture"
    if policy not in CONFORM_POLICIES:
        raise SceneError(f"aspectRatioConformPolicy = '{policy}': it must be one of {', '.join(CONFORM_POLICIES)}",
                         prim=str(rs.GetPath()))
    camera = read_camera(ctx, cam_prim, w, h, policy)

    scene = _assemble(parts, table, lights, camera, path, code, tcps)
    scene.sky = sky
    scene.validate()
    return scene


def _is_cpu(device) -> bool:
    """Whether the frame will be rendered on the CPU (``device`` None: Warp's default device)."""
    import warp as wp

    try:
        return wp.get_device(device).is_cpu
    except (RuntimeError, ValueError):
        raise SceneError(f"unknown device '{device}': use cpu or cuda:N", prim="device") from None


def _render_settings(stage, found):
    rs = UsdRender.Settings.GetStageRenderSettings(stage)
    if rs:
        return rs
    return UsdRender.Settings(found[0]) if found else None


def _pick_camera(stage, cameras, camera_path, rs):
    if camera_path is not None:
        try:
            prim = stage.GetPrimAtPath(str(camera_path))
        except Tf.ErrorException:
            prim = None
        if not prim or not prim.IsA(UsdGeom.Camera):
            raise SceneError("no UsdGeom.Camera at this path (camera_path)", prim=str(camera_path))
        if not prim.IsActive():
            raise SceneError("this camera is inactive (active = false) (camera_path)", prim=str(camera_path))
        return prim
    if rs:
        targets = rs.GetCameraRel().GetForwardedTargets()
        if targets:
            prim = stage.GetPrimAtPath(targets[0])
            if not prim or not prim.IsA(UsdGeom.Camera):
                raise SceneError(f"the render settings' camera '{targets[0]}' is not a UsdGeom.Camera",
                                 prim=str(rs.GetPath()))
            if not prim.IsActive():
                raise SceneError(f"the render settings' camera '{targets[0]}' is inactive (active = false)",
                                 prim=str(rs.GetPath()))
            return prim
    if not cameras:
        raise SceneError("the stage has no camera: add a UsdGeom.Camera (or pass camera_path)")
    return cameras[0]


def _resolution(ctx, rs, width, height) -> tuple[int, int, str]:
    """(width, height, where it came from) with the precedence of the module docstring."""
    where = "width/height"
    base = DEFAULT_RESOLUTION
    if rs:
        res = typed_get(ctx, rs.GetResolutionAttr(), "int2")
        if res is not None:
            base = (int(res[0]), int(res[1]))
            where = str(rs.GetPath())
            if not (0 < base[0] <= MAX_EDGE and 0 < base[1] <= MAX_EDGE):
                raise SceneError(f"resolution = {base[0]}x{base[1]}: each edge must be a whole number of pixels in "
                                 f"[1, {MAX_EDGE}]", prim=where)
    if width is None and height is None:
        w, h = base
    else:
        where = "width/height"
        for v, name in ((width, "width"), (height, "height")):
            if v is not None and (isinstance(v, bool) or not float(v).is_integer()):
                raise SceneError(f"{name} must be a whole number of pixels, got {v!r}", prim=name)
        if base[0] <= 0 or base[1] <= 0:
            base = DEFAULT_RESOLUTION
        w = int(width) if width is not None else int(round(int(height) * base[0] / base[1]))
        h = int(height) if height is not None else int(round(int(width) * base[1] / base[0]))
    if w <= 0 or h <= 0:
        raise SceneError(f"resolution must be positive, got {w}x{h}", prim=where)
    if w > MAX_EDGE or h > MAX_EDGE:
        raise SceneError(f"resolution {w}x{h}: each edge must be at most {MAX_EDGE} pixels", prim=where)
    return w, h, where


def _conform_vertical_aperture(ha: float, va: float, aspect: float, policy: str) -> float:
    """Vertical aperture after conforming (ha, va) to the image ``aspect`` (UsdRender policies)."""
    wider = aspect > ha / va  # the image is wider than the aperture
    if policy == "adjustApertureHeight" or (policy == "expandAperture" and not wider) or (
        policy == "cropAperture" and wider
    ):
        return ha / aspect
    return va  # adjustApertureWidth, adjustPixelAspectRatio, or expand/crop keeping the height


def _orthonormal(m: np.ndarray, prim: str) -> np.ndarray:
    """``m`` with its rotation part made orthonormal: forward (-Z) and up (+Y) kept, scale removed."""
    z, y = m[:3, 2], m[:3, 1]
    nz = np.linalg.norm(z)
    y = y - np.dot(y, z) / (nz * nz) * z if nz > 0.0 else y
    ny = np.linalg.norm(y)
    if not (nz > 0.0 and ny > 0.0):
        raise SceneError("the camera transform is singular (zero scale)", prim=prim)
    z, y = z / nz, y / ny
    out = np.eye(4)
    out[:3, 0], out[:3, 1], out[:3, 2], out[:3, 3] = np.cross(y, z), y, z, m[:3, 3]
    return out


def read_camera(ctx: StageContext, prim, width: int, height: int, policy: str = "expandAperture") -> Camera:
    """The :class:`Camera` of a ``UsdGeom.Camera`` prim at ``width`` × ``height`` pixels."""
    path = str(prim.GetPath())
    cam = UsdGeom.Camera(prim)
    focal = finite_float(typed_get(ctx, cam.GetFocalLengthAttr(), "real"), "focalLength", path)
    ha = finite_float(typed_get(ctx, cam.GetHorizontalApertureAttr(), "real"), "horizontalAperture", path)
    va = finite_float(typed_get(ctx, cam.GetVerticalApertureAttr(), "real"), "verticalAperture", path)
    for value, name in ((focal, "focalLength"), (ha, "horizontalAperture"), (va, "verticalAperture")):
        if not 0.0 < value <= MAX_OPTICS:
            raise SceneError(f"{name} = {value:g}: it must be positive and at most {MAX_OPTICS:g}", prim=path)
    if not MIN_APERTURE_RATIO <= ha / va <= 1.0 / MIN_APERTURE_RATIO:
        raise SceneError(f"horizontalAperture / verticalAperture = {ha:g} / {va:g}: an aspect beyond "
                         f"1:{1 / MIN_APERTURE_RATIO:g}", prim=path)
    clip = typed_get(ctx, cam.GetClippingRangeAttr(), "vec2")
    if clip is None:
        raise SceneError("attribute 'clippingRange' has no value", prim=path)
    near = finite_float(clip[0], "clippingRange near", path)
    far = finite_float(clip[1], "clippingRange far", path)
    if not 0.0 < near < far:
        raise SceneError(f"clippingRange ({near:g}, {far:g}) must satisfy 0 < near < far", prim=path)
    mpu = ctx.meters_per_unit
    if far * mpu > MAX_FAR_M:
        ctx.warn(f"clippingRange far = {far * mpu:.3g} m is clamped to {MAX_FAR_M:g} m", path)
        far = MAX_FAR_M / mpu
        if not near < far:
            raise SceneError(f"clippingRange near = {near * mpu:.3g} m lies beyond {MAX_FAR_M:g} m", prim=path)
    if far / near > MAX_CLIP_RATIO:
        ctx.warn(f"clippingRange far / near = {far / near:.3g}: depth precision is lost beyond a ratio of "
                 f"{MAX_CLIP_RATIO:g}", path)
    if policy == "adjustPixelAspectRatio":
        ctx.warn("aspectRatioConformPolicy adjustPixelAspectRatio is not supported (square pixels only): "
                 "the vertical aperture is kept", path)
    va_image = _conform_vertical_aperture(ha, va, width / height, policy)
    camera = Camera(
        to_world=_orthonormal(ctx.to_world(prim), path),
        near=near * mpu,
        far=far * mpu,
        width=int(width),
        height=int(height),
    )
    projection = str(typed_get(ctx, cam.GetProjectionAttr(), "token"))
    if projection not in (UsdGeom.Tokens.perspective, UsdGeom.Tokens.orthographic):
        raise SceneError(f"projection = '{projection}': it must be perspective or orthographic", prim=path)
    if projection == UsdGeom.Tokens.orthographic:
        camera.orthographic = True
        camera.ortho_height = va_image / 10.0 * mpu
    else:
        camera.fov_y = 2.0 * math.atan(va_image / 2.0 / focal)
    camera.validate(where=path)
    return camera


def _assemble(parts, table, lights, camera, path, code, tcps) -> Scene:
    meshes, v0, t0 = [], 0, 0
    for p in parts:
        meshes.append(MeshRange(p.path, v0, len(p.points), t0, len(p.indices), p.dynamic, p.water))
        v0 += len(p.points)
        t0 += len(p.indices)
    return Scene(
        points=np.concatenate([p.points for p in parts]).astype(np.float32),
        normals=np.concatenate([p.normals for p in parts]).astype(np.float32),
        indices=np.concatenate([p.indices + r.vertex_start for p, r in zip(parts, meshes)]).astype(np.int32),
        triangle_material=np.concatenate([p.triangle_material for p in parts]).astype(np.int32),
        materials=list(table.materials),
        lights=lights,
        camera=camera,
        meshes=meshes,
        time=float(code) / tcps,
        time_code=float(code),
        source=path,
    )
