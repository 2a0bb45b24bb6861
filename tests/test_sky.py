"""The sky (cisp_warp/sky.py): lat-long lookup against a numpy twin, irradiance against exact integrals,
occlusion, and the sky seen where the camera finds no surface."""

import math

import numpy as np
import pytest
import warp as wp

from cisp_warp import analytic
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.scene import Camera, Material, Sky
from cisp_warp.scene.model import look_at_matrix
from cisp_warp.sky import SkyMap, latlong_directions, sh_basis, sky_map, sky_radiance, sky_sh_irradiance

FLOOR = Material("floor", albedo=(0.5, 0.5, 0.5), roughness=1.0)


@wp.kernel
def _lookup(m: SkyMap, d: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = sky_radiance(m, d[i])


def sky_radiance_np(sky: Sky, d: np.ndarray) -> np.ndarray:
    """Twin of ``sky_radiance``: the OpenEXR lat-long convention written out, bilinear, wrapping in longitude."""
    L = sky.radiance_map()
    h, w = L.shape[:2]
    local = d @ np.asarray(sky.to_world)  # rotation inverse = transpose
    local /= np.linalg.norm(local, axis=-1, keepdims=True)
    lon = np.arctan2(local[:, 0], local[:, 2])
    lat = np.arcsin(np.clip(local[:, 1], -1, 1))
    u = (math.pi - lon) / (2 * math.pi) * w - 0.5
    v = (0.5 * math.pi - lat) / math.pi * h - 0.5
    i0, j0 = np.floor(u).astype(int), np.floor(v).astype(int)
    a, b = (u - i0)[:, None], (v - j0)[:, None]
    out = 0
    for dj, wy in ((0, 1 - b), (1, b)):
        for di, wx in ((0, 1 - a), (1, a)):
            out = out + L[np.clip(j0 + dj, 0, h - 1), (i0 + di) % w] * wx * wy
    return out


def test_latlong_lookup_matches_twin_and_convention(device, rng):
    tex = rng.uniform(0.1, 2.0, size=(8, 16, 3)).astype(np.float32)
    c, s = math.cos(0.7), math.sin(0.7)
    sky = Sky("/Sky", (2.0, 3.0, 4.0), tex, np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]))
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    out = wp.zeros(len(d), dtype=wp.vec3, device=device)
    wp.launch(_lookup, len(d), inputs=[sky_map(sky, device), wp.array(d.astype(np.float32), dtype=wp.vec3, device=device),
                                       out], device=device)
    np.testing.assert_allclose(out.numpy(), sky_radiance_np(sky, d), rtol=2e-4, atol=1e-4)
    # OpenEXR convention: +Y is row 0 (latitude +π/2); +Z is longitude 0, the middle column
    plain = Sky("/Sky", (1.0, 1.0, 1.0), tex)
    dirs, _ = latlong_directions(8, 16)
    assert dirs[0, 0, 1] > 0.98 and dirs[-1, 0, 1] < -0.98
    np.testing.assert_allclose(dirs[4, 8], [0, 0, 1], atol=0.2)
    np.testing.assert_allclose(sky_radiance_np(plain, dirs.reshape(-1, 3)), tex.reshape(-1, 3), rtol=1e-6)
    # no sky: zero (+0.0, as the black map's bilinear sum gives) without reading the map
    none = sky_map(None, device)
    assert none.present == 0 and sky_map(sky, device).present == 1
    out.fill_(wp.vec3(-1.0, -1.0, -1.0))
    wp.launch(_lookup, len(d), inputs=[none, wp.array(d.astype(np.float32), dtype=wp.vec3, device=device), out],
              device=device)
    assert np.all(out.numpy() == 0.0) and not np.signbit(out.numpy()).any()


def test_sh_irradiance_is_exact_for_uniform_and_linear_skies():
    uniform = Sky("/Sky", (1.5, 2.0, 3.0))
    e = sky_sh_irradiance(uniform)
    for n in ([0, 1, 0], [1, 0, 0], [0.3, -0.5, 0.81]):
        n = np.asarray(n) / np.linalg.norm(n)
        np.testing.assert_allclose(sh_basis(n) @ e, math.pi * np.array([1.5, 2.0, 3.0]), rtol=1e-6)
    # L(ω) = a + b ω_y: the irradiance on an up-facing surface is π a + 2π/3 b (band ≤ 1: exact in SH)
    a, b = 1.0, 0.6
    dirs, _ = latlong_directions(256, 512)
    tex = np.repeat((a + b * dirs[..., 1:2]), 3, axis=-1).astype(np.float32)
    e = sh_basis(np.array([0.0, 1.0, 0.0])) @ sky_sh_irradiance(Sky("/Sky", (1.0, 1.0, 1.0), tex))
    np.testing.assert_allclose(e, math.pi * a + 2 * math.pi / 3 * b, rtol=1e-3)


