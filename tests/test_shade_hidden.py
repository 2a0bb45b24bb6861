"""The composite's rays that screen space cannot follow (cisp_warp/shade_hidden.py): what they reach against exact
answers, the BVH trace against its every-triangle twin, and the hand-over from the composite's march."""

import math

import numpy as np

from cisp_warp import analytic
from cisp_warp.optics import fresnel_dielectric_np
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.scene import Camera, Light, LightKind
from cisp_warp.scene.model import look_at_matrix
from cisp_warp.shade import MISSED_REFLECTED, MISSED_REFRACTED
from cisp_warp.shade_hidden import HIDDEN_REFLECTED

E_SUN = 1000.0  # W/m²
SUN_DIR = np.array([0.0, -0.6, -0.8])  # travel; the wall (facing +z) sees cos = 0.8
WALL_Z = -1.2
WALL_TOP = 1.5
ALBEDO = 0.8


def water_and_offscreen_wall(size=32):
    """Flat water (1 m square, y = 0) over a floor, and a lit wall behind it (z = -1.2, facing +z, 0 <= y <= 1.5)
    that the camera does not see but the water's reflection does: the reflected camera rays leave the image."""
    water = (analytic.quad(0, 0, 0, (0.5, 0, 0), (0, 0, -0.5)), 1)
    floor = (analytic.quad(0, -0.5, 0, (2, 0, 0), (0, 0, -2)), 0)
    wall = (analytic.quad(0, 0.5 * WALL_TOP, WALL_Z, (2, 0, 0), (0, 0.5 * WALL_TOP, 0)), 0)
    cam = Camera(look_at_matrix((0.0, 1.5, 0.8), (0.0, 0.0, 0.0)), fov_y=math.radians(40), width=size, height=size,
                 near=0.05, far=10)
    sun = Light(LightKind.DISTANT, "sun", intensity=E_SUN, direction=tuple(SUN_DIR))
    return analytic.build([water, floor, wall], cam, [sun])


def render(scene, device, method="none", naive=False):
    r = Renderer(scene, RenderSettings(rsm_size=128, method=method, denoiser="none",
                                       photons=PhotonSettings(photons=20_000, seed=3)), device=device)
    r.hidden.naive = naive
    r.render_frame()
    return r


def test_reflection_off_screen_sees_the_lit_wall(device):
    """A reflected ray that leaves the image lands on the wall the camera cannot see: the pixel shows
    F · ρ/π · E cos θ of the wall (its shadow-mapped direct light; no sky, no photons), exactly; a reflected ray that
    passes over the wall sees the (black) sky; the refracted rays see the floor in the water's shadow (black)."""
    r = render(water_and_offscreen_wall(), device)
    assert r.hidden.layer.has_mesh == 1
    g = r.gbuffer
    shape = (g.height, g.width)
    water = g.water.depth.numpy().reshape(shape) > 0
    missed = r.hidden.missed.numpy().reshape(shape)
    final = r.final.numpy().reshape(shape + (3,))
    x = g.water.position.numpy().reshape(shape + (3,))
    eye = np.array([0.0, 1.5, 0.8])
    v = eye - x
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    f = fresnel_dielectric_np(v[..., 1], 1.33)  # the water's normal is +y
    d = v * np.array([-1.0, 1.0, -1.0])  # reflected about +y
    t = (WALL_Z - x[..., 2]) / d[..., 2]
    y_hit = x[..., 1] + t * d[..., 1]
    # the refracted ray's floor point, inside the water's shadow (the floor beyond it is lit by the sun itself)
    cos_t = np.sqrt(1.0 - (1.0 - v[..., 1] ** 2) / 1.33 ** 2)
    t_dir = -v / 1.33 + np.array([0.0, 1.0, 0.0]) * (v[..., 1:2] / 1.33 - cos_t[..., None])
    floor = x + t_dir * (-0.5 / t_dir[..., 1:2])
    shadow_z = -0.5 * SUN_DIR[2] / SUN_DIR[1]  # the water's shadow on the floor is the water moved by this along z
    in_shadow = (np.abs(floor[..., 0]) < 0.45) & (np.abs(floor[..., 2] - shadow_z) < 0.45)
    on_wall = water & in_shadow & (y_hit > 0.05) & (y_hit < WALL_TOP - 0.05)
    over_wall = water & in_shadow & (y_hit > WALL_TOP + 0.05)
    assert on_wall.sum() > 40 and over_wall.sum() > 20  # both kinds of pixel are in the view
    assert ((missed[water] & MISSED_REFLECTED) != 0).all()  # every reflection leaves the image
    assert ((missed[on_wall] & HIDDEN_REFLECTED) != 0).all() and not (missed[over_wall] & HIDDEN_REFLECTED).any()
    seen = f * ALBEDO / math.pi * E_SUN * 0.8
    np.testing.assert_allclose(final[on_wall], np.repeat(seen[on_wall][:, None], 3, -1), rtol=1e-4)
    assert np.abs(final[over_wall]).max() == 0.0


