"""Write the malformed-USD corpus that ``tests/test_malformed.py`` loads, and its ``expected.json``.

Every file here is one way a scene can be broken. ``expected.json`` maps each file name to the prim
path the error message must name (or null when the problem is the whole file) and a keyword the
reason must contain; ``"outcome": "warning"`` marks a file that loads, with a :class:`SceneWarning`
naming the file, that prim and that keyword (something ignored or clamped), else loading it must raise
:class:`SceneError`. The files after "issue 16" are one minimal file per failure family that
``tools/fuzz_usd.py`` found (tracebacks, NaN renders, hangs, errors without a file, silent nonsense). Run ``python tests/malformed/make_corpus.py`` after changing a case and commit
the files it writes (they are small).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

HERE = Path(__file__).resolve().parent

HEADER = """#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = {mpu}
    upAxis = "{up}"{extra_meta}
)
"""

FLOOR = """
    def Mesh "Floor"{mesh_meta}
    {{
        int[] faceVertexCounts = {counts}
        int[] faceVertexIndices = {indices}
        point3f[] points = {points}{mesh_extra}
    }}
"""

SUN = """
    def DistantLight "Sun"
    {{
        float inputs:intensity = {intensity}
        float inputs:exposure = {exposure}
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }}
"""

CAMERA = """
    def Camera "Cam"
    {{
        float focalLength = {focal}
        float horizontalAperture = 32
        float verticalAperture = {vap}
        float2 clippingRange = {clip}
        double3 xformOp:translate = (0, 1, 5)
        float3 xformOp:scale = {cam_scale}
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
    }}
"""

QUAD_POINTS = "[(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1)]"
DEFAULTS = dict(
    mpu="1",
    up="Y",
    extra_meta="",
    counts="[4]",
    indices="[0, 3, 2, 1]",
    points=QUAD_POINTS,
    mesh_extra="",
    mesh_meta="",
    intensity="3",
    exposure="0",
    focal="35",
    vap="18",
    clip="(0.1, 100)",
    cam_scale="(1, 1, 1)",
)


def stage_text(floor=True, sun=True, camera=True, extra_world="", extra_root="", **kw) -> str:
    """A valid flat-floor stage (quad, distant light, camera) with parts replaced or left out."""
    v = dict(DEFAULTS, **kw)
    body = (FLOOR.format(**v) if floor else "") + (SUN.format(**v) if sun else "")
    body += (CAMERA.format(**v) if camera else "") + extra_world
    return HEADER.format(**v) + '\ndef Xform "World"\n{' + body + "}\n" + extra_root


def render_settings(res: str) -> str:
    return f"""
def Scope "Render"
{{
    def RenderSettings "Settings"
    {{
        uniform int2 resolution = {res}
    }}
}}
"""


WATER_MATERIAL = """
    def Scope "Looks"
    {{
        def Material "Water"
        {{
            token outputs:surface.connect = </World/Looks/Water/Surface.outputs:surface>
            def Shader "Surface"
            {{
                uniform token info:id = "UsdPreviewSurface"
                float inputs:ior = {ior}
                float inputs:opacity = 0
                float inputs:roughness = 0
                token outputs:surface
            }}
        }}
    }}
"""

BOUND_META = """ (
        prepend apiSchemas = ["MaterialBindingAPI"]
    )"""
BOUND = """
        rel material:binding = </World/Looks/Water>"""


def star_polygon(n: int) -> tuple[str, str, str]:
    """(counts, indices, points) of one non-convex (star) polygon of ``n`` corners, integer coordinates."""
    import math

    pts = []
    for k in range(n):
        r = 1000 if k % 2 == 0 else 600
        pts.append(f"({round(r * math.cos(2 * math.pi * k / n))}, 0, {round(r * math.sin(2 * math.pi * k / n))})")
    return f"[{n}]", "[" + ", ".join(map(str, range(n))) + "]", "[" + ", ".join(pts) + "]"


WATER_ATTRS = """
        custom double cisp:water:choppiness = {chop}
        custom int cisp:water:resolution = {res}
        custom double cisp:water:wind_speed = {wind}
        custom double cisp:water:depth = {depth}"""

LIGHT_TEMPLATE = """
    def {kind} "{name}"{meta}
    {{{body}
    }}
