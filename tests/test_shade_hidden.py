"""The composite's rays that screen space cannot follow (cisp_warp/shade_hidden.py): what they reach against exact
answers, the BVH trace against its every-triangle twin, and the hand-over from the composite's march."""

import math

import numpy as np
import pytest

from cisp_warp import analytic
from cisp_warp.optics import fresnel_dielectric_np
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.scene import Camera, Light, LightKind
from cisp_warp.scene.model import look_at_matrix
from cisp_warp.shade import MISSED_REFLECTED, MISSED_REFRACTED
from cisp_warp.photons.hidden_flux import HIDDEN_GATHER
from cisp_warp.shade_hidden import HIDDEN_REFLECTED, HIDDEN_REFRACTED

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


def render(scene, device, method="none", naive=False, hidden_rays="both"):
    r = Renderer(scene, RenderSettings(rsm_size=128, method=method, denoiser="none", hidden_rays=hidden_rays,
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


# --- the caustic at hidden hits (photons.hidden_flux) ---

SUN_TILT = np.array([0.6, -0.8, 0.0])  # travel: across the wall's plane, so no photon meets the wall, none shadows
WALL_NEAR_Z = 0.1


def water_over_hidden_floor(size=48):
    """Flat water (1 m square, y = 0) 0.5 m over a floor, an opaque wall under the water (z = 0.1, facing the camera,
    -0.5 <= y <= -0.05) that hides the floor behind it from the camera's straight view; the camera's refracted rays,
    steeper, pass over the wall's top and reach that floor (the pool's coping, docs/perf_notes.md section 22). The sun
    travels along +x, parallel to the wall: the floor behind it gets the water's refracted light and nothing else."""
    water = (analytic.quad(0, 0, 0, (0.5, 0, 0), (0, 0, -0.5)), 1)
    floor = (analytic.quad(0, -0.5, 0, (2, 0, 0), (0, 0, -2)), 0)
    wall = (analytic.quad(0, -0.275, WALL_NEAR_Z, (0.6, 0, 0), (0, 0.225, 0)), 0)
    cam = Camera(look_at_matrix((0.0, 1.5, 1.2), (0.0, 0.0, 0.0)), fov_y=math.radians(40), width=size, height=size,
                 near=0.05, far=10)
    sun = Light(LightKind.DISTANT, "sun", intensity=E_SUN, direction=tuple(SUN_TILT))
    return analytic.build([water, floor, wall], cam, [sun])


def refracted_floor_hits(r):
    """Per camera pixel (flat): the refracted camera ray's floor point (y = -0.5) and its throughput (1 - F)/η²."""
    x = r.gbuffer.water.position.numpy().astype(np.float64)
    eye = np.array([0.0, 1.5, 1.2])
    v = eye - x
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    f = fresnel_dielectric_np(v[:, 1], 1.33)
    cos_t = np.sqrt(1.0 - (1.0 - v[:, 1] ** 2) / 1.33 ** 2)
    t_dir = -v / 1.33 + np.array([0.0, 1.0, 0.0]) * (v[:, 1:2] / 1.33 - cos_t[:, None])
    return x + t_dir * (-0.5 / t_dir[:, 1:2]), (1.0 - f) / 1.33 ** 2


def test_hidden_floor_shows_the_refracted_sun(device):
    """The floor behind the wall, seen only through the water: the photons landing there are booked occluded and
    kept in light space; the refracted ray's hidden hit sees their irradiance, which under flat water is exactly
    E = (1 - F(θ_sun)) E_sun cos θ_sun. Each band pixel shows (1 - F_cam)/η² · ρ/π · E (no direct light through the
    water, no sky): its mean within 3% (photon noise: ~16 per map texel, 3×3 gathered, ~40 texels in the band), every
    pixel within 25%, for cisp (light-view march) and sspm (BVH). Without the hidden rays ("none") the pixel showed
    the wall; without stored photons (method "none") it is black."""
    cos_sun = -SUN_TILT[1]
    e_floor = (1.0 - fresnel_dielectric_np(np.array([cos_sun]), 1.33)[0]) * E_SUN * cos_sun
    for method in ("cisp", "sspm"):
        r = render(water_over_hidden_floor(), device, method=method, hidden_rays="refracted")
        missed = r.hidden.missed.numpy()
        floor, w = refracted_floor_hits(r)
        # the floor under the water's light, a gather window (3 × 3 map texels) clear of its edge at x = -0.25
        band = ((missed & HIDDEN_REFRACTED) != 0) & (floor[:, 0] > 0.05) & (floor[:, 0] < 0.55)
        assert band.sum() > 20, band.sum()
        assert (floor[band, 2] < WALL_NEAR_Z).all()  # behind the wall
        assert not (missed & MISSED_REFLECTED).any()  # reflections keep the sky ("refracted")
        want = w[band] * ALBEDO / math.pi * e_floor
        got = r.final.numpy()[band]
        ratio = got / want[:, None]
        assert abs(ratio.mean() - 1.0) < 0.03, (method, ratio.mean())
        assert np.abs(ratio - 1.0).max() < 0.25, (method, np.abs(ratio - 1.0).max())
        ledger = r.photons.read_ledger()
        assert abs(ledger.closure()) < 1e-9  # the kept photons are booked as before (occluded): the ledger closes
        assert ledger["occluded"].sum() > 0
    black = render(water_over_hidden_floor(), device, method="none", hidden_rays="refracted")
    assert np.abs(black.final.numpy()[band]).max() == 0.0


def hidden_irradiance_np(views, flux, map_w, map_h, gather, y, n):
    """numpy twin of photons.hidden_flux.hidden_irradiance (float64): the first view holding each point, project,
    gather, divide by the receiver's area of one map texel."""
    out = np.zeros((len(y), 3))
    for i in range(len(y)):
        for v, view in enumerate(views):
            q = view.project(y[i])
            if q[2] <= 0 or not (0 <= q[0] < view.width and 0 <= q[1] < view.height):
                continue
            ix = min(int(q[0] * map_w / view.width), map_w - 1)
            iy = min(int(q[1] * map_h / view.height), map_h - 1)
            js = [(jy, jx) for jy in range(iy - gather, iy + gather + 1) for jx in range(ix - gather, ix + gather + 1)
                  if 0 <= jx < map_w and 0 <= jy < map_h]
            total = sum(flux[(v * map_h + jy) * map_w + jx].astype(np.float64) for jy, jx in js)
            to_world = np.asarray(view.to_world, np.float64)
            axis = -to_world[:3, 2]
            area = (view.width / map_w) * (view.height / map_h) / (view.fx * view.fy)
            ray = axis
            if not view.orthographic:
                eye = to_world[:3, 3]
                ray = (y[i] - eye) / np.linalg.norm(y[i] - eye)
                z = np.dot(y[i] - eye, axis)
                area *= z * z * np.dot(ray, axis)
            out[i] = total / len(js) / (area / max(abs(np.dot(ray, n[i])), 1e-6))
            break
    return out


def test_hidden_caustic_matches_its_twin(device):
    """hidden_caustic's lookup against the numpy twin, on the hidden floor's band: the added radiance per pixel to
    float rounding. The map is over the light's whole views (pilot views: static here, known on the host)."""
    scene = water_over_hidden_floor()
    r = render(scene, device, method="sspm", hidden_rays="refracted")
    missed = r.hidden.missed.numpy()
    band = (missed & HIDDEN_REFRACTED) != 0
    assert band.sum() > 20
    # the radiance the caustic adds: render the hidden pass again without the flux maps
    g = r.gbuffer
    args = (g, r.lights, r.inputs.cameras, r.surface_radiance, r.sky_map, r.t_max)
    base = r.final.numpy().copy()  # with it
    r.hidden.missed.assign(missed & (MISSED_REFRACTED | MISSED_REFLECTED))
    r.final.zero_()
    r.hidden.render(*args, r.final)  # without
    added = base - r.final.numpy()
    tri = r.hidden.hidden_tri.numpy()[0::2][band]
    uvw = r.hidden.hidden_uvw.numpy()[0::2][band]
    pts, idx = scene.points.astype(np.float64), scene.indices.reshape(-1, 3)
    t = np.abs(tri) - 1
    y = (pts[idx[t, 0]] * uvw[:, :1] + pts[idx[t, 1]] * uvw[:, 1:2] + pts[idx[t, 2]] * (1 - uvw[:, :1] - uvw[:, 1:2]))
    n = np.tile([0.0, 1.0, 0.0], (len(y), 1))  # every hidden hit is on the floor
    assert np.allclose(y[:, 1], -0.5, atol=1e-5)
    lm, hf = r.lights[0], r.photons.hidden
    views = [p.view for p in lm.pilot] if lm.fitted else [p.view for p in lm.rsm]
    w, h = hf.shape[0]
    e = hidden_irradiance_np(views, hf.flux[0].numpy(), w, h, HIDDEN_GATHER, y, n)
    want = e * (ALBEDO / math.pi) * uvw[:, 2:3]
    assert want.max() > 0
    np.testing.assert_allclose(added[band], want, rtol=1e-4, atol=1e-6 * want.max())


@pytest.mark.parametrize("method,splat,traced", [("cisp", "point", True), ("sspm", "point", True),
                                                 ("caustics_map", "point", False), ("cisp", "wavefront", False)])
def test_hidden_rays_only_where_the_photons_keep_their_landings(device, method, splat, traced):
    """The composite hands rays to the BVH only where a hidden hit can get its caustic (the photons keep a
    hidden-flux map); the others keep the screen-space fallbacks."""
    r = Renderer(analytic.sinusoidal_water(32, 18),
                 RenderSettings(rsm_size=32, method=method, denoiser="none",
                                photons=PhotonSettings(photons=1_000, splat=splat)), device=device)
    assert (r._hidden_bits != 0) == traced
    assert (getattr(r.photons, "hidden", None) is not None) == traced