def _sky_scene(parts, sky, width=24, height=16, eye=(0.0, 3.0, 0.01), target=(0.0, 0.0, 0.0)):
    cam = Camera(look_at_matrix(eye, target), fov_y=math.radians(50), width=width, height=height, near=0.05,
                 far=50.0)
    scene = analytic.build(parts, cam, [], (FLOOR,))
    scene.sky = sky
    return scene


def test_uniform_sky_on_an_open_plane_gives_pi_L_and_occlusion_darkens(device):
    L = np.array([10.0, 20.0, 30.0])
    floor = (analytic.quad(0, 0, 0, (4, 0, 0), (0, 0, -4)), 0)
    r = Renderer(_sky_scene([floor], Sky("/Sky", tuple(L))), RenderSettings(method="none", sky_maps=32,
                                                                           sky_map_size=128), device=device)
    r.render_frame()
    a = r.aovs(include_rsm=False)
    lit = a["depth"] > 0
    assert lit.all()
    np.testing.assert_allclose(a["sky_irradiance"][lit], np.broadcast_to(math.pi * L, (lit.sum(), 3)), rtol=1e-5)
    # Lambertian floor: L_out = ρ/π · π L = ρ L, exactly
    np.testing.assert_allclose(a["final"][lit], np.broadcast_to(0.5 * L, (lit.sum(), 3)), rtol=1e-5)
    assert np.all(a["direct_irradiance"] == 0.0)

    # a roof 0.3 m above the middle of the floor hides most of the sky there; the floor far from it keeps π L
    roof = (analytic.quad(0, 0.3, 0, (1, 0, 0), (0, 0, 1)), 0)  # faces down: normal (0, -1, 0)
    r = Renderer(_sky_scene([floor, roof], Sky("/Sky", tuple(L)), width=48, height=32, eye=(0.0, 0.2, 3.8),
                            target=(0.0, 0.0, -1.0)),
                 RenderSettings(method="none", sky_maps=64, sky_map_size=256), device=device)
    r.render_frame()
    a = r.aovs(include_rsm=False)
    e = a["sky_irradiance"][..., 1] / (math.pi * L[1])
    pos = a["position"]
    under = (a["depth"] > 0) & (np.abs(pos[..., 0]) < 0.4) & (np.abs(pos[..., 2]) < 0.4) & (pos[..., 1] < 0.01)
    open_ = (a["depth"] > 0) & (np.hypot(pos[..., 0], pos[..., 2]) > 2.5) & (pos[..., 1] < 0.01)
    assert under.sum() > 5 and open_.sum() > 5
    assert e[under].max() < 0.5  # the roof covers all but the grazing directions
    assert e[open_].min() > 0.9 and e.max() <= 1.0 + 1e-5


def test_sky_irradiance_is_kept_only_while_its_inputs_stand_still(device):
    """A frame with the camera the irradiance was computed for and static opaque geometry keeps it (a poisoned buffer
    stays poisoned: the kernel did not run); a moved camera recomputes it, equal bit for bit to a fresh renderer's
    frame, also after frames that left the sky out; moving opaque geometry, or the first frame, always computes."""
    from dataclasses import replace

    L = (2.0, 3.0, 4.0)
    floor = (analytic.quad(0, 0, 0, (4, 0, 0), (0, 0, -4)), 0)
    roof = (analytic.quad(0, 0.3, 0, (1, 0, 0), (0, 0, 1)), 0)
    settings = RenderSettings(method="none", sky_maps=16, sky_map_size=64)
    scene = lambda eye: _sky_scene([floor, roof], Sky("/Sky", L), eye=eye, target=(0.0, 0.0, -1.0))  # noqa: E731
    eye0, eye1 = (0.0, 0.4, 3.8), (0.3, 0.5, 3.6)
    r = Renderer(scene(eye0), settings, device=device)
    r.render_frame()
    first = r.sky_irradiance.numpy().copy()
    assert (first > 0).any()
    r.sky_irradiance.fill_(wp.vec3(-1.0, -1.0, -1.0))
    r.render_frame()  # same camera: kept
    assert np.all(r.sky_irradiance.numpy() == -1.0)
    r.sky_irradiance.assign(first)
    r.render_frame()
    np.testing.assert_array_equal(r.sky_irradiance.numpy(), first)
    r.set_camera(replace(scene(eye1).camera, width=r.width, height=r.height))
    r.render_frame()  # moved: computed
    fresh = Renderer(scene(eye1), settings, device=device)
    fresh.render_frame()
    moved = r.sky_irradiance.numpy()
    assert not np.array_equal(moved, first)
    np.testing.assert_array_equal(moved, fresh.sky_irradiance.numpy())
    r.sky_irradiance.fill_(wp.vec3(-1.0, -1.0, -1.0))
    r.render_frame()  # standing still again: kept
    assert np.all(r.sky_irradiance.numpy() == -1.0)
    # frames that leave the sky out (a chunk's warm-up) move the camera under it: the next full frame computes,
    # although its camera is the last frame's
    from cisp_warp.sequence import render_history_frame

    r.sky_irradiance.assign(moved)
    r.set_camera(replace(scene(eye0).camera, width=r.width, height=r.height))
    render_history_frame(r)
    r.render_frame()
    np.testing.assert_array_equal(r.sky_irradiance.numpy(), first)
    r.set_camera(replace(scene(eye1).camera, width=r.width, height=r.height))
    r.render_frame()
    r.sky.dynamic = True  # as when opaque geometry moves: maps redrawn and the irradiance computed every frame
    r.render_frame()
    np.testing.assert_array_equal(r.sky_irradiance.numpy(), moved)
    # a renderer's first frame computes although both cameras it reads are the same
    fresh.sky_irradiance.fill_(wp.vec3(-1.0, -1.0, -1.0))
    again = Renderer(scene(eye1), settings, device=device)
    again.sky.irradiance.fill_(wp.vec3(-1.0, -1.0, -1.0))
    again.render_frame()
    np.testing.assert_array_equal(again.sky_irradiance.numpy(), moved)