"""


def issue16_cases() -> dict[str, tuple[bytes | str, str | None, str, str]]:
    """One minimal file per failure family of issue 16: name -> (content, prim, keyword, outcome)."""
    valid = stage_text()
    c: dict[str, tuple[bytes | str, str | None, str, str]] = {}
    err, warn = "error", "warning"
    # --- tracebacks before: USD's parse error quoting bytes that are not UTF-8; attributes of the wrong type
    c["non_utf8_bytes.usda"] = (valid.encode().replace(b'def Mesh "Floor"', b'def Mesh "Fl\xc7\x9foor" \xba'),
                                None, "UTF-8", err)
    c["points_as_float_array.usda"] = (stage_text(points="[1, 2, 3]").replace("point3f[] points", "float[] points"),
                                       "/World/Floor", "points", err)
    c["points_as_string_array.usda"] = (stage_text(points='["a", "b"]').replace("point3f[] points", "string[] points"),
                                        "/World/Floor", "points", err)
    c["face_counts_scalar.usda"] = (stage_text(counts="4").replace("int[] faceVertexCounts", "int faceVertexCounts"),
                                    "/World/Floor", "faceVertexCounts", err)
    c["face_counts_float.usda"] = (stage_text(counts="[4.5]").replace("int[] faceVertexCounts",
                                                                      "float[] faceVertexCounts"),
                                   "/World/Floor", "faceVertexCounts", err)
    c["clipping_range_scalar.usda"] = (stage_text(clip="5").replace("float2 clippingRange", "float clippingRange"),
                                       "/World/Cam", "clippingRange", err)
    c["normals_as_float_array.usda"] = (stage_text(mesh_extra="""
        float[] normals = [0, 1, 0, 0]"""), "/World/Floor", "normals", warn)
    c["display_color_as_float_array.usda"] = (stage_text(mesh_extra="""
        float[] primvars:displayColor = [0.5, 0.5]"""), "/World/Floor", "displayColor", warn)
    water = WATER_ATTRS.format(chop="0.5", res="16", wind="2", depth="1")
    grid = dict(points="[(-1, 0, -1), (1, 0, -1), (-1, 0, 1), (1, 0, 1)]", indices="[0, 2, 3, 1]")
    c["water_wind_speed_1e300.usda"] = (stage_text(mesh_extra=water.replace("wind_speed = 2", "wind_speed = 1e300"),
                                                   **grid), "/World/Floor", "cisp:water:wind_speed", err)
    # --- NaN renders before: light power or positions beyond float32
    c["light_power_beyond_float32.usda"] = (stage_text(intensity="1e30", exposure="40"), "/World/Sun",
                                            "float32", err)
    c["light_exposure_128.usda"] = (stage_text(exposure="129"), "/World/Sun", "exposure", err)
    c["light_at_1e300.usda"] = (stage_text(sun=False, extra_world=LIGHT_TEMPLATE.format(
        kind="SphereLight", name="Far", meta="", body="""
        float inputs:intensity = 10
        bool treatAsPoint = 1
        double3 xformOp:translate = (1e300, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]""")), "/World/Far", "origin", err)
    c["meters_per_unit_1e9.usda"] = (stage_text(mpu="1e9"), None, "metersPerUnit", err)
    c["meters_per_unit_1e-300.usda"] = (stage_text(mpu="1e-300"), None, "metersPerUnit", err)
    c["huge_xform_scale.usda"] = (stage_text(mesh_extra="""
        float3 xformOp:scale = (1e30, 1e30, 1e30)
        uniform token[] xformOpOrder = ["xformOp:scale"]"""), "/World/Floor", "transform", err)
    c["points_beyond_extent.usda"] = (stage_text(points="[(-1, 0, -1), (1e30, 0, -1), (1, 0, 1), (-1, 0, 1)]"),
                                      "/World/Floor", "origin", err)
    c["water_choppiness_1e30.usda"] = (stage_text(mesh_extra=water.replace("choppiness = 0.5", "choppiness = 1e30"),
                                                  **grid), "/World/Floor", "cisp:water:choppiness", err)
    # --- hangs before: assets that are not regular files, huge non-convex n-gons, tuples in a float[],
    #     an FFT too large for the CPU (a FIFO cannot live in git: tests/test_malformed.py makes one)
    c["reference_to_device.usda"] = (stage_text(extra_world="""
    def Xform "Extra" (
        references = @/dev/zero@
    )
    {
    }
