"""Rasterizer against its naive twin (ray-cast G-buffer), and RSM flux against closed forms."""

import math

import numpy as np
import pytest
import trimesh
import warp as wp

from cisp_warp.raster import kernels as RK
from cisp_warp.raster import (GBuffer, LightMaps, Rasterizer, View, ViewParams, camera_view, light_views,
                              raycast_back_view, raycast_view)
from cisp_warp.scene import LAYER_OPAQUE, LAYER_SPECULAR, Camera, DeviceScene, Light, LightKind, Material, Scene
from cisp_warp.scene.model import look_at_matrix

WATER = Material("water", albedo=(1, 1, 1), roughness=0.0, opacity=0.0, ior=1.33)
WHITE = Material("white", albedo=(0.8, 0.8, 0.8), roughness=1.0)


def make_scene(parts, camera, lights=None):
    """parts: list of (points, faces, material index)."""
    pts, nrm, idx, mat = [], [], [], []
    off = 0
    for p, f, m in parts:
        mesh = trimesh.Trimesh(p, f, process=False)
        pts.append(np.asarray(p, np.float32))
        nrm.append(np.asarray(mesh.vertex_normals, np.float32))
        idx.append(np.asarray(f, np.int32) + off)
        mat.append(np.full(len(f), m, np.int32))
        off += len(p)
    lights = lights or [Light(LightKind.DISTANT, "sun", direction=(0.0, -1.0, 0.0), intensity=1.0)]
    return Scene(np.vstack(pts), np.vstack(nrm), np.vstack(idx), np.concatenate(mat), [WHITE, WATER], lights, camera)


def box_room():
    """A closed 2 m room (opaque), a water sheet across it, a sphere and a box inside."""
    room = trimesh.creation.box((2.0, 2.0, 2.0))
    room.invert()
    sphere = trimesh.creation.icosphere(2, radius=0.3)
    sphere.apply_translation((0.3, -0.5, 0.1))
    cube = trimesh.creation.box((0.4, 0.6, 0.4))
    cube.apply_transform(trimesh.transformations.rotation_matrix(0.5, (0, 1, 0)))
    cube.apply_translation((-0.4, -0.6, -0.3))
    n = 24
    g = np.linspace(-0.95, 0.95, n + 1)
    X, Z = np.meshgrid(g, g)
    Y = -0.4 + 0.03 * np.sin(5 * X) * np.cos(4 * Z)
    wpts = np.stack([X, Y, Z], -1).reshape(-1, 3)
    q = np.arange(n * (n + 1)).reshape(n, n + 1)[:, :n].reshape(-1)
    wf = np.concatenate([np.stack([q, q + n + 1, q + 1], -1), np.stack([q + 1, q + n + 1, q + n + 2], -1)])
    return [(room.vertices, room.faces, 0), (sphere.vertices, sphere.faces, 0), (cube.vertices, cube.faces, 0), (wpts, wf, 1)]


VIEWS = {
    "inside_perspective": dict(eye=(0.2, 0.3, 0.9), target=(-0.1, -0.6, -0.5), ortho=False),
    "oblique_perspective": dict(eye=(-0.8, 0.7, 0.8), target=(0.4, -0.8, -0.2), ortho=False),
    "top_orthographic": dict(eye=(0.1, 0.95, 0.05), target=(0.0, -1.0, 0.0), ortho=True),
}


def agreement(scene, view, layer, depth_key, tri_key, device):
    ds = DeviceScene(scene, device)
    g = GBuffer.allocate(view.width, view.height, device)
    g.render(Rasterizer(ds), view.params(), view.params())
    a = g.numpy()
    d_ray, t_ray = raycast_view(ds, view, layer)
    t_ras, d_ras = a[tri_key], a[depth_key]
    same = t_ras == t_ray
    both = (t_ras >= 0) & same
    rel = np.abs(d_ras[both] - d_ray[both]) / d_ray[both]
    return same.mean(), (rel.max() if rel.size else 0.0), both.sum()


@pytest.mark.parametrize("name", sorted(VIEWS))
def test_raster_matches_raycast_room(device, name):
    v = VIEWS[name]
    cam = Camera(look_at_matrix(v["eye"], v["target"]), fov_y=math.radians(70), ortho_height=1.2, near=0.02, far=10.0,
                 width=96, height=64, orthographic=v["ortho"])
    scene = make_scene(box_room(), cam)
    view = camera_view(cam)
    frac, rel, n = agreement(scene, view, LAYER_OPAQUE, "depth", "tri_id", device)
    assert n > 0.9 * 96 * 64  # the room fills the view
    assert frac >= 0.995, f"triangle id agrees on {frac:.4f} of pixels"
    assert rel <= 1e-4, f"depth differs by {rel:.2e} relative"
    # the raster's water layer is cut away behind opaque surfaces, the ray cast of the water alone is not:
    # compare depth where the raster kept a water pixel
    frac_w, rel_w, n_w = agreement(scene, view, LAYER_SPECULAR, "water_depth", "water_tri_id", device)
    assert n_w > 0
    assert rel_w <= 1e-4


@pytest.mark.parametrize("name", sorted(VIEWS))
def test_back_face_layer_matches_its_ray_cast(device, name):
    """The back-face layer (``Rasterizer.draw_back`` + ``kernels.resolve_back``) against its naive twin (every
    triangle against every pixel's ray): the nearest back face behind the front surface. In the room (walls facing
    in, nothing behind them) only the sphere's and the box's pixels have one, at or behind their front."""
    v = VIEWS[name]
    cam = Camera(look_at_matrix(v["eye"], v["target"]), fov_y=math.radians(70), ortho_height=1.2, near=0.02, far=10.0,
                 width=48, height=32, orthographic=v["ortho"])
    scene = make_scene(box_room(), cam)
    view = camera_view(cam)
    ds = DeviceScene(scene, device)
    g = GBuffer.allocate(view.width, view.height, device)
    g.render(Rasterizer(ds), view.params(), view.params())
    a = g.numpy()
    back = a["back_depth"]
    twin = raycast_back_view(ds, view, LAYER_OPAQUE, a["depth"], a["tri_id"])
    has, has_twin = back > 0, twin > 0
    assert (has == has_twin).mean() >= 0.99, f"back layer present on {(has == has_twin).mean():.4f} alike"
    both = has & has_twin
    assert both.sum() > 20  # the sphere and the box are in view
    rel = np.abs(back[both] - twin[both]) / twin[both]
    assert np.quantile(rel, 0.99) <= 1e-4, f"back depth differs by {np.quantile(rel, 0.99):.2e} relative"
    assert np.all(back[has] >= a["depth"][has])
    room_tris = len(trimesh.creation.box((2.0, 2.0, 2.0)).faces)  # the room's faces come first
    on_room = (a["tri_id"] >= 0) & (a["tri_id"] < room_tris)
    assert on_room.sum() > 0.5 * on_room.size and not has[on_room].any()  # walls facing in: nothing behind them
    g.back_faces = False  # switched off: no layer (not the last frame's), the depth as before
    g.render(Rasterizer(ds), view.params(), view.params())
    off = g.numpy()
    assert not off["back_depth"].any()
    np.testing.assert_array_equal(off["depth"], a["depth"])


def test_thin_and_fullscreen_triangles(device):
    """A triangle covering the whole screen (vertices far outside it, one behind the camera) and a
    one-pixel-thin sliver in front of it."""
    cam = Camera(look_at_matrix((0, 0, 0), (0, 0, -1)), fov_y=math.radians(60), near=0.05, far=50.0, width=80, height=60)
    big = (np.array([[-50.0, -40.0, -6.0], [60.0, -30.0, -7.0], [0.0, 50.0, 2.0]]), np.array([[0, 1, 2]]), 0)
    f = 0.5 * 60 / math.tan(math.radians(30))
    px = 1.0 / f * 2.0  # one pixel at depth 2 m
    sliver = (np.array([[-1.0, 0.1, -2.0], [1.0, 0.1 + px, -2.0], [1.0, 0.1, -2.0]]), np.array([[0, 1, 2]]), 0)
    scene = make_scene([big, sliver], cam)
    view = camera_view(cam)
    frac, rel, n = agreement(scene, view, LAYER_OPAQUE, "depth", "tri_id", device)
    ds = DeviceScene(scene, device)
    g = GBuffer.allocate(80, 60, device)
    g.render(Rasterizer(ds), view.params(), view.params())
    tri = g.numpy()["tri_id"]
    assert np.all(tri >= 0), "the full-screen triangle leaves holes"
    assert 0 < (tri == 1).sum() < 2 * 80, "the sliver is one pixel thin and about 40 pixels long"
    assert frac >= 0.995 and rel <= 1e-4


def _sphere_scene(material_index, light):
    s = trimesh.creation.icosphere(4, radius=1.0)
    s.invert()
    cam = Camera(look_at_matrix((0, 0, 0.5), (0, 0, 0)), width=16, height=16, near=0.01, far=5.0)
    return make_scene([(s.vertices, s.faces, material_index)], cam, [light])


def test_point_light_cube_flux_is_4pi_intensity(device):
    """A point light inside a closed specular sphere: its six faces send 4π·I watts, all onto the sphere."""
    light = Light(LightKind.POINT, "bulb", intensity=2.5, color=(1.0, 0.5, 0.25), position=(0.1, -0.05, 0.2))
    scene = _sphere_scene(1, light)
    ds = DeviceScene(scene, device)
    lm = LightMaps(ds, light, 32)
    lm.keep_texel_maps()  # the flux map kept (by default a reader computes it)
    lm.render(Rasterizer(ds))
    total = sum(r.flux.numpy().astype(np.float64).sum(axis=0) for r in lm.rsm)
    expected = 4 * math.pi * 2.5 * np.array([1.0, 0.5, 0.25])
    np.testing.assert_allclose(total, expected, rtol=1e-4)


