"""USD import: geometry, units, time, lights, camera and materials against hand-computed values.

Stages are built with the pxr API in a temporary folder; each test loads one small stage.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade

from cisp_warp.errors import SceneError, SceneWarning
from cisp_warp.scene.model import LightKind
from cisp_warp.usd import load_usd


# ---------------------------------------------------------------------------------------------- helpers


def new_stage(tmp_path, name="s.usda", up="Y", mpu=1.0, light=True, camera=True):
    """A stage with (by default) a distant light and a camera, Y up, metres."""
    stage = Usd.Stage.CreateNew(str(tmp_path / name))
    UsdGeom.SetStageUpAxis(stage, up)
    if mpu is not None:
        UsdGeom.SetStageMetersPerUnit(stage, mpu)
    UsdGeom.Xform.Define(stage, "/World")
    if light:
        UsdLux.DistantLight.Define(stage, "/World/Sun").CreateIntensityAttr(3.0)
    if camera:
        cam = UsdGeom.Camera.Define(stage, "/World/Cam")
        UsdGeom.XformCommonAPI(cam).SetTranslate((0.0, 0.0, 10.0))
    return stage


def add_mesh(stage, path, points, counts, indices, **attrs):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([Gf.Vec3f(*map(float, p)) for p in points])
    mesh.CreateFaceVertexCountsAttr([int(c) for c in counts])
    mesh.CreateFaceVertexIndicesAttr([int(i) for i in indices])
    for k, v in attrs.items():
        mesh.GetPrim().GetAttribute(k).Set(v)
    return mesh


def save_and_load(stage, **kwargs):
    stage.GetRootLayer().Save()
    return load_usd(stage.GetRootLayer().realPath, **kwargs)


def tri_area(scene, tri=None):
    p = scene.points.astype(np.float64)[scene.indices if tri is None else scene.indices[tri]]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def tri_normal(scene):
    p = scene.points.astype(np.float64)[scene.indices]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


UNIT_QUAD = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]  # in the XY plane, facing +Z


# ---------------------------------------------------------------------------------------------- geometry


def test_triangulation_preserves_area_and_winding(tmp_path):
    stage = new_stage(tmp_path)
    pent = [(0, 0, 0), (2, 0, 0), (2.5, 1, 0), (1, 2, 0), (-0.5, 1, 0)]
    # L-shaped hexagon (non-convex): a fan from corner 0 would leave the polygon.
    ell = [(3, 0, 0), (6, 0, 0), (6, 1, 0), (4, 1, 0), (4, 3, 0), (3, 3, 0)]
    # arrow-head pentagon whose first corner is the reflex one.
    arrow = [(8, 1, 0), (7, 0, 0), (10, 1, 0), (7, 2, 0), (7.5, 1.5, 0)]
    dart = [(11.3, 0.3, 0), (11, 0, 0), (12, 0, 0), (11, 1, 0)]  # non-convex quad, reflex first corner
    pts = UNIT_QUAD + pent + ell + arrow + dart
    counts = [4, 5, 6, 5, 4]
    idx = list(range(4)) + list(range(4, 9)) + list(range(9, 15)) + list(range(15, 20)) + list(range(20, 24))
    add_mesh(stage, "/World/M", pts, counts, idx)
    scene = save_and_load(stage)

    def shoelace(poly):
        xy = np.asarray(poly, dtype=np.float64)[:, :2]
        return 0.5 * abs(np.dot(xy[:, 0], np.roll(xy[:, 1], -1)) - np.dot(xy[:, 1], np.roll(xy[:, 0], -1)))

    assert scene.triangle_count == sum(c - 2 for c in counts)
    assert np.isclose(tri_area(scene).sum(), sum(shoelace(p) for p in (UNIT_QUAD, pent, ell, arrow, dart)))
    np.testing.assert_allclose(tri_normal(scene), np.tile([0.0, 0.0, 1.0], (scene.triangle_count, 1)), atol=1e-6)
    # Every triangle of the L lies inside the L (its centroid is not in the notch x>4, y>1).
    c = scene.points[scene.indices].mean(axis=1)
    in_ell = (c[:, 0] > 3) & (c[:, 0] < 6)
    assert not np.any(in_ell & (c[:, 0] > 4) & (c[:, 1] > 1))
    np.testing.assert_allclose(scene.normals, np.tile([0, 0, 1], (scene.vertex_count, 1)), atol=1e-6)


def test_left_handed_and_mirrored_meshes_come_out_counter_clockwise(tmp_path):
    stage = new_stage(tmp_path)
    meshes = [
        add_mesh(stage, "/World/Right", UNIT_QUAD, [4], [0, 1, 2, 3]),
        add_mesh(stage, "/World/Left", UNIT_QUAD, [4], [0, 3, 2, 1]),  # clockwise seen from +z
        add_mesh(stage, "/World/Mirror", UNIT_QUAD, [4], [0, 1, 2, 3]),
    ]
    meshes[1].CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    meshes[2].AddScaleOp().Set(Gf.Vec3f(1, 1, -1))  # mirror in z: the front side turns to -z
    for m in meshes:
        m.CreateNormalsAttr([Gf.Vec3f(0, 0, 1)] * 4)
        m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    scene = save_and_load(stage)
    front = {"/World/Right": [0, 0, 1], "/World/Left": [0, 0, 1], "/World/Mirror": [0, 0, -1]}
    for r in scene.meshes:
        n = tri_normal(scene)[r.triangle_start : r.triangle_start + r.triangle_count]
        np.testing.assert_allclose(n, np.tile(front[r.path], (len(n), 1)), atol=1e-6, err_msg=r.path)
        vn = scene.normals[r.vertex_start : r.vertex_start + r.vertex_count]
        np.testing.assert_allclose(vn, np.tile(front[r.path], (len(vn), 1)), atol=1e-6, err_msg=r.path)


def test_face_varying_normals_split_vertices(tmp_path):
    stage = new_stage(tmp_path)
    # Two quads sharing an edge (points 1, 2), folded 90 degrees: hard edge authored face-varying.
    pts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (1, 0, -1), (1, 1, -1)]
    mesh = add_mesh(stage, "/World/Fold", pts, [4, 4], [0, 1, 2, 3, 1, 4, 5, 2])
    n_fv = [(0, 0, 1)] * 4 + [(1, 0, 0)] * 4
    mesh.CreateNormalsAttr([Gf.Vec3f(*n) for n in n_fv])
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    scene = save_and_load(stage)
    assert scene.vertex_count == 8  # points 1 and 2 split in two
    for t in range(scene.triangle_count):
        face_n = tri_normal(scene)[t]
        np.testing.assert_allclose(scene.normals[scene.indices[t]], np.tile(face_n, (3, 1)), atol=1e-6)


def test_vertex_normals_keep_point_order_and_go_through_inverse_transpose(tmp_path):
    stage = new_stage(tmp_path)
    pts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    mesh = add_mesh(stage, "/World/M", pts, [4], [0, 1, 2, 3])
    n = np.array([[1, 0, 1], [0, 0, 1], [-1, 0, 1], [0, 0, 1]], dtype=np.float64)
    mesh.CreateNormalsAttr([Gf.Vec3f(*v) for v in n])
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.AddScaleOp().Set(Gf.Vec3f(2.0, 1.0, 1.0))  # normals scale by 1/2 in x
    scene = save_and_load(stage)
    np.testing.assert_allclose(scene.points, np.array(pts) * [2, 1, 1], atol=1e-6)
    expect = n * [0.5, 1, 1]
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(scene.normals, expect, atol=1e-6)


def test_computed_normals_are_smooth_on_a_sphere_and_flat_on_a_cube(tmp_path):
    import trimesh

    stage = new_stage(tmp_path)
    ico = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    add_mesh(stage, "/World/Ball", ico.vertices, [3] * len(ico.faces), ico.faces.reshape(-1))
    box = trimesh.creation.box(extents=(1, 1, 1))
    cube = add_mesh(stage, "/World/Cube", box.vertices, [3] * len(box.faces), box.faces.reshape(-1))
    UsdGeom.XformCommonAPI(cube).SetTranslate((5, 0, 0))
    scene = save_and_load(stage)
    ball, cube_r = scene.meshes
    bp = scene.points[: ball.vertex_count]
    np.testing.assert_allclose(scene.normals[: ball.vertex_count], bp / np.linalg.norm(bp, axis=1, keepdims=True),
                               atol=0.03)  # area-weighted vertex normals
    assert ball.vertex_count == len(ico.vertices)  # smooth: not split
    assert cube_r.vertex_count == 24  # 6 faces x 4 corners
    t = slice(cube_r.triangle_start, cube_r.triangle_start + cube_r.triangle_count)
    for tri, fn in zip(scene.indices[t], tri_normal(scene)[t]):
        np.testing.assert_allclose(scene.normals[tri], np.tile(fn, (3, 1)), atol=1e-6)


def test_nested_xform_stack_matches_hand_computed_transform(tmp_path):
    stage = new_stage(tmp_path)
    parent = UsdGeom.Xform.Define(stage, "/World/A")
    parent.AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
    parent.AddRotateYOp().Set(90.0)
    parent.AddScaleOp().Set(Gf.Vec3f(2, 2, 2))
    child = UsdGeom.Xform.Define(stage, "/World/A/B")
    child.AddRotateXOp().Set(-90.0)
    child.AddTranslateOp().Set(Gf.Vec3d(0, 0, 1))
    pts = np.array([(0, 0, 0), (1, 0, 0), (0, 1, 0)], dtype=np.float64)
    add_mesh(stage, "/World/A/B/M", pts, [3], [0, 1, 2])
    scene = save_and_load(stage)

    def rot_x(deg):
        c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])

    def rot_y(deg):
        c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])

    # xformOpOrder applies the last op first: p_parent = T(R(S p)); p_child = Rx(T' p).
    child_p = (rot_x(-90) @ (pts + [0, 0, 1]).T).T
    world = (rot_y(90) @ (2.0 * child_p).T).T + [1, 2, 3]
    np.testing.assert_allclose(scene.points, world, atol=1e-5)


def test_z_up_centimetre_stage_becomes_y_up_metres(tmp_path):
    stage = new_stage(tmp_path, up="Z", mpu=None)  # metersPerUnit unauthored -> 0.01
    add_mesh(stage, "/World/M", [(0, 0, 0), (100, 0, 0), (0, 100, 0), (0, 0, 100)], [3, 3], [0, 1, 2, 0, 1, 3])
    cam = UsdGeom.Camera.Get(stage, "/World/Cam")
    cam.CreateClippingRangeAttr(Gf.Vec2f(10, 5000))
    UsdGeom.XformCommonAPI(cam).SetTranslate((0.0, -500.0, 0.0))
    UsdGeom.XformCommonAPI(cam).SetRotate((90.0, 0.0, 0.0))  # USD camera looks down -Z; now down +Y (Z up)
    scene = save_and_load(stage)
    # (the two triangles meet at 90 degrees: the shared edge is split, so compare the distinct points)
    np.testing.assert_allclose(np.unique(scene.points, axis=0), [(0, 0, -1), (0, 0, 0), (0, 1, 0), (1, 0, 0)],
                               atol=1e-6)
    np.testing.assert_allclose(scene.camera.position, [0, 0, 5], atol=1e-6)
    np.testing.assert_allclose(scene.camera.forward, [0, 0, -1], atol=1e-6)  # stage +Y -> world -Z
    np.testing.assert_allclose(scene.camera.to_world[:3, 1], [0, 1, 0], atol=1e-6)  # stage +Z up -> world +Y
    assert scene.camera.near == pytest.approx(0.1) and scene.camera.far == pytest.approx(50.0)
    # the distant light (local -Z, stage "down") travels along world -Y.
    np.testing.assert_allclose(scene.lights[0].direction, [0, -1, 0], atol=1e-6)


def test_time_samples_move_points_and_camera(tmp_path):
    stage = new_stage(tmp_path)
    stage.SetTimeCodesPerSecond(24.0)
    stage.SetStartTimeCode(1.0)
    stage.SetEndTimeCode(5.0)
    mesh = add_mesh(stage, "/World/M", UNIT_QUAD, [4], [0, 1, 2, 3])
    mesh.GetPointsAttr().Set([Gf.Vec3f(*p) for p in UNIT_QUAD], 1.0)
    mesh.GetPointsAttr().Set([Gf.Vec3f(p[0], p[1], 0.5) for p in UNIT_QUAD], 5.0)
    cam = UsdGeom.Camera.Get(stage, "/World/Cam")
    cam.GetPrim().GetAttribute("xformOp:translate").Set(Gf.Vec3d(0, 0, 10), 1.0)
    cam.GetPrim().GetAttribute("xformOp:translate").Set(Gf.Vec3d(0, 3, 10), 5.0)
    stage.GetRootLayer().Save()
    path = stage.GetRootLayer().realPath
    a = load_usd(path)  # startTimeCode
    b = load_usd(path, time_code=5.0)
    assert a.time_code == 1.0 and a.time == pytest.approx(1 / 24)
    assert b.time_code == 5.0 and b.time == pytest.approx(5 / 24)
    np.testing.assert_allclose(a.points[:, 2], 0.0)
    np.testing.assert_allclose(b.points[:, 2], 0.5)
    np.testing.assert_allclose(a.camera.position, [0, 0, 10])
    np.testing.assert_allclose(b.camera.position, [0, 3, 10])
    assert a.meshes[0].dynamic and a.meshes[0].water is None


# ---------------------------------------------------------------------------------------------- lights


def test_lights_direction_spot_cone_and_intensity(tmp_path):
    stage = new_stage(tmp_path, light=False)
    add_mesh(stage, "/World/M", UNIT_QUAD, [4], [0, 1, 2, 3])
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(2.0)
    sun.CreateExposureAttr(3.0)
    sun.CreateColorAttr(Gf.Vec3f(1.0, 0.5, 0.25))
    UsdGeom.XformCommonAPI(sun).SetRotate((-45.0, 0.0, 0.0))  # -Z tilted down by 45 degrees
    spot = UsdLux.SphereLight.Define(stage, "/World/Spot")
    spot.CreateTreatAsPointAttr(True)
    spot.CreateIntensityAttr(10.0)
    UsdGeom.XformCommonAPI(spot).SetTranslate((0.0, 2.0, 0.0))
    UsdGeom.XformCommonAPI(spot).SetRotate((-90.0, 0.0, 0.0))  # -Z -> -Y: points down
    shaping = UsdLux.ShapingAPI.Apply(spot.GetPrim())
    shaping.CreateShapingConeAngleAttr(30.0)
    shaping.CreateShapingConeSoftnessAttr(0.25)
    bulb = UsdLux.SphereLight.Define(stage, "/World/Bulb")
    bulb.CreateRadiusAttr(0.001)
    bulb.CreateIntensityAttr(1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)  # none of these lights warrants a warning
        scene = save_and_load(stage)
    by = {light.name: light for light in scene.lights}
    s = by["/World/Sun"]
    assert s.kind == LightKind.DISTANT
    np.testing.assert_allclose(s.direction, [0, -math.sqrt(0.5), -math.sqrt(0.5)], atol=1e-6)
    assert s.intensity == pytest.approx(16.0)
    np.testing.assert_allclose(s.radiometric_rgb, [16.0, 8.0, 4.0])
    sp = by["/World/Spot"]
    assert sp.kind == LightKind.SPOT
    np.testing.assert_allclose(sp.position, [0, 2, 0], atol=1e-6)
    np.testing.assert_allclose(sp.direction, [0, -1, 0], atol=1e-6)
    assert sp.cone_angle == pytest.approx(math.radians(30.0))
    assert sp.cone_softness == pytest.approx(0.25)
    assert sp.intensity == pytest.approx(10.0)
    assert by["/World/Bulb"].kind == LightKind.POINT


def test_unsupported_and_approximated_lights_warn(tmp_path):
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/M", UNIT_QUAD, [4], [0, 1, 2, 3])
    UsdLux.RectLight.Define(stage, "/World/Rect")
    UsdLux.DomeLight.Define(stage, "/World/Dome")
    big = UsdLux.SphereLight.Define(stage, "/World/Big")
    big.CreateRadiusAttr(0.5)
    big.CreateEnableColorTemperatureAttr(True)
    with pytest.warns(SceneWarning) as record:
        scene = save_and_load(stage)
    text = "\n".join(str(w.message) for w in record)
    for needle in ("/World/Rect", "radius", "enableColorTemperature"):
        assert needle in text
    assert "/World/Dome" not in text  # a dome light is the sky, read without a warning
    assert sorted(light.name for light in scene.lights) == ["/World/Big", "/World/Sun"]
    assert scene.sky is not None and scene.sky.name == "/World/Dome"


# ---------------------------------------------------------------------------------------------- camera


def test_camera_fov_from_focal_and_aperture_and_render_settings(tmp_path):
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/M", UNIT_QUAD, [4], [0, 1, 2, 3])
    cam = UsdGeom.Camera.Get(stage, "/World/Cam")
    cam.CreateFocalLengthAttr(35.0)
    cam.CreateHorizontalApertureAttr(32.0)
    cam.CreateVerticalApertureAttr(18.0)
    ortho = UsdGeom.Camera.Define(stage, "/World/Ortho")
    ortho.CreateProjectionAttr(UsdGeom.Tokens.orthographic)
    ortho.CreateHorizontalApertureAttr(32.0)
    ortho.CreateVerticalApertureAttr(18.0)
    rs = UsdRender.Settings.Define(stage, "/Render/Settings")
    rs.CreateResolutionAttr(Gf.Vec2i(320, 180))
    stage.GetRootLayer().Save()
    path = stage.GetRootLayer().realPath
    scene = load_usd(path)
    assert (scene.camera.width, scene.camera.height) == (320, 180)
    assert scene.camera.fov_y == pytest.approx(2 * math.atan(18.0 / 2 / 35.0))
    assert not scene.camera.orthographic
    assert load_usd(path, width=640).camera.height == 360  # aspect of the settings kept
    o = load_usd(path, camera_path="/World/Ortho", width=64, height=36)
    assert o.camera.orthographic and o.camera.ortho_height == pytest.approx(1.8)
    # A 1:1 image with a 16:9 aperture: expandAperture grows the vertical aperture to 32.
    sq = load_usd(path, width=100, height=100)
    assert sq.camera.fov_y == pytest.approx(2 * math.atan(32.0 / 2 / 35.0))


def test_camera_transform_is_orthonormalised(tmp_path):
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/M", UNIT_QUAD, [4], [0, 1, 2, 3])
    cam = UsdGeom.Camera.Get(stage, "/World/Cam")
    UsdGeom.XformCommonAPI(cam).SetScale((3.0, 2.0, 0.5))
    UsdGeom.XformCommonAPI(cam).SetRotate((0.0, 30.0, 0.0))
    m = save_and_load(stage).camera.to_world
    np.testing.assert_allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-9)
    assert np.linalg.det(m[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(m[:3, 2], [math.sin(math.radians(30)), 0, math.cos(math.radians(30))], atol=1e-6)


# ---------------------------------------------------------------------------------------------- materials


def make_material(stage, path, **inputs):
    mat = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, path + "/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    types = {"diffuseColor": Sdf.ValueTypeNames.Color3f}
    for k, v in inputs.items():
        shader.CreateInput(k, types.get(k, Sdf.ValueTypeNames.Float)).Set(v)
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return mat, shader


def bind(prim, mat):
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)


def test_material_binding_values_and_subsets(tmp_path):
    stage = new_stage(tmp_path)
    glass, _ = make_material(stage, "/World/Looks/Glass", diffuseColor=Gf.Vec3f(0.1, 0.2, 0.3),
                             roughness=0.05, metallic=0.0, opacity=0.0, ior=2.4)
    gold, _ = make_material(stage, "/World/Looks/Gold", diffuseColor=Gf.Vec3f(1.0, 0.8, 0.2), metallic=1.0)
    mesh = add_mesh(stage, "/World/M", UNIT_QUAD + [(p[0] + 2, p[1], 0) for p in UNIT_QUAD], [4, 4],
                    [0, 1, 2, 3, 4, 5, 6, 7])
    bind(mesh.GetPrim(), glass)
    subset = UsdGeom.Subset.CreateGeomSubset(mesh, "right", UsdGeom.Tokens.face, [1],
                                             UsdShade.Tokens.materialBind)
    bind(subset.GetPrim(), gold)
    scene = save_and_load(stage)
    mats = [scene.materials[i] for i in scene.triangle_material]
    assert [m.name for m in mats] == ["/World/Looks/Glass"] * 2 + ["/World/Looks/Gold"] * 2
    g = mats[0]
    assert g.albedo == pytest.approx((0.1, 0.2, 0.3)) and g.roughness == pytest.approx(0.05)
    assert g.opacity == 0.0 and g.ior == pytest.approx(2.4) and g.transmissive
    assert mats[2].metallic == 1.0 and mats[2].roughness == 0.5 and mats[2].ior == 1.5  # spec defaults


def test_texture_on_diffuse_color_warns_and_uses_the_constant(tmp_path):
    stage = new_stage(tmp_path)
    mat, shader = make_material(stage, "/World/Looks/Tex", roughness=0.7)
    tex = UsdShade.Shader.Define(stage, "/World/Looks/Tex/Image")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("tiles.png")
    out = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    inp = shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f)
    inp.Set(Gf.Vec3f(0.5, 0.4, 0.3))
    inp.ConnectToSource(out)
    mesh = add_mesh(stage, "/World/M", UNIT_QUAD, [4], [0, 1, 2, 3])
    bind(mesh.GetPrim(), mat)
    with pytest.warns(SceneWarning, match="/World/Looks/Tex"):
        scene = save_and_load(stage)
    m = scene.materials[scene.triangle_material[0]]
    assert m.albedo == pytest.approx((0.5, 0.4, 0.3)) and m.roughness == pytest.approx(0.7)


def test_display_color_per_face_and_per_vertex(tmp_path):
    stage = new_stage(tmp_path)
    # 3 quads in a row: red, green, red (uniform displayColor)
    pts = [(x, y, 0) for y in (0, 1) for x in range(4)]
    idx = [0, 1, 5, 4, 1, 2, 6, 5, 2, 3, 7, 6]
    tiles = add_mesh(stage, "/World/Tiles", pts, [4, 4, 4], idx)
    pv = tiles.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform)
    pv.Set([Gf.Vec3f(1, 0, 0), Gf.Vec3f(0, 1, 0), Gf.Vec3f(1, 0, 0)])
    tri = add_mesh(stage, "/World/Tri", [(0, 0, 1), (1, 0, 1), (0, 1, 1)], [3], [0, 1, 2])
    tri.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex).Set([Gf.Vec3f(0.2, 0.2, 0.2)] * 3)
    const = add_mesh(stage, "/World/Const", [(0, 0, 2), (1, 0, 2), (0, 1, 2)], [3], [0, 1, 2])
    const.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([Gf.Vec3f(1, 0, 0)])
    scene = save_and_load(stage)
    names = [scene.materials[i].name for i in scene.triangle_material]
    assert names == ["displayColor#ff0000"] * 2 + ["displayColor#00ff00"] * 2 + ["displayColor#ff0000"] * 2 \
        + ["displayColor#333333", "displayColor#ff0000"]
    assert len(scene.materials) == 3  # one per distinct colour, shared across meshes
    assert scene.materials[scene.triangle_material[2]].albedo == (0.0, 1.0, 0.0)


def test_default_material_without_binding_or_display_color(tmp_path):
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/M", UNIT_QUAD, [4], [0, 1, 2, 3])
    scene = save_and_load(stage)
    assert [m.name for m in scene.materials] == ["default"]


# ---------------------------------------------------------------------------------------------- water, visibility


def test_water_attributes_make_a_dynamic_mesh_range(tmp_path):
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/Floor", UNIT_QUAD, [4], [0, 1, 2, 3])
    grid = [(0, 0.5, 0), (1, 0.5, 0), (0, 0.5, 1), (1, 0.5, 1)]  # a 2 x 2 rest grid, vertex iz * nx + ix
    water = add_mesh(stage, "/World/Water", grid, [4], [0, 2, 3, 1])
    prim = water.GetPrim()
    prim.CreateAttribute("cisp:water:resolution", Sdf.ValueTypeNames.Int).Set(64)
    prim.CreateAttribute("cisp:water:wind_speed", Sdf.ValueTypeNames.Float).Set(2.0)
    prim.CreateAttribute("cisp:water:spectrum", Sdf.ValueTypeNames.Token).Set("phillips")
    prim.CreateAttribute("cisp:water:wind_direction", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(1, 0))
    prim.CreateAttribute("cisp:other", Sdf.ValueTypeNames.Int).Set(1)
    scene = save_and_load(stage)
    floor, w = scene.meshes
    assert not floor.dynamic and floor.water is None
    assert w.dynamic and w.path == "/World/Water"
    assert w.water == {"resolution": 64, "wind_speed": 2.0, "spectrum": "phillips", "wind_direction": (1.0, 0.0)}
    assert type(w.water["resolution"]) is int and type(w.water["spectrum"]) is str
    assert w.vertex_count == 4  # vertex i is point i: sim/ can write in place


def test_invisible_and_guide_prims_are_skipped(tmp_path):
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/Shown", UNIT_QUAD, [4], [0, 1, 2, 3])
    hidden = UsdGeom.Xform.Define(stage, "/World/Hidden")
    hidden.MakeInvisible()
    add_mesh(stage, "/World/Hidden/M", UNIT_QUAD, [4], [0, 1, 2, 3])
    guide = add_mesh(stage, "/World/Guide", UNIT_QUAD, [4], [0, 1, 2, 3])
    guide.CreatePurposeAttr(UsdGeom.Tokens.guide)
    proxy = add_mesh(stage, "/World/Proxy", UNIT_QUAD, [4], [0, 1, 2, 3])
    proxy.CreatePurposeAttr(UsdGeom.Tokens.proxy)
    render = add_mesh(stage, "/World/Render", UNIT_QUAD, [4], [0, 1, 2, 3])
    render.CreatePurposeAttr(UsdGeom.Tokens.render)
    scene = save_and_load(stage)
    assert [m.path for m in scene.meshes] == ["/World/Shown", "/World/Render"]


def test_degenerate_triangles_are_dropped_with_a_warning(tmp_path):
    stage = new_stage(tmp_path)
    pts = UNIT_QUAD + [(2, 0, 0), (3, 0, 0), (4, 0, 0)]  # last triangle collinear
    add_mesh(stage, "/World/M", pts, [4, 3, 3], [0, 1, 2, 3, 4, 5, 6, 0, 0, 1])
    with pytest.warns(SceneWarning, match=r"prim '/World/M'.*2 of 4 triangles are degenerate"):
        scene = save_and_load(stage)
    assert scene.triangle_count == 2


def test_scene_is_validated_and_names_its_source(tmp_path):
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/M", UNIT_QUAD, [4], [0, 1, 2, 3])
    scene = save_and_load(stage)
    assert scene.source.endswith("s.usda")
    assert scene.points.dtype == np.float32 and scene.indices.dtype == np.int32
    assert scene.triangle_material.dtype == np.int32 and scene.normals.dtype == np.float32
    scene.validate()


def test_resolution_beyond_memory_is_refused_before_allocating(tmp_path):
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/M", UNIT_QUAD, [4], [0, 1, 2, 3])
    with pytest.raises(SceneError, match="s.usda"):
        save_and_load(stage, width=10**6, height=10**5)  # 1e11 px × 64 B ≈ 6 TiB


# ---------------------------------------------------------------------------------------------- shipped scene

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]
CORNELL = ROOT / "scenes_usd" / "cornell_flooded.usda"


def _cornell_generator():
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_cornell_flooded", ROOT / "tools" / "make_cornell_flooded.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_cornell_flooded_loads_as_seed_000_describes_it():
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)  # the shipped scene imports without a warning
        scene = load_usd(CORNELL)
    lo, hi = scene.bounds()
    np.testing.assert_allclose(lo, [-0.5, 0.0, -0.5], atol=1e-6)
    np.testing.assert_allclose(hi, [0.5, 1.0, 0.5], atol=1e-6)
    (spot,) = scene.lights
    assert spot.kind == LightKind.SPOT and spot.intensity == pytest.approx(2.0)
    np.testing.assert_allclose(spot.direction, [0, -1, 0], atol=1e-9)
    # The cone reaches the walls (x or z = ±0.5) only below the water line.
    assert spot.position[1] - 0.5 / math.tan(spot.cone_angle) < 0.35 - 0.01
    water = next(m for m in scene.meshes if m.water)
    assert water.dynamic and water.path == "/World/Water"
    assert water.water["depth"] == 0.35 and water.water["spectrum"] == "phillips"
    t = slice(water.triangle_start, water.triangle_start + water.triangle_count)
    mat = scene.materials[scene.triangle_material[t][0]]
    assert mat.transmissive and mat.roughness == 0.0 and mat.ior == pytest.approx(2.4)
    y = scene.points[water.vertex_start : water.vertex_start + water.vertex_count, 1]
    assert 0.001 < y.max() - 0.35 < 0.01 and 0.001 < 0.35 - y.min() < 0.01  # waves of a few mm
    # shading normals agree with the counter-clockwise geometric normals everywhere
    n_geo = tri_normal(scene)
    n_shade = scene.normals[scene.indices].astype(np.float64).mean(axis=1)
    assert np.einsum("ij,ij->i", n_geo, n_shade).min() > 0.9
    cam = scene.camera
    assert (cam.width, cam.height) == (640, 360) and math.degrees(cam.fov_y) == pytest.approx(40.0, abs=0.1)
    assert (cam.near, cam.far) == pytest.approx((0.05, 20.0))
    names = {m.name for m in scene.materials}
    assert {"/World/Looks/Red", "/World/Looks/Green", "/World/Looks/White", "/World/Looks/Water"} <= names


def test_cornell_generator_is_deterministic_and_in_sync_with_the_committed_file(tmp_path):
    gen = _cornell_generator()
    stage = gen.build(tmp_path / "c.usda", 2.4, 96, 0)
    assert gen.validation_errors(stage) == []
    assert (tmp_path / "c.usda").read_bytes() == CORNELL.read_bytes(), "rerun tools/make_cornell_flooded.py"


# ------------------------------------------------------------------------- cost linear in the corners (issue 16)


def _naive_auto_smooth(tri_point, tri_n, n_points):
    """Twin of ``auto_smooth_normals`` for triangle meshes: every corner against every triangle at its point."""
    cos = math.cos(math.radians(45.0))
    flat = tri_n / np.linalg.norm(tri_n, axis=1, keepdims=True)
    out = np.zeros((len(tri_point), 3, 3))
    for t, tri in enumerate(tri_point):
        for c, p in enumerate(tri):
            for u in np.nonzero(np.any(tri_point == p, axis=1))[0]:
                if flat[t] @ flat[u] >= cos:
                    out[t, c] += tri_n[u]
    return out / np.linalg.norm(out, axis=2, keepdims=True)


@pytest.mark.parametrize("valence", [6, 200])
def test_auto_smooth_matches_its_naive_twin(valence):
    """A fan of ``valence`` triangles folded (63 degrees) into a hard edge: per-corner normals equal the
    naive O(k^2) twin's below MAX_SMOOTH_VALENCE; above it the fan's centre is flat (its faces bend too much)."""
    from cisp_warp.usd.mesh import MAX_SMOOTH_VALENCE, auto_smooth_normals

    rng = np.random.default_rng(3)
    a = np.linspace(0.0, 2.0 * math.pi, valence + 1)
    rim = np.stack([np.cos(a), np.where(np.cos(a) > 0.0, 2.0 * np.cos(a), 0.0), np.sin(a)], axis=1)[:-1]
    points = np.vstack([[0.0, 0.0, 0.0], rim]) + rng.normal(0.0, 1e-3, (valence + 1, 3))
    tris = np.array([[0, 1 + (k + 1) % valence, 1 + k] for k in range(valence)])
    p = points[tris]
    tri_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    per_point, per_corner, n_flat = auto_smooth_normals(tris, tri_n, len(points))
    assert per_point is None  # the fold is a hard edge
    if valence <= MAX_SMOOTH_VALENCE:
        assert n_flat == 0
        np.testing.assert_allclose(per_corner, _naive_auto_smooth(tris, tri_n, len(points)), atol=1e-12)
    else:
        assert n_flat == 1
        flat = tri_n / np.linalg.norm(tri_n, axis=1, keepdims=True)
        np.testing.assert_allclose(per_corner[:, 0], flat, atol=1e-12)  # the centre's corners keep their face's


def test_polygon_counts_once_per_point_in_smoothing():
    """An n-gon's fan triangles all meet at its first corner; they form one element, so a convex polygon's
    normals are its plane's normal everywhere."""
    from cisp_warp.usd.mesh import auto_smooth_normals

    n = 50
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    points = np.stack([np.cos(a), np.zeros(n), np.sin(a)], axis=1)
    tris = np.array([[0, k + 1, k] for k in range(1, n - 1)])
    p = points[tris]
    tri_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    per_point, per_corner, n_flat = auto_smooth_normals(tris, tri_n, n, np.zeros(len(tris), dtype=np.int64))
    assert per_corner is None and n_flat == 0
    np.testing.assert_allclose(per_point, np.tile([0.0, 1.0, 0.0], (n, 1)), atol=1e-12)