"""), "/World/Extra", "device", err)
    c["sublayer_device.usda"] = (valid.replace('    defaultPrim = "World"', '    subLayers = [@/dev/zero@]\n'
                                               '    defaultPrim = "World"'), None, "device", err)
    star = star_polygon(2001)
    c["non_convex_2001_gon.usda"] = (stage_text(counts=star[0], indices=star[1], points=star[2]), "/World/Floor",
                                     "not convex", err)
    c["float_array_of_tuples.usda"] = (stage_text(mesh_extra="""
        float[] weights = [(1, 2, 3), (4, 5, 6)]"""), None, "not a readable USD", err)
    c["water_resolution_4096_cpu.usda"] = (stage_text(mesh_extra=water.replace("resolution = 16", "resolution = 4096"),
                                                      **grid), "/World/Floor", "CPU", err)
    # --- errors without a file before: cisp:water checks (now in load_usd); xform ops that do not exist
    c["water_depth_nan.usda"] = (stage_text(mesh_extra=water.replace("depth = 1", "depth = nan"), **grid),
                                 "/World/Floor", "cisp:water:depth", err)
    c["water_not_a_grid.usda"] = (stage_text(mesh_extra=water), "/World/Floor", "regular grid", err)
    c["invalid_xform_op.usda"] = (stage_text(mesh_extra="""
        uniform token[] xformOpOrder = ["a", "b"]"""), "/World/Floor", "xform", err)
    # --- silent nonsense before
    c["resolution_as_string.usda"] = (stage_text(extra_root=render_settings('"640x360"').replace("uniform int2",
                                                                                               "uniform string")),
                                      "/Render/Settings", "resolution", err)
    c["intensity_as_string.usda"] = (stage_text(intensity='"3"').replace("float inputs:intensity",
                                                                        "string inputs:intensity"),
                                     "/World/Sun", "inputs:intensity", err)
    c["inactive_render_camera.usda"] = (stage_text(extra_world="""
    def Camera "Off" (
        active = false
    )
    {
    }
""", extra_root="""
def Scope "Render"
{
    def RenderSettings "Settings"
    {
        rel camera = </World/Off>
    }
}
"""), "/Render/Settings", "inactive", err)
    c["binding_to_missing_material.usda"] = (stage_text(mesh_meta=BOUND_META, mesh_extra=BOUND), "/World/Floor",
                                             "/World/Looks/Water", warn)
    c["subset_of_points.usda"] = (stage_text(mesh_meta=BOUND_META, mesh_extra="""
        def GeomSubset "Corners" (
            prepend apiSchemas = ["MaterialBindingAPI"]
        )
        {
            uniform token elementType = "point"
            uniform token familyName = "materialBind"
            int[] indices = [0, 1]
            rel material:binding = </World/Looks/Water>
        }""", extra_world=WATER_MATERIAL.format(ior="1.33")), "/World/Floor/Corners", "elementType", warn)
    c["cone_angle_360.usda"] = (stage_text(sun=False, extra_world="""
    def SphereLight "Spot" (
        prepend apiSchemas = ["ShapingAPI"]
    )
    {
        bool treatAsPoint = 1
        float inputs:shaping:cone:angle = 360
    }