def test_distant_light_flux_is_irradiance_times_projected_area(device):
    """A flat 1 m × 1.5 m water sheet under a distant light at 30°: flux = E⊥ · A · cos θ."""
    theta = math.radians(30.0)
    d = (math.sin(theta), -math.cos(theta), 0.0)
    light = Light(LightKind.DISTANT, "sun", intensity=800.0, direction=d)
    sheet = (np.array([[-0.5, 0, -0.75], [0.5, 0, -0.75], [0.5, 0, 0.75], [-0.5, 0, 0.75]]), np.array([[0, 2, 1], [0, 3, 2]]), 1)
    floor = (np.array([[-2, -1, -2], [2, -1, -2], [2, -1, 2], [-2, -1, 2]]), np.array([[0, 2, 1], [0, 3, 2]]), 0)
    cam = Camera(look_at_matrix((0, 2, 3), (0, 0, 0)), width=16, height=16)
    scene = make_scene([sheet, floor], cam, [light])
    ds = DeviceScene(scene, device)
    lm = LightMaps(ds, light, 256)
    lm.keep_texel_maps()  # the flux map kept (by default a reader computes it)
    lm.render(Rasterizer(ds))
    total = lm.rsm[0].flux.numpy().astype(np.float64).sum(axis=0)
    expected = 800.0 * 1.5 * math.cos(theta)
    # the sheet's edges cut texels: the error is at most the edge texels' share (~2/256 per side)
    np.testing.assert_allclose(total, expected, rtol=2e-2)
    spec = lm.rsm[0].specular.tri_id.numpy()
    assert (spec >= 0).mean() > 0.9  # the fit covers the water, not the floor


@wp.kernel
def _spot_falloffs(c: wp.array(dtype=wp.float32), cos_inner: float, cos_outer: float, cone: float, soft: float,
                   naive: wp.array(dtype=wp.float32), proven: wp.array(dtype=wp.float32)):
    i = wp.tid()
    naive[i] = RK.spot_falloff(c[i], cone, soft)
    proven[i] = RK.spot_falloff_proven(c[i], cos_inner, cos_outer, cone, soft)


@pytest.mark.parametrize("cone_deg, soft", [(35.0, 0.2), (8.0, 0.0), (30.0, 0.25), (60.0, 0.9), (100.0, 0.2),
                                            (179.0, 0.0), (20.0, 1.0), (20.0, 1.5), (0.0, 0.2), (0.01, 0.5)])
def test_spot_falloff_proven_is_spot_falloff(device, rng, cone_deg, soft):
    """``spot_falloff_proven`` (the emission's falloff: 1 from ``spot_cone_cosines``' inner bound up, 0 from its outer
    one down, no acos there) gives ``spot_falloff``'s bits for every float32 cosine within 2^14 ulps of either bound,
    of the inner angle's cosine and of the cone's, near 1 and above it (a normalized vector's rounding), near -1, and
    2^16 uniform in [-1.01, 1.01]; and the bounds prove almost all of the inner cone and of what lies beyond the cone
    (within 2^-11 of their angles, to float32), so the skips are not left out. A zero inner angle (softness >= 1, a
    zero cone) proves no inner cone."""
    cone = math.radians(cone_deg)
    c_in, c_out = RK.spot_cone_cosines(cone, soft)
    cone32 = float(np.float32(cone))
    inner32 = float(np.float32(cone) * (np.float32(1.0) - np.clip(np.float32(soft), np.float32(0.0), np.float32(1.0))))

    def f32_up(x):
        return float(np.nextafter(np.float32(x), np.float32(2.0)))

    def f32_down(x):
        return float(np.nextafter(np.float32(x), np.float32(-2.0)))

    if inner32 <= 0.0:
        assert c_in == RK.SPOT_COS_NONE
    else:
        assert c_in <= f32_up(math.cos(inner32 * (1.0 - 2.0 ** -11)))  # nearly all of the inner cone proven
    if cone32 <= 0.0 or cone32 * (1.0 + 2.0 ** -12) >= math.pi:
        assert c_out == -RK.SPOT_COS_NONE
    else:
        assert c_out >= f32_down(math.cos(cone32 * (1.0 + 2.0 ** -11)))  # nearly all beyond the cone proven
    assert c_out < c_in
    ulps = np.arange(-(1 << 14), 1 << 14, dtype=np.int32)
    parts = [rng.uniform(-1.01, 1.01, 1 << 16).astype(np.float32)]
    for centre in (np.clip(c_in, -1.0, 1.0), np.clip(c_out, -1.0, 1.0), math.cos(inner32), math.cos(cone32), 1.0,
                   -1.0):
        bits = np.array([centre], np.float32).view(np.int32)[0]
        parts.append((bits + ulps).view(np.float32))
    c = np.concatenate(parts).astype(np.float32)
    c = c[np.isfinite(c)]
    c_d = wp.array(c, dtype=wp.float32, device=device)
    naive, proven = wp.zeros(len(c), dtype=wp.float32, device=device), wp.zeros(len(c), dtype=wp.float32, device=device)
    wp.launch(_spot_falloffs, dim=len(c), device=device, inputs=[c_d, c_in, c_out, cone, soft, naive, proven])
    np.testing.assert_array_equal(proven.numpy().view(np.int32), naive.numpy().view(np.int32))
    if inner32 > 0.0:
        assert np.count_nonzero(c >= c_in) > 1 << 14  # the inner proof ran
    if c_out > -1.0:
        assert np.count_nonzero(c <= c_out) > 1 << 14  # the outer proof ran


def test_spot_flux_matches_cone_integral(device):
    """A spot light above a large specular plane: total flux = I · ∫ falloff dΩ over the cone."""
    cone, soft = math.radians(30.0), 0.25
    light = Light(LightKind.SPOT, "spot", intensity=3.0, position=(0, 1, 0), direction=(0, -1, 0), cone_angle=cone, cone_softness=soft)
    plane = (np.array([[-10, 0, -10], [10, 0, -10], [10, 0, 10], [-10, 0, 10]]), np.array([[0, 2, 1], [0, 3, 2]]), 1)
    cam = Camera(look_at_matrix((0, 2, 3), (0, 0, 0)), width=16, height=16)
    scene = make_scene([plane], cam, [light])
    ds = DeviceScene(scene, device)
    lm = LightMaps(ds, light, 256)
    lm.keep_texel_maps()  # the flux map kept (by default a reader computes it)
    lm.render(Rasterizer(ds))
    total = lm.rsm[0].flux.numpy().astype(np.float64).sum(axis=0)[0]
    a = np.linspace(0, cone, 20001)
    inner = cone * (1 - soft)
    s = np.clip((cone - a) / (cone - inner), 0, 1)
    f = np.where(a <= inner, 1.0, s * s * (3 - 2 * s))
    expected = 3.0 * 2 * math.pi * np.trapezoid(f * np.sin(a), a)
    np.testing.assert_allclose(total, expected, rtol=5e-3)


def test_motion_vectors_follow_camera(device):
    """A camera that moved sideways: motion points to where each surface point was in the previous frame."""
    cam0 = Camera(look_at_matrix((0, 0, 3), (0, 0, 0)), width=64, height=48, fov_y=math.radians(50))
    cam1 = Camera(look_at_matrix((0.1, 0, 3), (0.1, 0, 0)), width=64, height=48, fov_y=math.radians(50))
    wall = (np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]]), np.array([[0, 1, 2], [0, 2, 3]]), 0)
    scene = make_scene([wall], cam1)
    ds = DeviceScene(scene, device)
    g = GBuffer.allocate(64, 48, device)
    v0, v1 = camera_view(cam0), camera_view(cam1)
    g.render(Rasterizer(ds), v1.params(), v0.params())
    mv = g.numpy()["motion"]
    f = 0.5 * 48 / math.tan(math.radians(25))
    np.testing.assert_allclose(mv[..., 0], f * 0.1 / 3.0, rtol=1e-3)
    np.testing.assert_allclose(mv[..., 1], 0.0, atol=1e-3)


@pytest.mark.parametrize("room", ["closed", "open"])
def test_resolves_leave_visibility_clear_for_the_next_draw(device, room):
    """The frame draws without clearing its visibility buffers (``draw(clear=False)``): each resolve resets what it
    read. So after a frame every buffer is clear again, and a second frame from another camera and light pose is
    the frame a fresh renderer draws (a key left from the first would win the depth test where the second draws
    farther or nothing)."""
    cams = [Camera(look_at_matrix(e, (0.0, -0.5, 0.0)), fov_y=math.radians(70), near=0.02, far=10.0, width=48, height=32)
            for e in ((0.2, 0.3, 0.9), (-0.7, 0.8, 0.6))]
    lights = [Light(LightKind.SPOT, "spot", intensity=3.0, position=p, direction=(0, -1, 0), cone_angle=math.radians(50))
              for p in ((0.0, 0.9, 0.0), (0.4, 0.5, -0.3))]
    parts = box_room() if room == "closed" else box_room()[1:]  # open: pixels with no surface, which move
    scene = make_scene(parts, cams[0], [lights[0]])
    ds = DeviceScene(scene, device)
    raster = Rasterizer(ds)

    def frame(g, lm, k):
        if lm.light is not lights[k]:
            lm.set_light(lights[k])
        v = camera_view(cams[k]).params()
        g.render(raster, v, v)
        lm.render(raster)
        out = {f"cam_{a}": b for a, b in g.numpy().items()}
        for r in lm.rsm:
            out.update(r.numpy(prefix=f"{r.view.name}_"))
        return out

    g, lm = GBuffer.allocate(48, 32, device), LightMaps(ds, lights[0], 32)
    frame(g, lm, 0)
    empty = np.uint64(0xFFFFFFFFFFFFFFFF)
    buffers = [g.visibility, g.water.visibility] + [b for r in lm.rsm for b in (r.visibility, r.specular.visibility)]
    assert all(np.all(b.numpy() == empty) for b in buffers)
    second = frame(g, lm, 1)
    fresh = frame(GBuffer.allocate(48, 32, device), LightMaps(ds, lights[0], 32), 1)  # moved by set_light too
    assert second.keys() == fresh.keys()
    for k in second:
        np.testing.assert_array_equal(second[k], fresh[k], err_msg=k)
    assert (second["cam_water_tri_id"] >= 0).any() and (second["cam_tri_id"] >= 0).any()
    if room == "open":  # pixels that change between a surface and none, both ways
        first_tri = frame(GBuffer.allocate(48, 32, device), LightMaps(ds, lights[0], 32), 0)["cam_tri_id"]
        assert ((first_tri >= 0) & (second["cam_tri_id"] < 0)).any() and ((first_tri < 0) & (second["cam_tri_id"] >= 0)).any()


