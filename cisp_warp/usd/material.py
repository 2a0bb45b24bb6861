"""Materials from USD: ``UsdPreviewSurface`` through material binding, else ``primvars:displayColor``.

* A bound material (``UsdShade.MaterialBindingAPI.ComputeBoundMaterial``, all-purpose binding; per-face
  ``GeomSubset`` bindings of family ``materialBind`` too) whose universal surface shader is a
  ``UsdPreviewSurface`` gives ``Material(name=<material prim path>, albedo=diffuseColor, roughness,
  metallic, opacity, ior)``. Unauthored inputs take the UsdPreviewSurface defaults (0.18 grey, 0.5,
  0, 1, 1.5). An input connected to a texture or shading graph is not evaluated: one
  :class:`SceneWarning` names the material and the source, and the value authored on the input itself
  (else the UsdPreviewSurface default) is used.
* Faces with no bound material take their colour from ``primvars:displayColor`` (any interpolation).
  Albedo is per triangle, through the material index, so each *distinct* colour becomes one material:
  a triangle's colour (the mean of its corners' for vertex or face-varying colour) is quantised to
  8 bits per channel and named ``displayColor#rrggbb``, roughness 0.5, metallic 0, opaque, IOR 1.5.
  Materials of the same quantised colour are shared by every mesh of the stage.
* Faces with neither get ``Material()`` (the model's default grey), named ``default``.
"""

from __future__ import annotations

import numpy as np
from pxr import UsdShade

from ..errors import SceneError
from ..scene.model import Material
from .stage import StageContext, finite_float, finite_vec3, typed_get

PREVIEW_SURFACE_DEFAULTS = {
    "diffuseColor": (0.18, 0.18, 0.18),
    "roughness": 0.5,
    "metallic": 0.0,
    "opacity": 1.0,
    "ior": 1.5,
}
MIN_IOR = 1.0  #: smallest index of refraction accepted (of the material relative to the air around it)
MAX_IOR = 10.0  #: largest (the highest of natural materials is about 4)
DISPLAY_COLOR_LEVELS = 255  #: displayColor is quantised to 8 bits per channel before it becomes a material


class MaterialTable:
    """The scene's material list, built while meshes are read; each distinct source gets one entry."""

    def __init__(self, ctx: StageContext):
        self.ctx = ctx
        self.materials: list[Material] = []
        self._index: dict[str, int] = {}

    def _add(self, key: str, make) -> int:
        if key not in self._index:
            self._index[key] = len(self.materials)
            self.materials.append(make())
        return self._index[key]

    def default(self) -> int:
        return self._add("default", Material)

    def bound(self, material: UsdShade.Material) -> int:
        """Index of the material made from the ``UsdPreviewSurface`` of ``material``."""
        path = str(material.GetPath())
        return self._add(path, lambda: read_preview_surface(self.ctx, material))

    def display_colors(self, rgb: np.ndarray) -> np.ndarray:
        """Material index per row of ``rgb`` (N, 3): one material per distinct quantised colour."""
        q = np.rint(np.clip(rgb, 0.0, 1.0) * DISPLAY_COLOR_LEVELS).astype(np.int64)
        unique, inverse = np.unique(q, axis=0, return_inverse=True)
        ids = np.empty(len(unique), dtype=np.int32)
        for k, c in enumerate(unique):
            name = "displayColor#" + "".join(f"{int(v):02x}" for v in c)
            albedo = tuple(float(v) / DISPLAY_COLOR_LEVELS for v in c)
            ids[k] = self._add(name, lambda n=name, a=albedo: Material(name=n, albedo=a, roughness=0.5))
        return ids[inverse.reshape(-1)]


def _input_value(ctx: StageContext, shader: UsdShade.Shader, name: str, material_path: str):
    """Value of ``inputs:<name>`` following interface connections; texture connections -> warning."""
    default = PREVIEW_SURFACE_DEFAULTS[name]
    inp = shader.GetInput(name)
    if not inp:
        return default
    for attr in inp.GetValueProducingAttributes():
        if UsdShade.Utils.GetType(attr.GetName()) == UsdShade.AttributeType.Output:
            own = typed_get(ctx, inp.GetAttr(), "vec3" if name == "diffuseColor" else "real", material_path)
            value = default if own is None else own
            ctx.warn(
                f"inputs:{name} of shader '{shader.GetPath()}' is connected to '{attr.GetPath()}' (a texture "
                f"or shading graph), which is not evaluated: using the constant {tuple(np.ravel(value))}",
                material_path,
            )
            return value
        kind = "vec3" if name == "diffuseColor" else "real"
        value = typed_get(ctx, attr, kind, material_path)
        if value is not None:
            return value
    return default