"""), "/World/Spot", "cone", err)
    c["ior_1e-30.usda"] = (stage_text(mesh_meta=BOUND_META, mesh_extra=BOUND, extra_world=WATER_MATERIAL.format(
        ior="1e-30")), "/World/Looks/Water/Surface", "ior", err)
    return c


def cases() -> dict[str, tuple[bytes | str, str | None, str]]:
    """file name -> (content, prim the message must name or None, keyword of the reason)."""
    valid = stage_text()
    c: dict[str, tuple[bytes | str, str | None, str]] = {}
    # --- not a (complete) USD file
    c["empty.usda"] = ("", None, "empty")
    c["text_renamed.usda"] = ("These are not the prims you are looking for.\n", None, "not a readable USD file")
    c["png_renamed.usda"] = (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(64)), None, "not a readable USD")
    c["truncated.usda"] = (valid[: int(len(valid) * 0.6)], None, "not a readable USD file")
    c["garbage.usdc"] = (b"PXR-USDC" + bytes((i * 37) % 251 for i in range(200)), None, "not a readable USD")
    c["usd_text_named.txt"] = (valid, None, "not a USD file")
    c["header_only.usda"] = ("#usda 1.0\n", None, "no renderable triangles")
    # --- stage metadata
    c["zero_meters_per_unit.usda"] = (stage_text(mpu="0"), None, "metersPerUnit")
    c["x_up_axis.usda"] = (stage_text(up="X"), None, "upAxis")
    # --- mesh topology and values
    c["nan_points.usda"] = (stage_text(points="[(-1, 0, -1), (nan, 0, -1), (1, 0, 1), (-1, 0, 1)]"),
                            "/World/Floor", "NaN")
    c["inf_points.usda"] = (stage_text(points="[(-1, 0, -1), (1, 0, -1), (1, inf, 1), (-1, 0, 1)]"),
                            "/World/Floor", "Inf")
    c["index_out_of_range.usda"] = (stage_text(indices="[0, 3, 2, 7]"), "/World/Floor", "out of range")
    c["negative_index.usda"] = (stage_text(indices="[0, 3, -2, 1]"), "/World/Floor", "out of range")
    c["counts_sum_mismatch.usda"] = (stage_text(counts="[5]"), "/World/Floor", "faceVertexCounts sum")
    c["huge_face_count.usda"] = (stage_text(counts="[2000000000]"), "/World/Floor", "faceVertexCounts sum")
    c["face_with_two_vertices.usda"] = (stage_text(counts="[2, 2]"), "/World/Floor", "at least 3")
    c["negative_face_count.usda"] = (stage_text(counts="[-4, 8]", indices="[0, 3, 2, 1]"),
                                     "/World/Floor", "at least 3")
    c["mesh_without_points.usda"] = (stage_text(points="[]", counts="[]", indices="[]"), "/World/Floor",
                                     "no points")
    c["mesh_without_faces.usda"] = (stage_text(counts="[]", indices="[]"), "/World/Floor", "no faces")
    c["all_triangles_degenerate.usda"] = (stage_text(points="[(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)]"),
                                          "/World/Floor", "degenerate")
    c["no_mesh.usda"] = (stage_text(floor=False), None, "no renderable triangles")
    c["nan_xform.usda"] = (stage_text(mesh_extra="""
        double3 xformOp:translate = (nan, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]"""), "/World/Floor", "NaN")
    c["subset_index_out_of_range.usda"] = (stage_text(
        mesh_meta=BOUND_META,
        mesh_extra=BOUND + """
        def GeomSubset "Part" (
            prepend apiSchemas = ["MaterialBindingAPI"]
        )
        {
            uniform token elementType = "face"
            uniform token familyName = "materialBind"
            int[] indices = [0, 5]
            rel material:binding = </World/Looks/Water>
        }""",
        extra_world=WATER_MATERIAL.format(ior="1.33")), "/World/Floor/Part", "out of range")
    # --- materials
    c["zero_ior.usda"] = (stage_text(mesh_meta=BOUND_META, mesh_extra=BOUND,
                                     extra_world=WATER_MATERIAL.format(ior="0")),
                          "/World/Looks/Water/Surface", "ior")
    c["negative_ior.usda"] = (stage_text(mesh_meta=BOUND_META, mesh_extra=BOUND,
                                     extra_world=WATER_MATERIAL.format(ior="-1.33")),
                              "/World/Looks/Water/Surface", "ior")
    c["nan_ior.usda"] = (stage_text(mesh_meta=BOUND_META, mesh_extra=BOUND,
                                     extra_world=WATER_MATERIAL.format(ior="nan")),
                         "/World/Looks/Water/Surface", "ior")
    # --- lights
    c["no_light.usda"] = (stage_text(sun=False), None, "no light")
    c["only_rect_light.usda"] = (stage_text(sun=False, extra_world="""
    def RectLight "Rect"
    {
        float inputs:intensity = 10
    }
