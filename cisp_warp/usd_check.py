"""What the scene generators share: render settings authored the same way, export, and the checks a
written stage must pass (every registered ``UsdValidation`` validator; ``UsdUtils.ComplianceChecker``,
what ``usdchecker`` ran, where the installed usd-core still has it)."""

from __future__ import annotations

from pathlib import Path

from pxr import Gf, Sdf, Usd, UsdGeom, UsdRender, UsdShade, UsdValidation


def author_render_settings(stage: Usd.Stage, camera: UsdGeom.Camera, resolution: tuple[int, int]) -> None:
    """``/Render/Settings``: the image size and the camera, named by the stage's ``renderSettingsPrimPath``."""
    render = UsdGeom.Scope.Define(stage, "/Render")
    render.GetPrim().SetDocumentation("Render settings: image size and camera.")
    settings = UsdRender.Settings.Define(stage, "/Render/Settings")
    settings.GetPrim().SetDocumentation(f"{resolution[0]}x{resolution[1]} through {camera.GetPath()}.")
    settings.CreateResolutionAttr(Gf.Vec2i(*resolution))
    settings.CreateCameraRel().SetTargets([camera.GetPath()])
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")


def define_material(stage: Usd.Stage, name: str, doc: str, color, roughness: float = 1.0, opacity: float = 1.0,
                    ior: float = 1.5) -> UsdShade.Material:
    """``/World/Looks/<name>``: a non-metallic ``UsdPreviewSurface`` (what the importer reads)."""
    mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
    mat.GetPrim().SetDocumentation(doc)
    shader = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(float(roughness))
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(float(opacity))
    shader.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(float(ior))
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return mat


def export(layer: Sdf.Layer, out: Path) -> Usd.Stage:
    """Write ``layer`` to ``out`` (folders made as needed) and open what was written."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    layer.Export(str(out))
    return Usd.Stage.Open(str(out))


def validation_errors(stage: Usd.Stage) -> list[str]:
    """Every error that the registered ``UsdValidation`` validators report on ``stage``."""
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    errors = UsdValidation.ValidationContext(validators).Validate(stage)
    return [
        f"{e.GetName()}: {e.GetMessage()}" for e in errors
        if not e.HasNoError() and e.GetType() == UsdValidation.ValidationErrorType.Error
    ]


def compliance_checker_errors(path: Path) -> list[str] | None:
    """Errors and failed checks of ``UsdUtils.ComplianceChecker`` (``usdchecker``), or None where the installed
    usd-core no longer has it (removed in usd-core 26 in favour of ``UsdValidation``)."""
    try:
        from pxr.UsdUtils.complianceChecker import ComplianceChecker
    except ImportError:
        return None
    checker = ComplianceChecker(arkit=False, skipARKitRootLayerCheck=False, rootPackageOnly=False)
    checker.CheckCompliance(str(path))
    return list(checker.GetErrors()) + list(checker.GetFailedChecks())
