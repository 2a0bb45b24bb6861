"""The user-facing surface: cisp_warp.render() and its docstring example, settings in plain values, the CLI's
outputs (three files, compositor channel names), --out checked first, Ctrl-C in a sequence, messages."""

import doctest
import os

import numpy as np
import pytest

import cisp_warp
from cisp_warp import api
from cisp_warp.cli import main
from cisp_warp.image_io import read_layers

TINY = ["--width", "48", "--height", "27", "--rsm-size", "64", "--photons", "5k", "--device", "cpu"]


def test_docstring_example_runs():
    result = doctest.testmod(api, optionflags=doctest.ELLIPSIS)
    assert result.attempted >= 4 and result.failed == 0


def test_top_level_names_and_plain_settings():
    for name in ("render", "demo", "Renderer", "RenderSettings", "PhotonSettings", "load_usd", "Animation",
                 "SceneError", "__version__"):
        assert hasattr(cisp_warp, name), name
    assert cisp_warp.__version__.count(".") >= 2
    s = cisp_warp.RenderSettings(photons=100_000, svgf={"max_history": 8})
    assert s.photons.photons == 100_000 and s.svgf.max_history == 8
    assert hash(s) == hash(cisp_warp.RenderSettings(photons=100_000, svgf={"max_history": 8}))
    with pytest.raises(cisp_warp.SceneError, match=r"^RenderSettings\.width must be a positive integer"):
        cisp_warp.RenderSettings(width=0)
    with pytest.raises(cisp_warp.SceneError, match=r"^PhotonSettings\.photons must be"):
        cisp_warp.RenderSettings(photons=-5)
    with pytest.raises(cisp_warp.SceneError, match=r"PhotonSettings\.bogus is not a field"):
        cisp_warp.RenderSettings(photons={"bogus": 1})


@pytest.mark.parametrize("kwargs, words", [
    (dict(width=0), "render(): width must be a positive integer"),
    (dict(photons="lots"), "render(): photons must be"),
    (dict(method="magic"), "render(): method must be one of"),
    (dict(device="cuda:77"), "no device 'cuda:77'"),
    (dict(time=1, frames=range(2)), "either time= (one frame) or frames="),
    (dict(frames=3), "frames must be a range"),
])
def test_bad_render_calls_say_one_sentence(kwargs, words):
    with pytest.raises(cisp_warp.SceneError) as info:
        cisp_warp.render(cisp_warp.demo("pool"), **kwargs)
    msg = str(info.value)
    assert words in msg and "\n" not in msg and "--" not in msg


def test_bad_scene_and_demo_names():
    with pytest.raises(cisp_warp.SceneError, match="no such USD file"):
        cisp_warp.render("no/such/file.usda")
    with pytest.raises(cisp_warp.SceneError, match="choose one of: pool, cornell"):
        cisp_warp.demo("beach")
    assert os.path.isfile(cisp_warp.demo("pool")) and os.path.isfile(cisp_warp.demo("cornell"))


def test_render_frames_is_an_iterator_of_frames():
    frames = cisp_warp.render(cisp_warp.demo("pool"), frames="3:5", device="cpu", width=32, height=18,
                              photons=2_000, rsm_size=64, supersample=1)
    out = list(frames)
    assert len(out) == 2 and out[0]["final"].shape == (18, 32, 3)
    assert np.std(out[1]["water_normal"][..., 0][out[1]["water_depth"] > 0]) > 0.0  # waves: the water is simulated


def test_cli_writes_three_files_with_compositor_channels(tmp_path):
    out = tmp_path / "o"
    assert main(["--demo", "pool", "--time", "24", "--out", str(out), "--quiet", *TINY]) == 0
    assert sorted(os.listdir(out)) == ["aovs.exr", "final.exr", "final.png"]
    final = read_layers(str(out / "final.exr"))
    beauty = np.stack([final[c].astype(np.float32) for c in "RGB"], axis=-1)
    assert beauty.sum(-1).min() > 0.0  # nothing black: sky behind the deck, sky-lit walls in shade
    ch = read_layers(str(out / "aovs.exr"))
    for name in ("R", "G", "B", "caustics.R", "caustics.G", "caustics.B", "direct.R", "direct.G", "direct.B",
                 "sky.R", "Z", "N.X", "N.Y", "N.Z", "id"):
        assert name in ch, name
    assert ch["id"].dtype == np.uint32 and ch["Z"].dtype == np.float32 and ch["R"].dtype == np.float16
    assert ch["R"].shape == (27, 48)
    assert (ch["Z"] > 0).mean() > 0.5
    more = tmp_path / "more"
    assert main(["--demo", "pool", "--time", "24", "--out", str(more), "--quiet", "--aovs", "photon_map,position",
                 "--npy", "--rsm-aovs", *TINY]) == 0
    ch = read_layers(str(more / "aovs.exr"))
    assert "photon_map.R" in ch and "position.X" in ch
    assert (more / "rsm.exr").exists() and (more / "photon_map.npy").exists()


def test_cli_checks_out_before_rendering(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["--demo", "pool", "--out", str(blocker / "sub"), *TINY]) == 2
    err = capsys.readouterr().err
    assert "cannot create the output folder" in err and "Traceback" not in err
    assert main(["--demo", "pool", "--out", str(tmp_path / "o"), "--aovs", "nonsense", *TINY]) == 2
    assert "--aovs: no AOV named nonsense" in capsys.readouterr().err


def test_ctrl_c_in_a_sequence_keeps_frames_and_closes_the_video(tmp_path):
    from cisp_warp.animation import Animation
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.sequence import render_sequence
    from cisp_warp.usd import load_usd

    path = cisp_warp.demo("pool")
    r = Renderer(load_usd(path, width=32, height=18), RenderSettings(rsm_size=64, photons=2_000), device="cpu")
    anim = Animation(r, path)

    def interrupt(code):
        if code == 1:
            raise KeyboardInterrupt

    stats = render_sequence(r, anim, range(0, 5), str(tmp_path), on_frame=interrupt)
    assert stats.interrupted and stats.codes == [0, 1]
    files = sorted(os.listdir(tmp_path))
    assert [f for f in files if f.endswith(".png")] == ["final.0000.png", "final.0001.png"]
    assert not [f for f in files if f.endswith(".partial")]
    if stats.video:
        assert os.path.getsize(stats.video) > 0


def test_make_pool_writes_stage_and_sky_into_a_new_folder(tmp_path, capsys):
    from cisp_warp.pool_scene import main as make_pool

    assert make_pool(["--out", str(tmp_path / "new" / "sub" / "p.usda"), "--water-spacing", "0.5"]) == 0
    assert sorted(os.listdir(tmp_path / "new" / "sub")) == ["p.usda", "pool_sky.exr"]
    (tmp_path / "file").write_text("x")
    assert make_pool(["--out", str(tmp_path / "file" / "p.usda")]) == 2
    err = capsys.readouterr().err
    assert "cannot write" in err and "Traceback" not in err


def test_ctrl_c_in_a_single_frame_is_one_line(tmp_path, capsys, monkeypatch):
    from cisp_warp.render import Renderer

    def interrupted(self, timer=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(Renderer, "render_frame", interrupted)
    assert main(["--demo", "pool", "--out", str(tmp_path / "o"), *TINY]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err
    assert os.listdir(tmp_path / "o") == []  # nothing half-written