"""), "/World/Rect", "no usable light")
    c["dome_missing_texture.usda"] = (stage_text(sun=False, extra_world="""
    def DomeLight "Dome"
    {
        asset inputs:texture:file = @no_such_sky.exr@
    }
"""), "/World/Dome", "does not exist")
    c["negative_intensity.usda"] = (stage_text(intensity="-3"), "/World/Sun", "intensity")
    c["nan_intensity.usda"] = (stage_text(intensity="nan"), "/World/Sun", "intensity")
    c["inf_exposure.usda"] = (stage_text(exposure="inf"), "/World/Sun", "exposure")
    c["zero_spot_cone.usda"] = (stage_text(sun=False, extra_world="""
    def SphereLight "Spot" (
        prepend apiSchemas = ["ShapingAPI"]
    )
    {
        bool treatAsPoint = 1
        float inputs:shaping:cone:angle = 0
    }
"""), "/World/Spot", "cone")
    # --- camera
    c["no_camera.usda"] = (stage_text(camera=False), None, "no camera")
    c["zero_focal_length.usda"] = (stage_text(focal="0"), "/World/Cam", "focalLength")
    c["nan_focal_length.usda"] = (stage_text(focal="nan"), "/World/Cam", "focalLength")
    c["zero_aperture.usda"] = (stage_text(vap="0"), "/World/Cam", "verticalAperture")
    c["clip_near_after_far.usda"] = (stage_text(clip="(100, 0.1)"), "/World/Cam", "clippingRange")
    c["clip_near_zero.usda"] = (stage_text(clip="(0, 100)"), "/World/Cam", "clippingRange")
    c["camera_zero_scale.usda"] = (stage_text(cam_scale="(0, 0, 0)"), "/World/Cam", "singular")
    # --- resolution
    c["zero_resolution.usda"] = (stage_text(extra_root=render_settings("(0, 360)")), "/Render/Settings",
                                 "resolution")
    c["negative_resolution.usda"] = (stage_text(extra_root=render_settings("(640, -360)")), "/Render/Settings",
                                     "resolution")
    c["resolution_beyond_memory.usda"] = (stage_text(extra_root=render_settings("(60000, 60000)")),
                                          "/Render/Settings", "G-buffer")
    return c


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE, help="folder to write into (default: next to this script)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    expected = {}
    every = {name: (*case, "error") for name, case in cases().items()}
    every.update(issue16_cases())
    for name, (content, prim, keyword, outcome) in every.items():
        data = content.encode() if isinstance(content, str) else content
        (args.out / name).write_bytes(data)
        expected[name] = {"prim": prim, "keyword": keyword, "outcome": outcome}
    (args.out / "expected.json").write_text(json.dumps(expected, indent=2, sort_keys=True) + "\n")
    print(f"wrote {len(expected)} malformed files and expected.json to {os.path.relpath(args.out)}")


if __name__ == "__main__":
    main()