def test_rsm_shadow_depth_is_the_nearer_layer(device):
    """The specular resolve writes an RSM's shadow depth: the specular depth where there is a specular surface in
    front of the opaque one, else the opaque depth (0 where neither)."""
    light = Light(LightKind.SPOT, "spot", intensity=3.0, position=(0.0, 0.9, 0.0), direction=(0, -1, 0),
                  cone_angle=math.radians(50))
    cam = Camera(look_at_matrix((0.2, 0.3, 0.9), (0.0, -0.5, 0.0)), width=16, height=16)
    ds = DeviceScene(make_scene(box_room(), cam, [light]), device)
    lm = LightMaps(ds, light, 48)
    lm.render(Rasterizer(ds))
    r = lm.rsm[0]
    spec, opaque = r.specular.depth.numpy(), r.opaque_depth.numpy()
    assert (spec > 0).any() and ((spec == 0) & (opaque > 0)).any()
    np.testing.assert_array_equal(r.shadow_depth.numpy(), np.where(spec > 0, spec, opaque))


def test_two_layers_in_one_pass_draw_as_two_passes(device):
    """``draw(layer_b=..., visibility_b=...)`` (both layers of a view in one set-up and tile walk, as the frame draws
    them) fills each buffer exactly as its own draw does; a triangle in both layers lands in both."""
    cam = Camera(look_at_matrix((-0.8, 0.7, 0.8), (0.4, -0.8, -0.2)), fov_y=math.radians(70), near=0.02, far=10.0,
                 width=64, height=40)
    scene = make_scene(box_room(), cam)
    ds = DeviceScene(scene, device)
    layers = ds.triangle_layers.numpy()
    layers[::7] |= LAYER_OPAQUE | LAYER_SPECULAR  # some triangles in both layers (a mirror is both)
    ds.triangle_layers.assign(layers)
    raster = Rasterizer(ds)
    views = wp.array([camera_view(cam).params()], dtype=ViewParams, device=device)
    n = 64 * 40
    single = [wp.zeros(n, dtype=wp.uint64, device=device) for _ in range(2)]
    raster.draw(views, 0, 64, 40, LAYER_OPAQUE, single[0])
    raster.draw(views, 0, 64, 40, LAYER_SPECULAR, single[1])
    pair = [wp.zeros(n, dtype=wp.uint64, device=device) for _ in range(2)]
    raster.draw(views, 0, 64, 40, LAYER_OPAQUE, pair[0], layer_b=LAYER_SPECULAR, visibility_b=pair[1])
    empty = np.uint64(0xFFFFFFFFFFFFFFFF)
    for a, b in zip(single, pair):
        assert (a.numpy() != empty).any()
        np.testing.assert_array_equal(a.numpy(), b.numpy())
    dual = np.flatnonzero(layers == (LAYER_OPAQUE | LAYER_SPECULAR))
    for b in pair:  # the triangles of both layers show in both buffers
        assert np.isin(b.numpy() & np.uint64(0xFFFFFFFF), dual).any()


def test_rsm_resolve_flux_is_the_flux_pass(device):
    """The RSM's fused resolve writes per texel the flux ``rsm_flux`` (the separate pass, its twin) computes from the
    resolved specular layer, for a spot light (falloff), a point light's cube faces and a distant light."""
    cam = Camera(look_at_matrix((0.2, 0.3, 0.9), (0.0, -0.5, 0.0)), width=16, height=16)
    lights = [Light(LightKind.SPOT, "spot", intensity=3.0, position=(0.0, 0.9, 0.0), direction=(0, -1, 0),
                    cone_angle=math.radians(40), cone_softness=0.3),
              Light(LightKind.POINT, "bulb", intensity=2.0, position=(0.1, 0.2, 0.0)),
              Light(LightKind.DISTANT, "sun", intensity=500.0, direction=(0.3, -1.0, 0.1))]
    for light in lights:
        ds = DeviceScene(make_scene(box_room()[1:], cam, [light]), device)  # no room: the sun reaches the water
        lm = LightMaps(ds, light, 40)
        lm.keep_texel_maps()  # the flux map kept (by default a reader computes it)
        lm.render(Rasterizer(ds))
        for k, r in enumerate(lm.rsm):
            twin = wp.zeros_like(r.flux)
            wp.launch(RK.rsm_flux, dim=r.width * r.height, device=device,
                      inputs=[lm.views, k, wp.vec3(*light.radiometric_rgb.astype(np.float32)),
                              wp.vec3(*np.asarray(light.direction, np.float32)), int(light.kind == LightKind.SPOT),
                              float(light.cone_angle), float(light.cone_softness), r.solid_angle, r.specular.tri_id, twin])
            np.testing.assert_array_equal(r.flux.numpy(), twin.numpy())
        assert any((r.flux.numpy() > 0).any() for r in lm.rsm)


@wp.func
def _shared_edge_as_written(a: wp.vec3, b: wp.vec3, x: float, y: float) -> float:
    """The shared edge function as it was first written (main before the column raster): the reference."""
    if a[0] < b[0] or (a[0] == b[0] and a[1] < b[1]):
        return RK._edge(a, b, x, y)
    return -RK._edge(b, a, x, y)


@wp.kernel
def _edge_probe(a: wp.array(dtype=wp.vec3), b: wp.array(dtype=wp.vec3), xy: wp.array(dtype=wp.vec2),
                shared: wp.array(dtype=wp.float32), terms: wp.array(dtype=wp.float32)):
    k = wp.tid()
    shared[k] = _shared_edge_as_written(a[k], b[k], xy[k][0], xy[k][1])
    terms[k] = RK._edge_at(RK._edge_terms(a[k], b[k]), xy[k][0], xy[k][1])