def test_camera_rays_that_miss_see_the_sky(device):
    tex = np.ones((4, 8, 3), np.float32)
    tex[:2] *= 3.0  # upper half brighter
    floor = (analytic.quad(0, 0, 0, (0.2, 0, 0), (0, 0, -0.2)), 0)
    sky = Sky("/Sky", (1.0, 1.0, 1.0), tex)
    r = Renderer(_sky_scene([floor], sky, eye=(0.0, 1.0, 3.0), target=(0.0, 1.0, 0.0)),
                 RenderSettings(method="none", sky_maps=8, sky_map_size=32), device=device)
    r.render_frame()
    a = r.aovs(include_rsm=False)
    empty = a["depth"] <= 0
    assert empty.mean() > 0.5
    top, bottom = a["final"][0].mean(), a["final"][-1].mean()
    assert top > bottom > 0.0  # looking level: above the horizon the bright half, below it the dim one


def test_supersampling_filters_radiometric_aovs_and_keeps_geometry(device):
    floor = (analytic.quad(0, 0, 0, (0.6, 0, 0), (0, 0, -0.6)), 0)
    L = (1.0, 1.0, 1.0)
    r1 = Renderer(_sky_scene([floor], Sky("/Sky", L), eye=(0.0, 1.5, 1.5)), RenderSettings(method="none", sky_maps=8),
                  device=device)
    r2 = Renderer(_sky_scene([floor], Sky("/Sky", L), eye=(0.0, 1.5, 1.5)),
                  RenderSettings(method="none", sky_maps=8, supersample=2), device=device)
    for r in (r1, r2):
        r.render_frame()
    a1, a2 = r1.aovs(include_rsm=False), r2.aovs(include_rsm=False)
    assert a2["final"].shape == a1["final"].shape == (16, 24, 3)
    assert a2["tri_id"].dtype == a1["tri_id"].dtype
    # same mean radiance: the floor is uniformly lit, only its edge pixels are partly covered
    np.testing.assert_allclose(a2["final"].mean(), a1["final"].mean(), rtol=0.05)
    # one sample per pixel: floor (ρ L = 0.5) or sky (L = 1), nothing between; 2 x 2: partly covered edge pixels
    between = lambda f: (f[..., 0] > 0.51) & (f[..., 0] < 0.99)  # noqa: E731
    assert not between(a1["final"]).any()
    assert between(a2["final"]).sum() >= 8