def test_bvh_trace_matches_its_every_triangle_twin(device):
    """The BVH's nearest opaque hit (wp.mesh_query_ray) and the naive loop over every opaque triangle: the same
    rays flagged, the same hidden hits, the same image to float rounding, on the wall scene with photons."""
    a = render(water_and_offscreen_wall(), device, method="cisp")
    fa, ma = a.final.numpy().copy(), a.hidden.missed.numpy().copy()
    ta, ua = a.hidden.hidden_tri.numpy().copy(), a.hidden.hidden_uvw.numpy().copy()
    b = render(water_and_offscreen_wall(), device, method="cisp", naive=True)
    np.testing.assert_array_equal(b.hidden.missed.numpy(), ma)
    hidden = np.repeat((ma & 12) != 0, 2)  # slots of pixels with any hidden hit
    slot_kind = np.tile([4, 8], ma.size)
    pending = hidden & ((np.repeat(ma, 2) & slot_kind) != 0)
    assert pending.sum() > 40
    np.testing.assert_array_equal(b.hidden.hidden_tri.numpy()[pending], ta[pending])
    np.testing.assert_allclose(b.hidden.hidden_uvw.numpy()[pending], ua[pending], atol=2e-5)
    np.testing.assert_allclose(b.final.numpy(), fa, rtol=2e-5, atol=1e-6 * np.abs(fa).max())


def test_a_visible_hit_shows_what_the_march_would_have_found(device):
    """Straight down through flat water (orthographic): the composite's march finds each pixel's own floor point.
    Handed to the hidden-surface pass instead (every refracted ray flagged missed), the BVH hit is that visible point
    and the pixel shows its G-buffer radiance, caustic included: the image is the composite's own."""
    scene = analytic.flat_water(0.0, size=32)
    scene.camera = Camera(look_at_matrix((0.0, 1.2, 0.0), (0.0, -0.5, 0.0), up=(0, 0, -1)), orthographic=True,
                          ortho_height=0.6, width=32, height=32, near=0.05, far=10)
    r = render(scene, device, method="cisp")
    g = r.gbuffer
    shape = (g.height, g.width)
    water = g.water.depth.numpy().reshape(-1) > 0
    assert water.sum() > 500
    want = r.final.numpy().copy()
    missed = r.hidden.missed.numpy()
    assert not (missed & MISSED_REFRACTED).any()  # the march found every floor point
    missed[water] = MISSED_REFRACTED  # now hand them all over
    r.hidden.missed.assign(missed)
    r.final.zero_()
    r.hidden.render(g, r.lights, r.inputs.cameras, r.surface_radiance, r.sky_map, r.t_max, r.final)
    got = r.final.numpy()
    assert np.abs(want[water]).max() > 0.0
    close = np.isclose(got[water], want[water], rtol=1e-5, atol=1e-7).all(axis=-1)
    # a ray along the view axis may land one pixel over on CUDA (fused multiply-adds), as in test_evaluation
    assert close.mean() > 0.99, f"{(~close).sum()} of {close.size} water pixels differ; shape {shape}"
