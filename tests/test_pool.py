"""The pool scene (tools/make_pool_scene.py) and animated rendering (cisp_warp.animation, cisp_warp.sequence)."""

import importlib.util
import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from cisp_warp.animation import Animation, StageClock, WaterSimulation, water_grid
from cisp_warp.errors import SceneError, SceneWarning
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.scene import DeviceScene, LightKind
from cisp_warp.sequence import VideoWriter, render_sequence
from cisp_warp.usd import load_usd

ROOT = Path(__file__).resolve().parents[1]
POOL = ROOT / "scenes_usd" / "pool.usda"
TINY = RenderSettings(width=64, height=36, rsm_size=64, photons=PhotonSettings(photons=2000, seed=5))


@pytest.fixture(scope="module")
def gen():
    import cisp_warp.pool_scene  # the generator behind cisp-make-pool and tools/make_pool_scene.py

    return cisp_warp.pool_scene


@pytest.fixture(scope="module")
def baked(gen, tmp_path_factory):
    """A small pool (0.25 m water grid) with the simulated water baked at time codes 0, 1, 2."""
    path = tmp_path_factory.mktemp("baked") / "pool_baked.usda"
    gen.build(path, gen.PoolOptions(water_spacing=0.25, bake=3))
    return path


def water_range(scene):
    (m,) = [m for m in scene.meshes if m.water]
    return m, slice(m.vertex_start, m.vertex_start + m.vertex_count)


# ---------------------------------------------------------------------------------------------- the stage


def test_generator_is_deterministic_compliant_and_in_sync_with_the_committed_file(gen, tmp_path):
    stage = gen.build(tmp_path / "p.usda", gen.PoolOptions())
    assert gen.validation_errors(stage) == []
    checker = gen.compliance_checker_errors(tmp_path / "p.usda")  # None: this usd-core no longer has it
    assert checker is None or checker == []
    assert (tmp_path / "p.usda").read_bytes() == POOL.read_bytes(), "rerun tools/make_pool_scene.py"


def test_baked_variant_is_compliant(gen, baked):
    from pxr import Usd

    assert gen.validation_errors(Usd.Stage.Open(str(baked))) == []


def test_stage_metadata(gen):
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(POOL))
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == "/World"
    assert (stage.GetTimeCodesPerSecond(), stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (24.0, 0.0, 120.0)


def test_pool_round_trips_through_the_importer(gen):
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)  # the shipped scene imports without a warning
        scene = load_usd(POOL)
    tris = {m.path: m.triangle_count for m in scene.meshes}
    nx, nz = gen.PoolOptions().water_counts()
    assert (nx, nz) == (129, 65)
    assert tris == {
        "/World/Basin/Floor": 2 * 32 * 16, "/World/Basin/Walls": 2 * 6 * 2 * (32 + 16), "/World/Basin/Steps": 2 * 3 * 4,
        "/World/Coping": 2 * (2 * 5 + 2 * 3), "/World/Deck": 2 * 4, "/World/Ladder": 2 * (2 * (5 + 5 + 4) + 3 * 4),
        "/World/Water": 2 * (nx - 1) * (nz - 1),
    }
    water, sl = water_range(scene)
    assert water.path == "/World/Water" and water.dynamic
    assert water.water == gen.PoolOptions().water_params().to_dict()
    np.testing.assert_array_equal(scene.points[sl, 1], 0.0)  # the default points are the flat rest grid
    # materials: tiles by displayColor, the rest bound; the water is a smooth dielectric
    names = {m.name: m for m in scene.materials}
    for rgb in (gen.TILE_LIGHT, gen.TILE_DARK_CHECK, gen.TILE_LANE, gen.TILE_WATERLINE, gen.STEP_TOP):
        key = "displayColor#" + "".join(f"{round(c * 255):02x}" for c in rgb)
        assert key in names, key
    w = names["/World/Looks/Water"]
    assert w.transmissive and w.roughness == 0.0 and w.ior == pytest.approx(1.333)
    floor = next(m for m in scene.meshes if m.path == "/World/Basin/Floor")
    floor_mats = {scene.materials[i].name for i in scene.triangle_material[floor.triangle_start:][:floor.triangle_count]}
    assert len(floor_mats) == 3  # checker light, checker dark, lane
    # lights in SI units
    sun = next(light for light in scene.lights if light.kind == LightKind.DISTANT)
    spot = next(light for light in scene.lights if light.kind == LightKind.SPOT)
    assert sun.intensity == pytest.approx(900.0)
    np.testing.assert_allclose(sun.direction, gen.sun_direction(60.0), atol=1e-6)
    assert spot.intensity == pytest.approx(75.0) and math.degrees(spot.cone_angle) == pytest.approx(35.0)
    np.testing.assert_allclose(spot.position, gen.SPOT_POSITION, atol=1e-6)
    axis = np.subtract(gen.SPOT_TARGET, gen.SPOT_POSITION)
    np.testing.assert_allclose(spot.direction, axis / np.linalg.norm(axis), atol=1e-6)
    # the basin: floor at -depth, deck at +0.15
    lo, hi = scene.bounds()
    assert lo[1] == pytest.approx(-1.2) and hi[0] == pytest.approx(6.5) and hi[2] == pytest.approx(4.5)