def test_edge_terms_are_the_shared_edge(device, rng):
    """The edge values with the orientation folded into the terms (``_edge_terms``, what ``_shared_edge`` and the
    column raster evaluate) equal the shared edge function as first written bit for bit on the CPU (up to the sign
    of a zero), both orientations, with pixel centres on the edge and vertices with long fractions. (On CUDA the
    written form could contract differently per orientation: compared there only to 1 ulp of the products.)"""
    n = 4000
    a = (rng.uniform(-50, 300, (n, 3)) + rng.uniform(0, 1, (n, 3)) / 3).astype(np.float32)
    b = (rng.uniform(-50, 300, (n, 3)) + rng.uniform(0, 1, (n, 3)) / 7).astype(np.float32)
    b[: n // 4, 0] = a[: n // 4, 0]  # vertical edges: the tie-break on y
    t = rng.uniform(0, 1, (n, 1)).astype(np.float32)
    xy = (a[:, :2] + t * (b[:, :2] - a[:, :2])).astype(np.float32)  # on the edge, up to rounding
    xy[n // 2:] = (np.floor(rng.uniform(0, 256, (n - n // 2, 2))) + 0.5).astype(np.float32)
    out = [wp.zeros(n, dtype=wp.float32, device=device) for _ in range(2)]
    for p, q in ((a, b), (b, a)):
        wp.launch(_edge_probe, dim=n, device=device,
                  inputs=[wp.array(p, dtype=wp.vec3, device=device), wp.array(q, dtype=wp.vec3, device=device),
                          wp.array(xy, dtype=wp.vec2, device=device)] + out)
        shared, terms = out[0].numpy(), out[1].numpy()
        if wp.get_device(device).is_cpu:
            assert np.array_equal(shared, terms)  # == : +0 and -0 alike
        else:
            scale = np.abs(b[:, :2] - a[:, :2]).sum(1) * (np.abs(xy - a[:, :2]).sum(1) + np.abs(xy - b[:, :2]).sum(1))
            assert np.all(np.abs(shared - terms) <= 1.2e-7 * scale + 1e-30)
        assert (shared != 0).sum() > n // 2


@wp.kernel
def _column_probe(sub_v: wp.array(dtype=wp.vec3), sub_bbox: wp.array(dtype=wp.vec4i), out: wp.array(dtype=wp.int32)):
    """Per (triangle, pixel column, tile row): 1 covered, 2 skipped as outside, 4 no pixel covered."""
    s, i, ty = wp.tid()
    box = sub_bbox[s]
    col = box[0] + i
    j_lo = wp.max(ty * RK.TILE, box[1])
    j_hi = wp.min(ty * RK.TILE + RK.TILE - 1, box[3])
    if col > box[2] or j_lo > j_hi:
        return
    a, b, c = sub_v[3 * s], sub_v[3 * s + 1], sub_v[3 * s + 2]
    e0, e1, e2 = RK._edge_terms(b, c), RK._edge_terms(c, a), RK._edge_terms(a, b)
    x = float(col) + 0.5
    y0 = float(j_lo) + 0.5
    y1 = float(j_hi) + 0.5
    flags = int(0)
    if (RK._column_outside(e0, RK._edge_slack(e0, box), x, y0, y1) or RK._column_outside(e1, RK._edge_slack(e1, box), x, y0, y1)
            or RK._column_outside(e2, RK._edge_slack(e2, box), x, y0, y1)):
        flags = flags | 2
    hit = int(0)
    for j in range(j_lo, j_hi + 1):
        y = float(j) + 0.5
        if RK._shared_edge(b, c, x, y) >= 0.0 and RK._shared_edge(c, a, x, y) >= 0.0 and RK._shared_edge(a, b, x, y) >= 0.0:
            hit = 1
    if hit == 0:
        flags = flags | 4
    out[(s * 64 + i) * 8 + ty] = flags | hit


def test_columns_skipped_only_where_nothing_is_covered(device, rng):
    """``_column_outside`` skips no column with a covered pixel centre (long thin triangles, edges through pixel
    centres, vertices far off screen), and skips most columns with none (it is what makes the column raster fast)."""
    n = 300
    v = rng.uniform(-20, 84, (n, 3, 3)).astype(np.float32)
    v[: n // 3, 1] = v[: n // 3, 0] + rng.uniform(-3, 3, (n // 3, 3)).astype(np.float32)  # slivers
    v[n // 3: n // 2, :, :2] = np.round(v[n // 3: n // 2, :, :2] * 2) / 2  # vertices on pixel centres and edges
    v[n // 2: n // 2 + 20, 2, :2] = rng.uniform(-3e4, 3e4, (20, 2)).astype(np.float32)  # far off screen
    area = (v[:, 1, 0] - v[:, 0, 0]) * (v[:, 2, 1] - v[:, 0, 1]) - (v[:, 2, 0] - v[:, 0, 0]) * (v[:, 1, 1] - v[:, 0, 1])
    v[area < 0] = v[area < 0][:, [0, 2, 1]]  # counter-clockwise, as setup_triangles leaves them
    lo = np.clip(np.ceil(v[..., :2].min(1) - 0.5), 0, 63).astype(np.int32)
    hi = np.clip(np.floor(v[..., :2].max(1) - 0.5), 0, 63).astype(np.int32)
    box = np.concatenate([lo, hi], 1)
    keep = (box[:, 0] <= box[:, 2]) & (box[:, 1] <= box[:, 3]) & (np.abs(area) > 1e-3)
    v, box = v[keep], box[keep]
    m = len(v)
    out = wp.zeros(m * 64 * 8, dtype=wp.int32, device=device)
    wp.launch(_column_probe, dim=(m, 64, 8), device=device,
              inputs=[wp.array(v.reshape(-1, 3), dtype=wp.vec3, device=device), wp.array(box, dtype=wp.vec4i, device=device), out])
    f = out.numpy()
    covered, skipped, empty = (f & 1) > 0, (f & 2) > 0, (f & 4) > 0
    assert covered.sum() > 1000 and empty.sum() > 1000
    assert not (covered & skipped).any(), "a column with a covered pixel was skipped"
    assert (skipped & empty).sum() >= 0.9 * empty.sum()


@pytest.mark.parametrize("stride", [64, 1024, 1 << 14])
def test_column_raster_is_the_tile_raster(device, stride):
    """``raster_tile_columns`` (a thread per pixel column, columns outside an edge skipped, a group of threads over
    consecutive items) fills both layers' buffers exactly as its twin ``raster_tiles``, for perspective and
    orthographic views, near-clipped and full-screen triangles and one-pixel slivers, with groups that take many
    items (stride 64: groups cross many sub-triangles) or at most one (1 << 14: most groups idle)."""
    cam = Camera(look_at_matrix((0, 0, 0), (0, 0, -1)), fov_y=math.radians(60), near=0.05, far=50.0, width=80, height=60)
    big = (np.array([[-50.0, -40.0, -6.0], [60.0, -30.0, -7.0], [0.0, 50.0, 2.0]]), np.array([[0, 1, 2]]), 0)
    sliver = (np.array([[-1.0, 0.1, -2.0], [1.0, 0.13, -2.0], [1.0, 0.1, -2.0]]), np.array([[0, 1, 2]]), 1)
    ds = DeviceScene(make_scene([big, sliver] + box_room(), cam), device)  # the room hides the big one: drawn all the same
    raster = Rasterizer(ds)
    raster.stride, raster.column_threads = stride, None  # both kernels launch `stride` threads, on every device
    raster.reject = False  # columns off: the naive twin raster_tiles
    views = [camera_view(cam).params()] + [camera_view(Camera(look_at_matrix(v["eye"], v["target"]), fov_y=math.radians(70),
                                                              ortho_height=1.2, near=0.02, far=10.0, width=72, height=40,
                                                              orthographic=v["ortho"])).params() for v in VIEWS.values()]
    empty = np.uint64(0xFFFFFFFFFFFFFFFF)
    for k, vp in enumerate(views):
        n = vp.width * vp.height
        arr = wp.array([vp], dtype=ViewParams, device=device)
        out = []
        for columns in (False, True):
            raster.columns = columns
            bufs = [wp.full(n, RK.EMPTY_KEY_VALUE, dtype=wp.uint64, device=device) for _ in range(2)]
            raster.draw(arr, 0, vp.width, vp.height, LAYER_OPAQUE, bufs[0], clear=False, layer_b=LAYER_SPECULAR,
                        visibility_b=bufs[1])
            out.append([b.numpy() for b in bufs])
        for naive, fast in zip(*out):
            if not wp.get_device(device).is_cuda:
                np.testing.assert_array_equal(fast, naive, err_msg=f"view {k}")
                continue
            # CUDA contracts the edge and depth products into FMAs differently in the two kernels (the same source
            # compiles to different roundings): keys may differ by ulps of depth, and a pixel centre on an edge may
            # go to the other triangle of the edge (its depth there 1e-5 off). Covered pixels agree but for such centres, depths to 1e-4.
            both = (fast != empty) & (naive != empty)
            assert ((fast != empty) != (naive != empty)).mean() <= 0.01, f"view {k}"
            np.testing.assert_allclose(key_depths(fast[both], vp.far), key_depths(naive[both], vp.far), rtol=1e-4,
                                       atol=0, err_msg=f"view {k}")
        assert (out[0][0] != empty).mean() > 0.5 and (out[0][1] != empty).any()


@wp.kernel
def _box_probe(sub_v: wp.array(dtype=wp.vec3), sub_bbox: wp.array(dtype=wp.vec4i), out: wp.array(dtype=wp.int32)):
    """Per (triangle, 8x8 tile of its box): 1 covered, 2 rejected as outside an edge, 4 no pixel covered."""
    s, tx, ty = wp.tid()
    box = sub_bbox[s]
    i_lo = wp.max(tx * RK.TILE, box[0])
    i_hi = wp.min(tx * RK.TILE + RK.TILE - 1, box[2])
    j_lo = wp.max(ty * RK.TILE, box[1])
    j_hi = wp.min(ty * RK.TILE + RK.TILE - 1, box[3])
    if i_lo > i_hi or j_lo > j_hi:
        return
    a, b, c = sub_v[3 * s], sub_v[3 * s + 1], sub_v[3 * s + 2]
    e0, e1, e2 = RK._edge_terms(b, c), RK._edge_terms(c, a), RK._edge_terms(a, b)
    tile = wp.vec4i(i_lo, j_lo, i_hi, j_hi)
    flags = int(0)
    if (RK._box_outside(e0, RK._edge_slack(e0, tile), tile) or RK._box_outside(e1, RK._edge_slack(e1, tile), tile)
            or RK._box_outside(e2, RK._edge_slack(e2, tile), tile)):
        flags = flags | 2
    hit = int(0)
    for j in range(j_lo, j_hi + 1):
        for i in range(i_lo, i_hi + 1):
            x = float(i) + 0.5
            y = float(j) + 0.5
            if RK._shared_edge(b, c, x, y) >= 0.0 and RK._shared_edge(c, a, x, y) >= 0.0 and RK._shared_edge(a, b, x, y) >= 0.0:
                hit = 1
    if hit == 0:
        flags = flags | 4
    out[(s * 8 + tx) * 8 + ty] = flags | hit


def test_tiles_rejected_only_where_nothing_is_covered(device, rng):
    """``_box_outside`` (``raster_tiles_reject``'s tile reject) rejects no tile with a covered pixel centre (slivers, edges
    through pixel centres, vertices far off screen), and most tiles with none."""
    n = 300
    v = rng.uniform(-20, 84, (n, 3, 3)).astype(np.float32)
    v[: n // 3, 1] = v[: n // 3, 0] + rng.uniform(-3, 3, (n // 3, 3)).astype(np.float32)  # slivers
    v[n // 3: n // 2, :, :2] = np.round(v[n // 3: n // 2, :, :2] * 2) / 2  # vertices on pixel centres and edges
    v[n // 2: n // 2 + 20, 2, :2] = rng.uniform(-3e4, 3e4, (20, 2)).astype(np.float32)  # far off screen
    area = (v[:, 1, 0] - v[:, 0, 0]) * (v[:, 2, 1] - v[:, 0, 1]) - (v[:, 2, 0] - v[:, 0, 0]) * (v[:, 1, 1] - v[:, 0, 1])
    v[area < 0] = v[area < 0][:, [0, 2, 1]]  # counter-clockwise, as setup_triangles leaves them
    lo = np.clip(np.ceil(v[..., :2].min(1) - 0.5), 0, 63).astype(np.int32)
    hi = np.clip(np.floor(v[..., :2].max(1) - 0.5), 0, 63).astype(np.int32)
    box = np.concatenate([lo, hi], 1)
    keep = (box[:, 0] <= box[:, 2]) & (box[:, 1] <= box[:, 3]) & (np.abs(area) > 1e-3)
    v, box = v[keep], box[keep]
    m = len(v)
    out = wp.zeros(m * 64, dtype=wp.int32, device=device)
    wp.launch(_box_probe, dim=(m, 8, 8), device=device,
              inputs=[wp.array(v.reshape(-1, 3), dtype=wp.vec3, device=device), wp.array(box, dtype=wp.vec4i, device=device), out])
    f = out.numpy()
    covered, rejected, empty = (f & 1) > 0, (f & 2) > 0, (f & 4) > 0
    assert covered.sum() > 500 and empty.sum() > 500
    assert not (covered & rejected).any(), "a tile with a covered pixel was rejected"
    assert (rejected & empty).sum() >= 0.7 * empty.sum()


@pytest.mark.parametrize("stride", [64, 1 << 14])
def test_reject_and_row_rasters_are_the_tile_raster(device, stride):
    """``raster_tiles_reject`` (tiles proven outside an edge skipped) and ``raster_tile_rows`` (a thread per tile row,
    rows outside an edge skipped) fill both layers' buffers exactly as their naive twin ``raster_tiles``: perspective
    and orthographic views, near-clipped and full-screen triangles, a one-pixel sliver; threads that take many items
    (stride 64) or at most one (1 << 14)."""
    cam = Camera(look_at_matrix((0, 0, 0), (0, 0, -1)), fov_y=math.radians(60), near=0.05, far=50.0, width=80, height=60)
    big = (np.array([[-50.0, -40.0, -6.0], [60.0, -30.0, -7.0], [0.0, 50.0, 2.0]]), np.array([[0, 1, 2]]), 0)
    sliver = (np.array([[-1.0, 0.1, -2.0], [1.0, 0.13, -2.0], [1.0, 0.1, -2.0]]), np.array([[0, 1, 2]]), 1)
    ds = DeviceScene(make_scene([big, sliver] + box_room(), cam), device)
    raster = Rasterizer(ds)
    raster.stride = stride
    views = [camera_view(cam).params()] + [camera_view(Camera(look_at_matrix(v["eye"], v["target"]), fov_y=math.radians(70),
                                                              ortho_height=1.2, near=0.02, far=10.0, width=72, height=40,
                                                              orthographic=v["ortho"])).params() for v in VIEWS.values()]
    empty = np.uint64(0xFFFFFFFFFFFFFFFF)
    for k, vp in enumerate(views):
        n = vp.width * vp.height
        arr = wp.array([vp], dtype=ViewParams, device=device)
        out = []
        for reject, rows_max in ((False, 0), (True, 0), (True, 1 << 30)):  # raster_tiles, _reject, raster_tile_rows
            raster.reject, raster.rows_max_pixels = reject, rows_max
            bufs = [wp.full(n, RK.EMPTY_KEY_VALUE, dtype=wp.uint64, device=device) for _ in range(2)]
            raster.draw(arr, 0, vp.width, vp.height, LAYER_OPAQUE, bufs[0], clear=False, layer_b=LAYER_SPECULAR,
                        visibility_b=bufs[1])
            out.append([b.numpy().copy() for b in bufs])
        for fast_run in out[1:]:
            for naive, fast in zip(out[0], fast_run):
                if not wp.get_device(device).is_cuda:
                    np.testing.assert_array_equal(fast, naive, err_msg=f"view {k}")
                    continue
                # CUDA may contract the edge and depth products into FMAs differently in the two kernels (section 24)
                both = (fast != empty) & (naive != empty)
                assert ((fast != empty) != (naive != empty)).mean() <= 0.01, f"view {k}"
                np.testing.assert_allclose(key_depths(fast[both], vp.far), key_depths(naive[both], vp.far),
                                           rtol=1e-4, atol=0, err_msg=f"view {k}")
        assert (out[0][0] != empty).mean() > 0.5 and (out[0][1] != empty).any()


def _rsm_frame(ds, light, size, fused, frames, thickness=(0.03, 0.02), surface=False, texel_maps=False):
    """Every buffer of a light's RSM views after ``frames`` (light poses) drawn with the fused resolve or its twins,
    and the depth bounds of each view's opaque depth (written by the fused resolve; built by ``photons.cisp``'s
    ``build_bounds``, the twin kernels ``depth_bounds`` + ``coarsen_bounds``, otherwise)."""
    from cisp_warp.photons.cisp import build_bounds
    from cisp_warp.photons.march import bounds_size

    raster = Rasterizer(ds)
    lm = LightMaps(ds, frames[0], size)
    lm.fused_resolve = fused
    if surface:  # the specular layers keep their position and normal (LightMaps.keep_surface_maps)
        lm.keep_surface_maps()
    if texel_maps:  # the views keep their flux and their layers' roughness and IOR (LightMaps.keep_texel_maps)
        lm.keep_texel_maps()
    bounds = [wp.full(bounds_size(r.width, r.height), wp.vec2(-1.0, -1.0), dtype=wp.vec2, device=ds.device)
              for r in lm.rsm]
    lm.keep_depth_bounds(bounds, *thickness)
    for light in frames:
        if lm.light is not light:
            lm.set_light(light)
        lm.render(raster)
    out = {}
    for k, r in enumerate(lm.rsm):
        if not lm.builds_depth_bounds(bounds[k]):
            build_bounds(r.opaque_depth, r.width, r.height, *thickness, bounds[k], ds.device, lm.views, k)
        out.update(r.numpy(prefix=f"{k}_"))
        out[f"{k}_opaque_tri"] = r.opaque_tri.numpy()
        out[f"{k}_visibility"] = r.visibility.numpy()
        out[f"{k}_specular_visibility"] = r.specular.visibility.numpy()
        out[f"{k}_bounds"] = bounds[k].numpy()
    return out


@pytest.mark.parametrize("size", [48, 70])
def test_fused_rsm_resolve_is_its_twins(device, size):
    """``resolve_rsm_view`` (one tiled pass per RSM view: opaque depth, specular layer, shadow depth, flux and the
    depth bounds) fills every buffer exactly as its twins ``resolve_depth`` + ``resolve_rsm_specular`` and the
    bounds exactly as ``depth_bounds`` + ``coarsen_bounds``: a spot light moved between two frames (texels that
    lose and gain the water both ways), a point light's cube faces, a distant light, on views that are not a
    multiple of a coarse cell (70: partial fine and coarse cells at the edges)."""
    cam = Camera(look_at_matrix((0.2, 0.3, 0.9), (0.0, -0.5, 0.0)), width=16, height=16)
    spots = [Light(LightKind.SPOT, "spot", intensity=3.0, position=p, direction=d, cone_angle=math.radians(40),
                   cone_softness=0.3) for p, d in (((0.0, 0.9, 0.0), (0, -1, 0)), ((0.5, 0.6, -0.3), (-0.3, -1, 0.2)))]
    cases = [(box_room(), spots), (box_room(), [Light(LightKind.POINT, "bulb", intensity=2.0, position=(0.1, 0.2, 0.0))]),
             (box_room()[1:], [Light(LightKind.DISTANT, "sun", intensity=500.0, direction=(0.3, -1.0, 0.1))])]
    for parts, frames in cases:
        ds = DeviceScene(make_scene(parts, cam, frames[:1]), device)
        # without the specular layer's position and normal, the flux, roughness and IOR (the default), and with
        for surface, texel_maps in ((False, False), (True, False), (False, True)):
            fused = _rsm_frame(ds, frames[0], size, True, frames, surface=surface, texel_maps=texel_maps)
            twins = _rsm_frame(ds, frames[0], size, False, frames, surface=surface, texel_maps=texel_maps)
            assert fused.keys() == twins.keys()
            assert ("0_specular_position" in fused) == surface and ("0_specular_normal" in fused) == surface
            assert all((f"0_{a}" in fused) == texel_maps for a in ("flux", "specular_roughness", "specular_ior"))
            for k in fused:
                np.testing.assert_array_equal(fused[k], twins[k], err_msg=f"{frames[0].name} {k}")
            b = fused["0_bounds"]
            assert (b[:, 0] < 1e29).any() and (b[:, 1] > 0).all()  # real surfaces bounded, every cell written
    lm = LightMaps(ds, frames[0], size)
    with pytest.raises(ValueError, match="bounds_size"):  # a bounds array the kernel would write past
        lm.keep_depth_bounds([wp.zeros(len(b) - 1, dtype=wp.vec2, device=device) for _ in lm.rsm], 0.03, 0.02)
        assert any((fused[f"{k}_specular_tri_id"] >= 0).any() for k in range(len([x for x in fused if x.endswith("_bounds")])))


@wp.kernel
def _texel_surface_of_layer(views: wp.array(dtype=ViewParams), k: int, tri_id: wp.array(dtype=wp.int32),
                            depth: wp.array(dtype=wp.float32), points: wp.array(dtype=wp.vec3),
                            normals: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32),
                            x_out: wp.array(dtype=wp.vec3), n_out: wp.array(dtype=wp.vec3)):
    p = wp.tid()
    tri = tri_id[p]
    if tri >= 0:
        x, n = RK.texel_surface(views[k], p, tri, depth[p], points, normals, indices)
        x_out[p] = x
        n_out[p] = n


def depth_keys(depth, far):
    """The high halves of the visibility keys of float32 depths in (0, far] (``RK.depth_key``'s two forms)."""
    depth = np.asarray(depth, np.float32)
    if RK.DEPTH_KEY_BITS:
        return depth.view(np.uint32).astype(np.uint64) << np.uint64(32)
    q = np.minimum(depth.astype(np.float64) / np.float64(np.float32(far)), 1.0) * float(RK.DEPTH_STEPS)
    return q.astype(np.uint64) << np.uint64(32)


def key_depths(keys, far):
    """The depths [m] non-empty visibility keys hold (``RK.key_depth``), as float64."""
    hi = np.asarray(keys, np.uint64) >> np.uint64(32)
    if RK.DEPTH_KEY_BITS:
        return hi.astype(np.uint32).view(np.float32).astype(np.float64)
    return hi.astype(np.float64) / float(RK.DEPTH_STEPS) * np.float64(np.float32(far))


def _bits(a):
    return np.ascontiguousarray(a, dtype=np.float32).view(np.uint32)


def test_texel_surface_is_what_the_resolve_writes(device, rng):
    """``texel_surface`` (the point and normal a reader computes from a specular texel's triangle and depth, for RSM
    views that keep no position and normal) gives, on every covered texel, the bits ``resolve_rsm_view`` writes
    into ``position`` and ``normal`` where they are kept: random spot, point and distant lights over the room (its
    sphere, box and wavy water), two poses each (texels that gain and lose the water), odd view sizes."""
    cam = Camera(look_at_matrix((0.2, 0.3, 0.9), (0.0, -0.5, 0.0)), width=16, height=16)
    covered = 0
    for trial in range(6):
        kind = (LightKind.SPOT, LightKind.POINT, LightKind.DISTANT)[trial % 3]
        frames = []
        for _ in range(2):
            pos = tuple(float(v) for v in rng.uniform((-0.6, 0.5, -0.6), (0.6, 0.9, 0.6)))
            aim = rng.uniform((-0.4, -1.0, -0.4), (0.4, -0.6, 0.4))
            frames.append(Light(kind, f"l{trial}", intensity=2.0, position=pos, direction=tuple(float(v) for v in aim),
                                cone_angle=math.radians(float(rng.uniform(25, 60))), cone_softness=0.2))
        parts = box_room()[1:] if kind == LightKind.DISTANT else box_room()  # no room: the sun reaches the water
        ds = DeviceScene(make_scene(parts, cam, frames[:1]), device)
        size = int(rng.integers(40, 72))
        raster = Rasterizer(ds)
        lm = LightMaps(ds, frames[0], size)
        assert not any(r.specular.has_surface for r in lm.rsm)  # the default: no position and normal kept
        assert lm.rsm[0].specular.position.shape == (0,)
        lm.keep_surface_maps()
        for light in frames:
            if lm.light is not light:
                lm.set_light(light)
            lm.render(raster)
            for k, r in enumerate(lm.rsm):
                sp = r.specular
                x_t, n_t = wp.zeros_like(sp.position), wp.zeros_like(sp.normal)
                wp.launch(_texel_surface_of_layer, dim=r.width * r.height, device=device,
                          inputs=[lm.views, k, sp.tri_id, sp.depth, ds.points, ds.normals, ds.indices, x_t, n_t])
                on = sp.tri_id.numpy() >= 0
                covered += int(on.sum())
                np.testing.assert_array_equal(_bits(x_t.numpy()[on]), _bits(sp.position.numpy()[on]))
                np.testing.assert_array_equal(_bits(n_t.numpy()[on]), _bits(sp.normal.numpy()[on]))
    assert covered > 5000


@wp.kernel
def _texel_emission_of_layer(views: wp.array(dtype=ViewParams), k: int, tri_id: wp.array(dtype=wp.int32),
                             emission: RK.TexelEmission, flux_out: wp.array(dtype=wp.vec3),
                             roughness_out: wp.array(dtype=wp.float32), ior_out: wp.array(dtype=wp.float32),
                             flux_at_out: wp.array(dtype=wp.vec3)):
    j, i = wp.tid()  # the texel's row and column, as the emission has them (no division of p)
    view = views[k]
    p = j * view.width + i
    tri = tri_id[p]
    if tri >= 0:
        flux_out[p] = RK.texel_emitted_flux(emission, view, p)
        flux_at_out[p] = RK.texel_emitted_flux_at(emission, view, p, i, j)
        roughness_out[p] = RK.texel_roughness(emission, tri)
        ior_out[p] = RK.texel_ior(emission, tri)


def test_texel_emission_is_what_the_resolve_writes(device, rng):
    """``TexelEmission`` (a specular texel's flux, roughness and IOR as a reader computes them from the light, its
    triangle and the materials, for RSM views that keep no such maps) gives, on every covered texel, the bits
    ``resolve_rsm_view`` writes into ``flux``, ``roughness`` and ``ior`` where they are kept, and a texel without a
    specular surface has zero flux there (what ``max_luminance`` and ``book_outside_window`` assume); the emission's
    ``texel_emitted_flux_at`` (column and row given; the spot's falloff proven from the cosine inside the inner cone
    and beyond the cone, ``spot_falloff_proven``) the same bits as the resolve's naive ``texel_flux``: random spot,
    point and distant lights over the room with two materials on the water side (its sphere and box are specular
    too), two poses each, odd sizes; fitted views (cascades and their pilots) beside whole ones."""
    from cisp_warp.raster import LightViewSettings

    cam = Camera(look_at_matrix((0.2, 0.3, 0.9), (0.0, -0.5, 0.0)), width=16, height=16)
    covered = 0
    for trial in range(6):
        kind = (LightKind.SPOT, LightKind.POINT, LightKind.DISTANT)[trial % 3]
        frames = []
        for _ in range(2):
            pos = tuple(float(v) for v in rng.uniform((-0.6, 0.5, -0.6), (0.6, 0.9, 0.6)))
            aim = rng.uniform((-0.4, -1.0, -0.4), (0.4, -0.6, 0.4))
            frames.append(Light(kind, f"l{trial}", intensity=float(rng.uniform(0.5, 3.0)), color=(1.0, 0.7, 0.4),
                                position=pos, direction=tuple(float(v) for v in aim),
                                cone_angle=math.radians(float(rng.uniform(25, 60))), cone_softness=0.2))
        parts = box_room()[1:] if kind == LightKind.DISTANT else box_room()  # no room: the sun reaches the water
        ds = DeviceScene(make_scene(parts, cam, frames[:1]), device)
        size = int(rng.integers(40, 72))
        raster = Rasterizer(ds)
        settings = LightViewSettings(fit="camera", pilot_size=24) if trial >= 3 else None
        lm = LightMaps(ds, frames[0], size, settings)
        assert not any(r.has_texel_maps or r.specular.has_material for r in lm.rsm + lm.pilot)  # the default
        assert lm.rsm[0].flux.shape == (0,) and lm.rsm[0].specular.ior.shape == (0,)
        lm.keep_texel_maps()
        for light in frames:
            if lm.light is not light:
                lm.set_light(light)
            if lm.fitted:
                lm.render_pilot(raster)
            lm.render(raster)
            for views, maps in ((lm.views, lm.rsm), (lm.pilot_views, lm.pilot)):
                for k, r in enumerate(maps):
                    sp = r.specular
                    f_t, r_t, i_t = wp.zeros_like(r.flux), wp.zeros_like(sp.roughness), wp.zeros_like(sp.ior)
                    fa_t = wp.zeros_like(r.flux)
                    wp.launch(_texel_emission_of_layer, dim=(r.height, r.width), device=device,
                              inputs=[views, k, sp.tri_id, lm.emission(r), f_t, r_t, i_t, fa_t])
                    on = sp.tri_id.numpy() >= 0
                    covered += int(on.sum())
                    np.testing.assert_array_equal(_bits(f_t.numpy()[on]), _bits(r.flux.numpy()[on]))
                    np.testing.assert_array_equal(_bits(fa_t.numpy()[on]), _bits(r.flux.numpy()[on]))
                    np.testing.assert_array_equal(_bits(r_t.numpy()[on]), _bits(sp.roughness.numpy()[on]))
                    np.testing.assert_array_equal(_bits(i_t.numpy()[on]), _bits(sp.ior.numpy()[on]))
                    assert not r.flux.numpy()[~on].any()
    assert covered > 5000


@wp.kernel
def _hit_and_surface(views: wp.array(dtype=ViewParams), keys: wp.array(dtype=wp.uint64),
                     pixels: wp.array(dtype=wp.int32), points: wp.array(dtype=wp.vec3),
                     normals: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32),
                     hit: wp.array(dtype=wp.vec3), surf: wp.array(dtype=wp.vec3)):
    """Per probe i: triangle_hit's point and interpolated normal (what specular_texel_key writes) at hit[2i], [2i+1];
    texel_surface's from its triangle and depth at surf[2i], [2i+1]."""
    i = wp.tid()
    view = views[0]
    tri, t, x, bary, d = RK.triangle_hit(view, keys[i], pixels[i], points, indices)
    hit[2 * i] = x
    hit[2 * i + 1] = RK.interp_normal(tri, bary, normals, indices)
    xs, ns = RK.texel_surface(view, pixels[i], tri, t, points, normals, indices)
    surf[2 * i] = xs
    surf[2 * i + 1] = ns


def test_texel_surface_of_a_ray_in_the_triangles_plane(device, rng):
    """A pixel ray in its triangle's plane (triangle_hit falls back to the key's depth and barycentrics
    (1, 0, 0)): texel_surface gives the same point and normal from that depth. An orthographic view looking down -z
    (its rays exactly along -z) and triangles in planes x = const, which contain every ray; beside them triangles
    in general position (the ordinary case) and triangles the ray misses (clamped barycentrics)."""
    w = h = 16
    view = ViewParams()
    view.world_to_view = wp.mat44(*np.eye(4, dtype=np.float32).ravel())
    view.view_to_world = wp.mat44(*np.eye(4, dtype=np.float32).ravel())
    view.fx = view.fy = 8.0
    view.cx, view.cy = w / 2.0, h / 2.0
    view.near, view.far = 0.01, 10.0
    view.width, view.height, view.orthographic = w, h, 1
    n_in, n_gen = 40, 200
    x0 = rng.uniform(-1, 1, n_in)
    in_plane = np.stack([np.stack([np.full(n_in, 0.0), rng.uniform(-1, 1, n_in), rng.uniform(-5, -1, n_in)], -1)
                         for _ in range(3)], 1)
    in_plane[:, :, 0] = x0[:, None]
    general = rng.uniform((-1, -1, -5), (1, 1, -1), (n_gen, 3, 3))
    pts = np.concatenate([in_plane, general]).reshape(-1, 3).astype(np.float32)
    nrm = rng.normal(size=pts.shape).astype(np.float32)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    tris = n_in + n_gen
    depth = rng.uniform(0.05, 9.5, tris).astype(np.float32)
    keys = depth_keys(depth, view.far) | np.arange(tris, dtype=np.uint64)
    pixels = rng.integers(0, w * h, tris).astype(np.int32)
    arr = lambda a, t: wp.array(a, dtype=t, device=device)  # noqa: E731
    hit, surf = wp.zeros(2 * tris, dtype=wp.vec3, device=device), wp.zeros(2 * tris, dtype=wp.vec3, device=device)
    wp.launch(_hit_and_surface, dim=tris, device=device,
              inputs=[arr([view], ViewParams), arr(keys, wp.uint64), arr(pixels, wp.int32), arr(pts, wp.vec3),
                      arr(nrm, wp.vec3), arr(np.arange(3 * tris, dtype=np.int32), wp.int32), hit, surf])
    h_np, s_np = hit.numpy(), surf.numpy()
    np.testing.assert_array_equal(_bits(s_np), _bits(h_np))
    # the in-plane probes took the fallback: the vertex normal of corner 0, the point at the key's depth
    np.testing.assert_allclose(h_np[1:2 * n_in:2], nrm[0:3 * n_in:3], atol=3e-7)  # (normalised again)
    np.testing.assert_allclose(-h_np[0:2 * n_in:2, 2], key_depths(keys[:n_in], view.far), rtol=1e-6)


@pytest.mark.parametrize("size", [(48, 32), (70, 45)])
def test_fused_back_resolve_is_its_twins(device, size):
    """``resolve_camera`` (both layers of the camera in one pass) fills every G-buffer AOV exactly as
    ``resolve_opaque`` + ``resolve_specular``, and ``resolve_back_view`` (the camera's back-face layer and the depth
    bounds of both layers in one tiled pass) fills ``depth_layers`` exactly as ``resolve_back`` and the bounds exactly as ``depth_bounds`` (with the back-face
    layer) + ``coarsen_bounds``, from two cameras in a closed room and an open one (pixels with no surface), on
    images that are not a multiple of a coarse cell."""
    from cisp_warp.photons.cisp import build_bounds
    from cisp_warp.photons.march import bounds_size

    w, h = size
    cams = [Camera(look_at_matrix(e, t), fov_y=math.radians(70), near=0.02, far=10.0, width=w, height=h)
            for e, t in (((-0.7, 0.8, 0.6), (0.0, -0.5, 0.0)), ((0.3, -0.3, 0.75), (0.3, -0.5, 0.1)))]  # then the sphere near
    for parts in (box_room(), box_room()[1:]):
        ds = DeviceScene(make_scene(parts, cams[0]), device)
        raster = Rasterizer(ds)
        out = []
        for fused in (True, False):
            g = GBuffer.allocate(w, h, device)
            g.fused_resolve = g.fused_layers = fused
            bounds = wp.full(bounds_size(w, h), wp.vec2(-1.0, -1.0), dtype=wp.vec2, device=device)
            g.keep_depth_bounds(bounds, 0.03, 0.02)
            prev = camera_view(cams[0]).params()
            for cam in cams:  # the second camera's motion vectors against the first
                v = camera_view(cam).params()
                g.render(raster, v, prev)
                prev = v
            assert g.builds_depth_bounds(bounds) == fused
            if not fused:
                build_bounds(g.depth_layers, w, h, 0.03, 0.02, bounds, device)
            out.append((g.depth_layers.numpy(), bounds.numpy(), g.visibility.numpy(), g.water.visibility.numpy(),
                        g.numpy()))
        for a, b in zip(out[0][:4], out[1][:4]):
            np.testing.assert_array_equal(a, b)
        assert out[0][4].keys() == out[1][4].keys()
        for k in out[0][4]:  # every G-buffer AOV: resolve_camera against resolve_opaque + resolve_specular
            np.testing.assert_array_equal(out[0][4][k], out[1][4][k], err_msg=k)
        assert (out[0][4]["water_tri_id"] >= 0).any() and (np.abs(out[0][4]["motion"]) > 0.5).any()
        back = out[0][0][w * h:]
        assert (back > 0).any() and (out[0][1][:, 1] > 0).all()
        front_only = wp.zeros(bounds_size(w, h), dtype=wp.vec2, device=device)
        build_bounds(wp.array(out[0][0][: w * h], dtype=wp.float32, device=device), w, h, 0.03, 0.02, front_only, device)
        assert (front_only.numpy()[:, 1] < out[0][1][:, 1]).any()  # the back-face layer widens some cells


def _shadow_state(r):
    """Every shadow map's depth and the direct irradiance of a renderer, copied."""
    out = {f"{li}_{k}": s.depth.numpy().copy() for li, lm in enumerate(r.lights) for k, s in enumerate(lm._shadows)}
    out["direct"] = r.direct.irradiance.numpy().copy()
    return out


def _poison_shadows(r):
    for lm in r.lights:
        for s in lm._shadows:
            s.depth.fill_(-1.0)


def _poisoned(r) -> list[bool]:
    return [bool(np.all(s.depth.numpy() == -1.0)) for lm in r.lights for s in lm._shadows]


def test_shadow_maps_are_kept_only_while_their_inputs_stand_still(device):
    """A shadow map is drawn only in frames where its view or the triangles it draws moved (``redraw_gate``, on the
    device): with nothing moved a poisoned map stays poisoned (nothing drawn); after 3 frames the maps and the
    direct light equal a fresh renderer's first frame, and the naive path's (``cache_shadows = False``, which draws
    every frame: the poison is overwritten); a moved light, moved opaque triangles (their generation counted) and
    simulated water each redraw, equal bit for bit to a fresh renderer of the moved scene; the water drawn over the
    kept opaque keys (``_ShadowView.split``) equals the naive path's one draw of both layers."""
    from dataclasses import replace

    from cisp_warp.animation import WaterSimulation
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.usd import load_usd

    settings = RenderSettings(method="cisp", rsm_size=50, denoiser="none", photons=PhotonSettings(photons=500))  # 2500 texels: a partial last stride of 8

    def renderer(points=None, normals=None, lights=None):
        scene = load_usd("scenes_usd/pool.usda", width=32, height=24)
        if lights is not None:
            scene.lights = lights
        r = Renderer(scene, settings, device=device)
        if points is not None:
            r.gpu.points.assign(points)
            r.gpu.normals.assign(normals)
            r.gpu.prev_points.assign(points)
        r.render_frame()
        return r

    r = renderer()
    assert [len(lm._shadows) for lm in r.lights] == [1, 1]  # the sun's scene-wide view, the spot's whole view
    for _ in range(2):
        r.render_frame()
    still = _shadow_state(r)
    for k, v in _shadow_state(renderer()).items():
        np.testing.assert_array_equal(still[k], v, err_msg=k)
    assert (still["0_0"] > 0).any() and (still["1_0"] > 0).any()
    _poison_shadows(r)
    r.render_frame()
    assert _poisoned(r) == [True, True]  # kept: nothing drawn
    for lm in r.lights:
        lm.cache_shadows = False
    r.render_frame()
    for k, v in _shadow_state(r).items():  # the naive path draws every frame
        np.testing.assert_array_equal(still[k], v, err_msg=k)
    for lm in r.lights:
        lm.cache_shadows = True
    r.render_frame()  # drawn by the naive path, held for these views: kept
    _poison_shadows(r)
    r.gpu.begin_frame()  # points may have moved (here they did not): the water's layer is redrawn
    r.render_frame()
    assert _poisoned(r) == [False, False]
    for k, v in _shadow_state(r).items():
        if k != "direct":
            np.testing.assert_array_equal(still[k], v, err_msg=k)
    # a moved light: its map only
    sun = r.lights[0].light
    moved_sun = replace(sun, direction=tuple(np.array([-0.25, -0.85, -0.4]) / np.linalg.norm([-0.25, -0.85, -0.4])))
    _poison_shadows(r)
    r.lights[0].set_light(moved_sun)
    r.render_frame()
    assert _poisoned(r) == [False, True]
    fresh = renderer(lights=[moved_sun, r.lights[1].light])
    np.testing.assert_array_equal(r.lights[0]._shadows[0].depth.numpy(), fresh.lights[0]._shadows[0].depth.numpy())
    assert not np.array_equal(r.lights[0]._shadows[0].depth.numpy(), still["0_0"])
    r.lights[0].set_light(sun)
    r.render_frame()
    np.testing.assert_array_equal(r.lights[0]._shadows[0].depth.numpy(), still["0_0"])
    # moved opaque triangles (the ladder, 5 cm along x), their layer's move counted
    ladder = next(m for m in r.scene.meshes if m.path.endswith("Ladder"))
    pts = r.gpu.points.numpy().copy()
    pts[ladder.vertex_start : ladder.vertex_start + ladder.vertex_count, 0] += 0.05
    _poison_shadows(r)
    r.gpu.points.assign(pts)
    r.gpu.geometry_moved(LAYER_OPAQUE)
    r.render_frame()
    assert _poisoned(r) == [False, False]
    fresh = renderer(pts, r.gpu.normals.numpy().copy())
    moved = _shadow_state(r)
    for k, v in _shadow_state(fresh).items():
        if k != "direct":  # the direct light reads this frame's G-buffer: fresh's has no motion, r's has
            np.testing.assert_array_equal(moved[k], v, err_msg=k)
    assert not np.array_equal(moved["0_0"], still["0_0"])
    # simulated water: every frame redraws
    sim = WaterSimulation(r.gpu)
    for t in (0.5, 0.9):
        _poison_shadows(r)
        r.gpu.begin_frame()
        sim.update(t)
        r.render_frame()
        assert _poisoned(r) == [False, False]
    fresh = renderer(r.gpu.points.numpy().copy(), r.gpu.normals.numpy().copy())
    waves = _shadow_state(r)
    for k, v in _shadow_state(fresh).items():
        if k != "direct":
            np.testing.assert_array_equal(waves[k], v, err_msg=k)
    assert not np.array_equal(waves["1_0"], moved["1_0"])
    # the pool's opaque keys are kept apart (its water moves, its opaque triangles do not): a water frame draws the
    # water alone over them (emptied keys stay empty: the sun's map loses the deck), and equals the naive path
    assert all(s.split for lm in r.lights for s in lm._shadows)
    r.lights[0]._shadows[0].opaque_keys.fill_(RK.EMPTY_KEY_VALUE)
    r.gpu.begin_frame()
    sim.update(1.3)
    r.render_frame()
    lost = r.lights[0]._shadows[0].depth.numpy().copy()
    for lm in r.lights:
        lm.cache_shadows = False
    r.render_frame()
    naive = _shadow_state(r)
    assert (lost == 0).sum() > (naive["0_0"] == 0).sum()
    for lm in r.lights:
        lm.cache_shadows = True
    r.gpu.geometry_moved(LAYER_OPAQUE)
    _poison_shadows(r)
    r.render_frame()
    for k, v in _shadow_state(r).items():
        if k != "direct":
            np.testing.assert_array_equal(naive[k], v, err_msg=k)


def test_redraw_gate_compares_views_bit_for_bit(device):
    """``redraw_gate`` draws a view that differs from the one drawn in any bit (a -0.0 for a +0.0, which ``==``
    calls equal) or whose layers' generation moved, and not the same view again; an inactive view records
    nothing; a scene without mesh ranges counts a move of every layer, one whose meshes are all static none."""
    from cisp_warp.raster.light_maps import VIEW_WORDS, redraw_gate, view_words
    from cisp_warp.scene.device import LAYER_BITS

    v = light_views(make_scene(box_room(), Camera(look_at_matrix((0, 0, 1), (0, 0, 0)))),
                    Light(LightKind.DISTANT, "sun", direction=(0.0, -1.0, 0.0)), 16)[0].params()
    views = wp.array([v, v], dtype=ViewParams, device=device)
    words = view_words(views)
    gen = wp.zeros(LAYER_BITS, dtype=wp.int32, device=device)
    drawn = wp.zeros(VIEW_WORDS, dtype=wp.uint32, device=device)
    drawn_gen = wp.zeros(LAYER_BITS, dtype=wp.int32, device=device)
    out = wp.zeros(1, dtype=ViewParams, device=device)
    far = float(np.float32(v.far))

    def gate(index=0, layers=LAYER_OPAQUE, force=0) -> float:
        wp.launch(redraw_gate, dim=1, device=device, inputs=[views, words, index, gen, layers, force, drawn, drawn_gen, out])
        return float(out.numpy()[0]["far"])

    assert gate() == far and gate() == 0.0  # first drawn, then kept
    assert gate(force=1) == far
    w = views.numpy()
    m = np.asarray(w[1]["world_to_view"]).copy()
    zero = np.argwhere(m == 0.0)[0]
    m[tuple(zero)] = -0.0
    w2 = ViewParams()
    w2.world_to_view = wp.mat44(*m.flatten())
    w2.view_to_world = v.view_to_world
    w2.fx, w2.fy, w2.cx, w2.cy, w2.near, w2.far = v.fx, v.fy, v.cx, v.cy, v.near, v.far
    w2.width, w2.height, w2.orthographic = v.width, v.height, v.orthographic
    views.assign([v, w2])
    assert gate(1) == far and gate(1) == 0.0 and gate(0) == far
    gen.assign(np.array([0, 1], np.int32))  # the specular layer moved
    assert gate(0, LAYER_OPAQUE) == 0.0 and gate(0, LAYER_OPAQUE | LAYER_SPECULAR) == far and gate(0) == 0.0
    w2.far = 0.0  # inactive: nothing drawn, nothing recorded
    views.assign([v, w2])
    assert gate(1) == 0.0 and gate(0) == 0.0
    scene = make_scene(box_room(), Camera(look_at_matrix((0, 0, 1), (0, 0, 0))))
    assert DeviceScene(scene, device).dynamic_layers == LAYER_OPAQUE | LAYER_SPECULAR
    # the gated clear of kept keys: every key when the view is drawn (2501 keys: a partial last stride), none when not
    from cisp_warp.raster.light_maps import clear_keys_if_drawn, shadow_clear_threads

    for threads in (shadow_clear_threads(2501), 7):  # as launched, and a stride that does not divide the keys
        keys = wp.full(2501, 5, dtype=wp.uint64, device=device)
        for far, expect in ((0.0, 5), (2.0, RK.EMPTY_KEY_VALUE)):
            w2.far = far
            wp.launch(clear_keys_if_drawn, dim=threads, device=device,
                      inputs=[wp.array([w2], dtype=ViewParams, device=device), keys, threads])
            assert np.all(keys.numpy() == np.uint64(expect))
    assert shadow_clear_threads(2048 * 2048) == 1 << 16 and shadow_clear_threads(2501) == 313


def test_split_redraw_gates_in_one_launch_are_the_two_gates(device, rng):
    """``redraw_gate_split`` (a split shadow map's two gates in one thread) against two ``redraw_gate`` launches over
    a random run of frames: views that stand still, move by one bit, go inactive, and layers whose generation moves
    (the opaque, the specular, both): the same views to draw and the same records of what was drawn, bit for bit."""
    from cisp_warp.raster.light_maps import VIEW_WORDS, redraw_gate, redraw_gate_split, view_words
    from cisp_warp.scene.device import LAYER_BITS

    v = light_views(make_scene(box_room(), Camera(look_at_matrix((0, 0, 1), (0, 0, 0)))),
                    Light(LightKind.DISTANT, "sun", direction=(0.0, -1.0, 0.0)), 16)[0].params()
    views = wp.array([v], dtype=ViewParams, device=device)
    words = view_words(views)
    gen = wp.zeros(LAYER_BITS, dtype=wp.int32, device=device)
    both = LAYER_OPAQUE | LAYER_SPECULAR
    mk = lambda: [wp.zeros(VIEW_WORDS, dtype=wp.uint32, device=device), wp.zeros(LAYER_BITS, dtype=wp.int32, device=device),  # noqa: E731
                  wp.zeros(1, dtype=ViewParams, device=device)]
    twin, twin_o, fused, fused_o = mk(), mk(), mk(), mk()
    base = views.numpy()
    drawn = [0, 0]
    for frame in range(40):
        rec = base.copy()
        what = rng.integers(0, 5)
        if what == 1:  # one bit of the pose moves
            rec[0]["cx"] = np.float32(rec[0]["cx"]) + np.float32(frame % 3)
        elif what == 2:  # inactive
            rec[0]["far"] = 0.0
        elif what == 3:  # a layer moved
            g = gen.numpy()
            g[rng.integers(0, 2)] += 1
            gen.assign(g)
        views.assign(rec)
        for arrays, layers in ((twin, both), (twin_o, LAYER_OPAQUE)):
            wp.launch(redraw_gate, dim=1, device=device, inputs=[views, words, 0, gen, layers, 0, *arrays])
        wp.launch(redraw_gate_split, dim=1, device=device,
                  inputs=[views, words, 0, gen, both, LAYER_OPAQUE, *fused, *fused_o])
        for a, b in zip(twin + twin_o, fused + fused_o):
            assert a.numpy().tobytes() == b.numpy().tobytes(), frame
        drawn[0] += int(twin[2].numpy()[0]["far"] > 0.0)
        drawn[1] += int(twin[2].numpy()[0]["far"] == 0.0)
    assert drawn[0] > 3 and drawn[1] > 3  # both decisions were taken


@wp.kernel
def _keys_and_back(views: wp.array(dtype=ViewParams), depth: wp.array(dtype=float), keys: wp.array(dtype=wp.uint64),
                   back: wp.array(dtype=float)):
    i = wp.tid()
    k = RK.depth_key(views[0], depth[i], wp.uint64(i))
    keys[i] = k
    back[i] = RK.key_depth(views[0], k)


def test_depth_keys_order_as_their_depths(device, rng):
    """``depth_key`` puts a fragment's depth in the key's high half as the numpy form says, keys order as their
    depths (ties by triangle id), and ``key_depth`` gives the depth back (exactly with the float bits, to the
    quantisation's step without them). Depths over (0, far], with pairs one float32 ulp apart and far itself."""
    view = camera_view(Camera(np.eye(4), near=0.01, far=37.5, width=8, height=8)).params()
    d = rng.uniform(1e-3, 37.5, 500).astype(np.float32)
    d = np.concatenate([d, np.nextafter(d[:50], np.float32(np.inf)), [np.float32(37.5), np.float32(1e-6)]])
    n = len(d)
    keys, back = wp.zeros(n, dtype=wp.uint64, device=device), wp.zeros(n, dtype=float, device=device)
    wp.launch(_keys_and_back, dim=n, device=device,
              inputs=[wp.array([view], dtype=ViewParams, device=device), wp.array(d, dtype=float, device=device),
                      keys, back])
    k = keys.numpy()
    np.testing.assert_array_equal(k, depth_keys(d, view.far) | np.arange(n, dtype=np.uint64))
    ks = k[np.lexsort((np.arange(n), d))]
    if RK.DEPTH_KEY_BITS:  # strictly: distinct depths get distinct keys
        assert (ks[1:] > ks[:-1]).all()
    else:
        assert ((ks[1:] >> np.uint64(32)) >= (ks[:-1] >> np.uint64(32))).all()
    step = 0.0 if RK.DEPTH_KEY_BITS else 37.5 / float(RK.DEPTH_STEPS) * 2
    np.testing.assert_allclose(back.numpy(), d, rtol=0, atol=step)
    np.testing.assert_array_equal(key_depths(k, view.far).astype(np.float32), back.numpy())
