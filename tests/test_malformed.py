"""Bad input gets a clear SceneError (file, prim, reason), never a crash or a hang.

The corpus under ``tests/malformed/`` is written by ``tests/malformed/make_corpus.py``; its
``expected.json`` says which prim and keyword each file's error must name.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from cisp_warp.errors import SceneError, SceneWarning
from cisp_warp.usd import load_usd

CORPUS = Path(__file__).resolve().parent / "malformed"
EXPECTED = json.loads((CORPUS / "expected.json").read_text())


def test_corpus_is_complete():
    files = {p.name for p in CORPUS.iterdir() if p.is_file() and p.name not in ("expected.json", "make_corpus.py")}
    assert files == set(EXPECTED), "rerun tests/malformed/make_corpus.py and commit its output"
    assert len(files) >= 25


@pytest.mark.filterwarnings("ignore::cisp_warp.errors.SceneWarning")
@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_malformed_file_raises_scene_error(name):
    case = EXPECTED[name]
    with pytest.raises(SceneError) as info:
        load_usd(CORPUS / name)
    message = str(info.value)
    assert name in message
    assert info.value.file is not None and info.value.file.endswith(name)
    if case["prim"]:
        assert f"prim '{case['prim']}'" in message
    assert case["keyword"].lower() in message.lower(), message


def test_missing_file(tmp_path):
    with pytest.raises(SceneError, match=r"nowhere\.usda.*not found"):
        load_usd(tmp_path / "nowhere.usda")


def test_directory_is_not_a_file(tmp_path):
    with pytest.raises(SceneError, match="not a regular file"):
        load_usd(tmp_path)


def _load_generator():
    spec = importlib.util.spec_from_file_location("make_corpus", CORPUS / "make_corpus.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def valid_stage(tmp_path) -> Path:
    """The corpus' base stage, unbroken: every malformed file is this with one thing wrong."""
    path = tmp_path / "valid.usda"
    path.write_text(_load_generator().stage_text())
    return path


def test_base_stage_of_the_corpus_loads(valid_stage):
    scene = load_usd(valid_stage)
    assert scene.triangle_count == 2 and len(scene.lights) == 1


@pytest.mark.parametrize(
    "kwargs, keyword",
    [
        (dict(width=0, height=360), "resolution"),
        (dict(width=-640), "resolution"),
        (dict(width=60000, height=60000), "G-buffer"),
        (dict(width=640.5), "whole number"),
        (dict(camera_path="/World/Nope"), "/World/Nope"),
        (dict(camera_path="/World/Sun"), "no UsdGeom.Camera"),
        (dict(time_code=float("nan")), "time_code"),
    ],
)
def test_bad_arguments(valid_stage, kwargs, keyword):
    with pytest.raises(SceneError) as info:
        load_usd(valid_stage, **kwargs)
    assert keyword in str(info.value) and "valid.usda" in str(info.value)


def test_missing_reference_warns_and_still_loads(valid_stage):
    reference = 'def Xform "World" (\n    references = @./gone.usda@\n)\n'
    valid_stage.write_text(valid_stage.read_text().replace('def Xform "World"\n', reference, 1))
    with pytest.warns(SceneWarning, match="gone.usda"):
        scene = load_usd(valid_stage)
    assert scene.triangle_count == 2