@pytest.mark.parametrize("star", [False, True])
def test_large_polygons_load(tmp_path, star):
    """A 20,000-gon exhausted memory in the smoothing (k^2 corner pairs); a 1,500-corner star is ear-clipped."""
    n = 1500 if star else 20000
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    r = np.where(np.arange(n) % 2 == 0, 1.0, 0.6) if star else np.ones(n)
    points = np.stack([r * np.cos(a), np.zeros(n), -r * np.sin(a)], axis=1)  # counter-clockwise seen from +Y
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/Disc", points, [n], list(range(n)))
    scene = save_and_load(stage, device="cpu")
    assert scene.triangle_count == n - 2
    np.testing.assert_allclose(tri_area(scene).sum(), 0.5 * np.sum(r * np.roll(r, -1)) * math.sin(2 * math.pi / n),
                               rtol=1e-5)
    assert np.allclose(scene.normals, [0.0, 1.0, 0.0], atol=1e-6)


def test_non_convex_polygon_over_the_cap_is_refused(tmp_path):
    from cisp_warp.usd.mesh import MAX_EAR_CLIP_CORNERS

    n = MAX_EAR_CLIP_CORNERS + 2
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    r = np.where(np.arange(n) % 2 == 0, 1.0, 0.6)
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/Star", np.stack([r * np.cos(a), np.zeros(n), -r * np.sin(a)], axis=1), [n], list(range(n)))
    with pytest.raises(SceneError, match=r"s\.usda.*/World/Star.*not convex.*faceVertexCounts"):
        save_and_load(stage, device="cpu")


