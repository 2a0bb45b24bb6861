"""One CUDA graph per steady frame, replayed frame after frame (``Renderer.render_frame(graph=...)``): the frame's
cameras and random streams come from ``frame.FrameInputs``, so a replay renders what launching every kernel does.
On the CPU nothing changes: no graph, and a seed plus a frame number reproduce a frame bit for bit."""

import math

import numpy as np
import pytest
import warp as wp

from cisp_warp import analytic
from cisp_warp.frame import FrameInputs
from cisp_warp.photons.base import frame_random
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.scene.model import look_at_matrix


def _renderer(device, method="cisp", denoiser="caustic"):
    return Renderer(analytic.wavy_water(width=32, height=24, grid=32),
                    RenderSettings(rsm_size=64, method=method, denoiser=denoiser, photons=20_000), device=device)


def _orbit(r, frame):
    """A camera that moves every frame (read by the replay from FrameInputs.cameras)."""
    cam = r.scene.camera
    a = 0.05 * frame
    eye = (1.2 * math.sin(a), 1.5, 1.2 * math.cos(a))
    from dataclasses import replace

    r.set_camera(replace(cam, to_world=look_at_matrix(eye, (0.0, 0.0, 0.0))))


def test_frame_inputs_hold_the_cameras_and_streams():
    r = _renderer("cpu")
    inputs = r.inputs
    assert isinstance(inputs, FrameInputs) and r.photons.inputs is inputs and r.fitter.inputs is inputs
    r.render_frame()
    r.render_frame()
    vals = inputs.randoms.numpy()
    assert tuple(vals[inputs.rsm_stream(0, 1)]) == frame_random(0, 1, 1)
    assert vals[inputs.pilot_stream(0, 0), 2] == 131
    cams = inputs.cameras.numpy()
    np.testing.assert_allclose(cams["fx"], [r.view_params.fx] * 2, rtol=1e-7)


@pytest.mark.parametrize("method", ["cisp", "sspm"])
def test_cpu_frames_bitwise_and_no_graph(method):
    """The CPU never captures (graph=True is ignored there) and two renderers give the same frames bit for bit."""
    finals = []
    for graph in (False, True):
        r = _renderer("cpu", method)
        assert not r.graph_capable
        out = []
        for f in range(3):
            _orbit(r, f)
            r.render_frame(graph=graph)
            out.append(r.final.numpy().copy())
        assert r.graph_captures == 0
        finals.append(out)
    for a, b in zip(*finals):
        np.testing.assert_array_equal(a, b)


@pytest.mark.skipif(not wp.is_cuda_available(), reason="CUDA graphs need a GPU")
@pytest.mark.parametrize("method,denoiser", [("cisp", "caustic"), ("sspm", "svgf"), ("cisp", "none")])
def test_graph_replay_matches_launches(method, denoiser):
    """Frames replayed from one graph (camera moving) match frames launched kernel by kernel, to the float
    atomics' order; the graph is captured once."""
    finals = {}
    for graph in (False, True):
        r = _renderer("cuda:0", method, denoiser)
        assert r.graph_capable
        out = []
        for f in range(5):
            _orbit(r, f)
            r.render_frame(graph=graph)
            out.append((r.final.numpy().astype(np.float64), r.photons.read_ledger()))
        assert r.graph_captures == (1 if graph else 0)
        finals[graph] = out
    for (a, la), (b, lb) in zip(finals[False], finals[True]):
        assert lb.closure() < 1e-5
        np.testing.assert_allclose(la.values, lb.values, rtol=1e-6, atol=1e-9 * np.abs(la.values).max())
        assert np.abs(a - b).mean() <= 1e-4 * np.abs(a).mean() + 1e-12


@pytest.mark.parametrize("device", ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else []))
def test_camera_projection_change_launches_then_recaptures(device):
    """A camera that turns orthographic mid-sequence (the trace, composite and pilots are compiled per camera
    projection): that frame is launched from Python (loading the new projection's kernels outside any capture), the
    next one captured again, and the frames match a renderer that never replays a graph."""
    from dataclasses import replace

    finals = {}
    for graph in (False, True):
        r = _renderer(device, "cisp", "svgf")
        out = []
        for f in range(5):
            _orbit(r, f)
            if f >= 3:
                r.set_camera(replace(r.scene.camera, orthographic=True, ortho_height=2.5))
                assert r._launch_next == (f == 3)
            r.render_frame(graph=graph)
            assert not r._launch_next
            out.append(r.final.numpy().astype(np.float64))
        assert r.graph_captures == (2 if graph and r.graph_capable else 0)
        finals[graph] = out
    for a, b in zip(finals[False], finals[True]):
        assert np.abs(a).max() > 0
        assert np.abs(a - b).mean() <= 1e-4 * np.abs(a).mean() + 1e-12