def test_dome_light_is_read_from_usd_with_its_texture(tmp_path):
    from PIL import Image
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

    from cisp_warp.usd import load_usd

    img = np.zeros((4, 8, 3), np.uint8)
    img[:2] = 255  # upper half white (sRGB 1 = linear 1), lower half black
    img[2:, :, 0] = 188  # sRGB 188 = linear 0.5029
    Image.fromarray(img).save(tmp_path / "sky.png")
    stage = Usd.Stage.CreateNew(str(tmp_path / "s.usda"))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    mesh = UsdGeom.Mesh.Define(stage, "/World/Floor")
    mesh.CreatePointsAttr([(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    UsdGeom.Camera.Define(stage, "/World/Cam").AddTranslateOp().Set(Gf.Vec3d(0, 1, 4))
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.CreateColorAttr(Gf.Vec3f(0.5, 1.0, 1.0))
    dome.CreateIntensityAttr(3.0)
    dome.CreateExposureAttr(1.0)
    dome.CreateTextureFileAttr(Sdf.AssetPath("./sky.png"))
    stage.Save()
    scene = load_usd(tmp_path / "s.usda")  # a dome light alone is light enough
    assert scene.lights == [] and scene.sky is not None
    np.testing.assert_allclose(scene.sky.radiance, (3.0, 6.0, 6.0))
    assert scene.sky.texture.shape == (4, 8, 3)
    np.testing.assert_allclose(scene.sky.texture[0, 0], 1.0, rtol=1e-6)
    np.testing.assert_allclose(scene.sky.texture[3, 0], (0.5029, 0.0, 0.0), atol=2e-3)

    dome.CreateTextureFileAttr(Sdf.AssetPath("./missing.exr"))
    stage.Save()
    from cisp_warp import SceneError

    with pytest.raises(SceneError, match=r"prim '/World/Sky'.*inputs:texture:file.*does not exist"):
        load_usd(tmp_path / "s.usda")


def test_direct_light_two_maps_a_launch_equal_one_a_launch(device):
    """DirectLighting's paired launches (direct_light_pair) give direct_light's irradiance bit for bit: the pool
    (sun + spot: one pair) and a point light's six cube faces with a spot (seven maps: three pairs and one alone)."""
    from cisp_warp.scene import Light, LightKind
    from cisp_warp.usd import load_usd

    pool = load_usd("scenes_usd/pool.usda", width=48, height=36, device=device)
    floor = (analytic.quad(0, 0, 0, (2, 0, 0), (0, 0, -2)), 0)
    box = (analytic.quad(0, 0.4, 0, (0.3, 0, 0), (0, 0, 0.3)), 0)
    lamps = [Light(LightKind.POINT, "lamp", intensity=50.0, position=(0.2, 1.0, 0.1), direction=(0, -1, 0)),
             Light(LightKind.SPOT, "spot", intensity=80.0, position=(-0.5, 1.5, 0.3), direction=tuple(np.array([0.3, -1.0, -0.1]) / np.linalg.norm([0.3, -1.0, -0.1])),
                   cone_angle=math.radians(40), cone_softness=0.1)]
    lamp_scene = analytic.build([floor, box], _sky_scene([floor], None, eye=(0.0, 2.0, 2.5)).camera, lamps, (FLOOR,))
    for scene, maps in ((pool, 2), (lamp_scene, 7)):
        r = Renderer(scene, RenderSettings(method="none", rsm_size=64), device=device)
        r.render_frame()
        assert sum(len(lm.shadow_maps()) for lm in r.lights) == maps
        paired = r.direct.irradiance.numpy().copy()
        assert (paired > 0).any()
        r.direct.pairs = False
        r.direct.irradiance.fill_(wp.vec3(-1.0, -1.0, -1.0))
        r.direct.render(r.gbuffer, r.lights)
        np.testing.assert_array_equal(r.direct.irradiance.numpy(), paired)


def test_reference_final_sees_the_methods_sky(device):
    """The reference's own final image (camera paths, photons/world.py) lights with the methods' sky: the sky's
    radiance where a path leaves the scene, and the methods' sky irradiance at a path's diffuse end. Without them its
    final was black wherever the camera saw the sky, and every method's FLIP against it measured that."""
    from cisp_warp.photons import PhotonSettings

    tex = np.ones((4, 8, 3), np.float32)
    tex[:2] *= 3.0  # upper half brighter
    floor = (analytic.quad(0, 0, 0, (2.0, 0, 0), (0, 0, -2.0)), 0)
    scene = lambda: _sky_scene([floor], Sky("/Sky", (1.0, 1.0, 1.0), tex), eye=(0.0, 1.0, 3.0),  # noqa: E731
                               target=(0.0, 0.5, 0.0))
    finals = {}
    for method in ("none", "reference"):
        r = Renderer(scene(), RenderSettings(method=method, denoiser="none", sky_maps=8, sky_map_size=32,
                                             photons=PhotonSettings(photons=1000, reference_photons=2000)),
                     device=device)
        r.render_frame()
        finals[method] = r.aovs(include_rsm=False)
    a, ref = finals["none"], finals["reference"]
    sky, floor_px = a["depth"] <= 0, a["depth"] > 0
    assert sky.sum() > 20 and floor_px.sum() > 20
    assert ref["final"][sky].min() > 0.0
    np.testing.assert_allclose(ref["final"][sky], a["final"][sky], rtol=1e-5)
    # on the floor: albedo/π × the same sky irradiance (no light, no caustic), to float rounding
    np.testing.assert_allclose(ref["final"][floor_px], a["final"][floor_px], rtol=1e-4)