# ------------------------------------------------------------------------------ ranges (issue 16)


@pytest.mark.parametrize(
    "setup, keyword",
    [
        (lambda s: s.GetPrimAtPath("/World/Sun").GetAttribute("inputs:exposure").Set(128.0), "overflow float32"),
        (lambda s: s.GetPrimAtPath("/World/Sun").GetAttribute("inputs:intensity").Set(3e20), "overflow float32"),
        (lambda s: UsdGeom.SetStageMetersPerUnit(s, 1e9), "metersPerUnit"),
        (lambda s: UsdGeom.Xformable(s.GetPrimAtPath("/World/Floor")).AddScaleOp().Set((1e7, 1e7, 1e7)),
         "/World/Floor"),
    ],
)
def test_values_beyond_float32_or_the_scene_extent_are_refused(tmp_path, setup, keyword):
    stage = new_stage(tmp_path)
    stage.GetPrimAtPath("/World/Sun").GetAttribute("inputs:intensity").Set(3.0)
    UsdLux.LightAPI(stage.GetPrimAtPath("/World/Sun")).CreateExposureAttr(0.0)
    add_mesh(stage, "/World/Floor", UNIT_QUAD, [4], [0, 1, 2, 3])
    setup(stage)
    with pytest.raises(SceneError) as info:
        save_and_load(stage, device="cpu")
    assert keyword in str(info.value) and "s.usda" in str(info.value)


def test_water_resolution_is_limited_on_the_cpu_only(tmp_path):
    stage = new_stage(tmp_path)
    grid = [(0, 0.5, 0), (1, 0.5, 0), (0, 0.5, 1), (1, 0.5, 1)]
    water = add_mesh(stage, "/World/Water", grid, [4], [0, 2, 3, 1])
    water.GetPrim().CreateAttribute("cisp:water:resolution", Sdf.ValueTypeNames.Int).Set(2048)
    with pytest.raises(SceneError, match=r"/World/Water.*cisp:water:resolution = 2048.*CPU"):
        save_and_load(stage, device="cpu")