def _unit_interval(ctx: StageContext, x: float, what: str, prim: str) -> float:
    if 0.0 <= x <= 1.0:
        return x
    ctx.warn(f"{what} = {x} lies outside [0, 1]: clamped", prim)
    return min(max(x, 0.0), 1.0)


def read_preview_surface(ctx: StageContext, material: UsdShade.Material) -> Material:
    path = str(material.GetPath())
    shader, _, _ = material.ComputeSurfaceSource()
    if not shader or shader.GetShaderId() != "UsdPreviewSurface":
        what = f"shader id '{shader.GetShaderId()}'" if shader else "no universal surface output"
        ctx.warn(f"material has {what}, not a UsdPreviewSurface: using UsdPreviewSurface defaults", path)
        d = PREVIEW_SURFACE_DEFAULTS
        return Material(path, d["diffuseColor"], d["roughness"], d["metallic"], d["opacity"], d["ior"])
    sp = str(shader.GetPath())
    albedo = finite_vec3(_input_value(ctx, shader, "diffuseColor", path), "inputs:diffuseColor", sp)
    if np.any(albedo < 0.0) or np.any(albedo > 1.0):
        ctx.warn(f"inputs:diffuseColor = {tuple(albedo)} lies outside [0, 1]: clamped", sp)
        albedo = np.clip(albedo, 0.0, 1.0)
    scalars = {}
    for name in ("roughness", "metallic", "opacity"):
        x = finite_float(_input_value(ctx, shader, name, path), f"inputs:{name}", sp)
        scalars[name] = _unit_interval(ctx, x, f"inputs:{name}", sp)
    ior = finite_float(_input_value(ctx, shader, "ior", path), "inputs:ior", sp)
    if not MIN_IOR <= ior <= MAX_IOR:
        raise SceneError(f"inputs:ior = {ior:g}: an index of refraction must be positive and lie in "
                         f"[{MIN_IOR:g}, {MAX_IOR:g}] (water 1.33, glass 1.5, diamond 2.42)", prim=sp)
    return Material(
        name=path,
        albedo=tuple(float(v) for v in albedo),
        roughness=scalars["roughness"],
        metallic=scalars["metallic"],
        opacity=scalars["opacity"],
        ior=ior,
    )


def face_materials(ctx: StageContext, prim, face_count: int, table: MaterialTable) -> np.ndarray:
    """Material index per face (F,) int32 from bindings (subsets first); -1 where nothing is bound."""
    face_mat = np.full(face_count, -1, dtype=np.int32)
    binding = UsdShade.MaterialBindingAPI(prim)
    whole, _ = binding.ComputeBoundMaterial()
    if whole:
        face_mat[:] = table.bound(whole)
    else:
        _warn_unresolved_binding(ctx, prim)
    for subset in binding.GetMaterialBindSubsets():
        mat, _ = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()
        sp = str(subset.GetPath())
        if not mat:
            _warn_unresolved_binding(ctx, subset.GetPrim())
            continue
        element = str(typed_get(ctx, subset.GetElementTypeAttr(), "token", sp))
        if element != "face":
            ctx.warn(f"GeomSubset elementType = '{element}': only face subsets bind materials; ignored", sp)
            continue
        faces = np.asarray(typed_get(ctx, subset.GetIndicesAttr(), "int[]", sp) or [], dtype=np.int64)
        bad = (faces < 0) | (faces >= face_count)
        if np.any(bad):
            raise SceneError(
                f"GeomSubset face index {int(faces[bad][0])} is out of range: the mesh has {face_count} faces",
                prim=str(subset.GetPath()),
            )
        face_mat[faces] = table.bound(mat)
    return face_mat


def _warn_unresolved_binding(ctx: StageContext, prim) -> None:
    """A ``material:binding`` that targets no ``UsdShade.Material`` is ignored, with a warning naming it."""
    rel = prim.GetRelationship("material:binding")
    if not rel:
        return
    targets = rel.GetTargets()
    for target in targets:
        found = prim.GetStage().GetPrimAtPath(target)
        if not (found and found.IsA(UsdShade.Material) and found.IsActive()):
            what = "no prim" if not found else ("an inactive prim" if not found.IsActive() else
                                                 f"a {found.GetTypeName() or 'typeless prim'}, not a Material")
            ctx.warn(f"material:binding targets '{target}', which is {what}: ignored (displayColor or the default "
                     "grey is used)", str(prim.GetPath()))
            return


__all__ = ["MaterialTable", "PREVIEW_SURFACE_DEFAULTS", "face_materials", "read_preview_surface"]