@pytest.mark.parametrize("code", [0.0, 60.0, 120.0, 37.5])
def test_camera_path_round_trips(gen, code):
    scene = load_usd(POOL, time_code=code)
    cam = scene.camera
    eye, aim = gen.camera_pose(code)
    if code == int(code):  # between samples USD interpolates translate and angles linearly, not the easing
        np.testing.assert_allclose(cam.position, eye, atol=1e-5)
        forward = (aim - eye) / np.linalg.norm(aim - eye)
        np.testing.assert_allclose(cam.forward, forward, atol=1e-5)
    assert (cam.width, cam.height) == (640, 360)
    assert math.degrees(cam.fov_y) == pytest.approx(2 * math.degrees(math.atan(20.25 / 2 / 28.0)), abs=1e-6)
    assert scene.time == pytest.approx(code / 24.0)
    # the open stage gives the very camera the importer gives, without re-importing
    clock = StageClock(POOL)
    np.testing.assert_array_equal(clock.camera(code, 640, 360).to_world, cam.to_world)
    assert clock.seconds(code) == scene.time


def test_the_camera_moves_between_time_codes():
    a, b = load_usd(POOL, time_code=0).camera, load_usd(POOL, time_code=120).camera
    assert np.linalg.norm(a.position - b.position) > 5.0  # dolly
    assert math.degrees(math.acos(np.clip(np.dot(a.forward, b.forward), -1, 1))) > 20.0  # pan


# ---------------------------------------------------------------------------------------------- the water


def test_water_grid_is_inferred_from_the_rest_points(gen):
    rest, _, _ = gen.water_rest_grid((9, 5))
    grid = water_grid(rest, "/W")
    assert grid.rect == (-4.0, -2.0, 4.0, 2.0) and grid.y0 == 0.0 and grid.counts == (9, 5)
    with pytest.raises(SceneError, match="/W.*regular grid"):
        water_grid(rest[np.random.default_rng(1).permutation(len(rest))], "/W")
    with pytest.raises(SceneError, match="/W.*regular grid"):
        water_grid(rest.reshape(5, 9, 3).transpose(1, 0, 2).reshape(-1, 3), "/W")  # x varies across rows


def test_bad_water_parameters_name_the_prim_and_attribute(device):
    scene = load_usd(POOL, width=16, height=9)
    water, _ = water_range(scene)
    water.water["choppiness"] = -1.0
    with pytest.raises(SceneError, match="/World/Water.*choppiness"):
        WaterSimulation(DeviceScene(scene, device))
    water.water["choppiness"] = 0.5
    water.water["wind_gust"] = 3.0
    with pytest.raises(SceneError, match="/World/Water.*wind_gust"):
        WaterSimulation(DeviceScene(scene, device))


def test_water_imported_at_t_equals_the_simulation_at_t(baked, device):
    """The points baked into USD at time code k (read by the importer) are what Animation simulates at k."""
    renderer = Renderer(load_usd(baked, time_code=0, width=64, height=36), TINY, device=device)
    anim = Animation(renderer, baked)
    _, sl = water_range(renderer.scene)
    simulated = {}
    for code in (0, 2, 1):
        anim.set_time_code(code)
        imported = load_usd(baked, time_code=code, width=64, height=36)
        p_sim = renderer.gpu.points.numpy()[sl]
        n_sim = renderer.gpu.normals.numpy()[sl]
        # 10 µm on waves of 1.5 cm rms height: float32 rounding on CUDA, bit-exact on the CPU
        np.testing.assert_allclose(p_sim, imported.points[sl], rtol=0, atol=1e-5)
        np.testing.assert_allclose(n_sim, imported.normals[sl], rtol=0, atol=1e-4)
        simulated[code] = p_sim.copy()  # numpy() of a cpu array is a view of the device memory
    assert np.abs(simulated[2] - simulated[0])[:, 1].max() > 1e-3  # the water moves: the test is not vacuous
    # only the water moves
    other = np.ones(len(renderer.scene.points), bool)
    other[sl] = False
    np.testing.assert_array_equal(renderer.gpu.points.numpy()[other], renderer.scene.points[other])


def test_no_sim_renders_the_baked_points(baked, device):
    renderer = Renderer(load_usd(baked, time_code=0, width=64, height=36), TINY, device=device)
    anim = Animation(renderer, baked, simulate=False)
    assert anim.water is None and anim.baked == ["/World/Water"]
    anim.set_time_code(2)
    _, sl = water_range(renderer.scene)
    np.testing.assert_allclose(renderer.gpu.points.numpy()[sl], load_usd(baked, time_code=2).points[sl], atol=0)


