"""A camera whose intrinsics change between frames (``Renderer.set_camera``: a zoom, as a USD camera's animated
focal length gives ``Animation``): the photons' deposit divides by the camera pixels' solid angles, so a renderer made
for one field of view and zoomed to another must give the frame of a renderer made for the second one."""

from dataclasses import replace

import numpy as np
import pytest

from cisp_warp import PhotonSettings, Renderer, RenderSettings, load_usd


@pytest.mark.parametrize("method", ["cisp", "sspm"])
def test_zoomed_camera_equals_a_renderer_made_for_it(method):
    scene = load_usd("scenes_usd/pool.usda", width=32, height=24)
    zoomed = replace(scene.camera, fov_y=scene.camera.fov_y * 0.8)
    settings = RenderSettings(rsm_size=64, method=method, denoiser="none", photons=PhotonSettings(photons=4000, seed=5))
    made = Renderer(replace(scene, camera=zoomed), settings, device="cpu")
    made.render_frame()
    moved = Renderer(scene, settings, device="cpu")
    moved.set_camera(zoomed)
    moved.render_frame()
    a, b = made.photons.photon_map.numpy(), moved.photons.photon_map.numpy()
    assert a.max() > 0
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(made.final.numpy(), moved.final.numpy())