# ---------------------------------------------------------------------------------------------- rendering


def _render_three(device, out_dir):
    renderer = Renderer(load_usd(POOL, time_code=50, width=64, height=36), TINY, device=device)
    anim = Animation(renderer, POOL)
    finals, motion = [], []

    def grab(code):
        finals.append(renderer.final.numpy().copy())
        motion.append(renderer.gbuffer.motion.numpy().copy())

    stats = render_sequence(renderer, anim, range(50, 53), str(out_dir), on_frame=grab)  # mid-dolly: fast
    return finals, motion, stats


def test_three_pool_frames_render(device, tmp_path):
    finals, motion, stats = _render_three(device, tmp_path)
    assert len(finals) == 3 and stats.codes == [50, 51, 52]
    for f in finals:
        assert np.all(np.isfinite(f)) and f.max() > 0.0
    assert np.abs(motion[0]).max() < 0.01  # the first frame has no previous one (float32 reprojection: ~1e-3 px)
    assert np.abs(motion[2]).max() > 0.1  # the camera dollies: motion vectors feed the temporal filter
    assert not np.array_equal(finals[1], finals[2])
    for code in range(50, 53):
        assert (tmp_path / f"final.{code:04d}.png").is_file()
    assert "rss" in stats.memory[0] and "frames, median" in stats.summary()


def test_three_pool_frames_are_deterministic_on_the_cpu(tmp_path):
    a, _, _ = _render_three("cpu", tmp_path / "a")
    b, _, _ = _render_three("cpu", tmp_path / "b")
    for fa, fb in zip(a, b):
        np.testing.assert_array_equal(fa, fb)


def test_video_writer_without_ffmpeg_warns_and_keeps_going(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import fails
    writer = VideoWriter(str(tmp_path / "v.mp4"), 24)
    with pytest.warns(RuntimeWarning, match="imageio-ffmpeg is not installed"):
        writer.append(np.zeros((5, 7, 3), np.uint8))
    writer.append(np.zeros((5, 7, 3), np.uint8))
    writer.close()
    assert writer.error and not (tmp_path / "v.mp4").exists()


def test_cli_renders_a_sequence_with_video(tmp_path, capsys):
    from cisp_warp.cli import main

    out = tmp_path / "seq"
    rc = main([str(POOL), "--frames", "0:2", "--width", "64", "--height", "36", "--rsm-size", "64",
               "--photons", "2k", "--device", "cpu", "--out", str(out)])
    assert rc == 0
    assert (out / "final.0000.png").is_file() and (out / "final.0001.png").is_file()
    err = capsys.readouterr().err
    assert "2 frames, median" in err and "rss" in err
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        assert "no video written" in err
    else:
        assert (out / "final.mp4").stat().st_size > 0


@pytest.mark.parametrize("argv, message", [
    (["--frames", "5:2"], "--frames"),
    (["--frames", "a:b"], "--frames"),
])
def test_cli_bad_frames_exit_2(argv, message, tmp_path, capsys):
    from cisp_warp.cli import main

    assert main([str(POOL), "--out", str(tmp_path), "--device", "cpu", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_cli_missing_stage_exit_2(tmp_path, capsys):
    from cisp_warp.cli import main

    missing = tmp_path / "nope.usda"
    assert main([str(missing), "--frames", "0:2", "--out", str(tmp_path), "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert "nope.usda" in err and "not found" in err and "Traceback" not in err


@pytest.mark.parametrize("argv", [["--sun-elevation", "100"], ["--water-spacing", "-1"], ["--bake", "-3"],
                                  ["--out", "x.txt"]])
def test_generator_bad_flags_exit_2(gen, argv, capsys):
    with pytest.raises(SystemExit) as exc:
        gen.parse_args(argv)
    assert exc.value.code == 2 and "error" in capsys.readouterr().err


def test_bench_animation_smoke():
    result = subprocess.run([sys.executable, str(ROOT / "tools" / "bench_animation.py"), "--smoke", "--device", "cpu"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "StageClock.camera" in result.stdout and "rss" in result.stdout


def test_refit_leaves_the_static_layers_bvh_as_built(device, monkeypatch):
    """``DeviceScene.refit`` (after the water moved) refits the BVH that holds the water's triangles and leaves the
    opaque layer's, static on the pool, as built: one refit where there were two."""
    from cisp_warp.scene.model import LAYER_OPAQUE, LAYER_SPECULAR

    ds = DeviceScene(load_usd(POOL, time_code=50, width=32, height=18), device)
    opaque, _ = ds.bvh(LAYER_OPAQUE)
    water, _ = ds.bvh(LAYER_SPECULAR)
    refits = []
    real = type(opaque).refit
    monkeypatch.setattr(type(opaque), "refit", lambda self: (refits.append(self.id), real(self))[1])
    ds.refit()
    assert refits == [water.id]
