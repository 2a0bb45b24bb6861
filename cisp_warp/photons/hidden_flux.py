"""Photons where the camera cannot see them: a light-space map of every landed photon, read at the composite's hidden hits.

A screen-space photon map holds irradiance only on the camera's surfaces: a photon whose landing point the camera
does not see (CISP's reprojection behind a camera surface, SSPM's depth test; both book it ``occluded``, or
``lost_camera`` where it lands outside the image) is dropped from it. The composite's refracted rays reach such
points all the same (the pool's floor in the coping's lee, docs/perf_notes.md sections 22, 28 and 31), so every
photon that lands (where the camera sees it or not) is also added, as power [W], to a map over its light's *whole*
views (the views of all its specular geometry: ``LightMaps.pilot_views`` when the RSM views are fitted cascades):
a grid of ``map_w`` × ``map_h`` texels per view, the photon in the first view that holds its landing point
(:func:`store_hidden`). At a hidden hit ``y`` with normal ``n``, :func:`hidden_irradiance` turns a small gather of
that map into irradiance [W/m²] by dividing by the area of the receiver one texel covers there
(:func:`texel_receiver_area`: the light view's texel footprint at ``y``, across the light's ray, over |cos| of the
ray and ``n``): a histogram density estimate in light space, no fudge factor.

Why every landed photon, not only the hidden ones: a hidden strip (the floor in a wall's lee) lies beside floor the
camera sees; a map of the hidden photons alone would read a gather window that straddles the two as too dark (0.58-0.77
of the exact answer in the flat test of tests/test_shade_hidden.py). Why the whole views, not the photon's own
cascade: a fitted cascade covers what the camera sees; a photon landing beyond its window would be lost (the
pool's near-wall band read 43.1 instead of 48.1 W/(m² sr) for sspm, section 31).

The power is not new energy: each photon keeps its one ledger entry (``stored``, ``rejected``, ``occluded``,
``lost_camera``); this map is a second record of where it landed, read only where the camera's map cannot be, so
the ledger still closes and nothing is counted twice in the image.

Buffers (one per light, zeroed with the photon map each frame):

``flux``  (whole views × map_h × map_w,) vec3: power [W] per map texel, RGB (accumulate)
"""

from __future__ import annotations

import math

import warp as wp

from ..raster.views import ViewParams, world_project

#: photons per map texel the map size aims for were a whole view's photons spread over all of it (they fall on the
#: specular part only, so more: relative noise of one texel's estimate <= 1/sqrt(16) before the gather)
HIDDEN_PHOTONS_PER_TEXEL = 16
#: the lookup's gather: (2 g + 1)² map texels averaged (g = 1: 3 × 3)
HIDDEN_GATHER = 1


def hidden_stride(view_width: int, view_height: int, photons: int) -> int:
    """RSM texels per hidden-map texel along each axis: ``photons`` spread over a ``view_width`` × ``view_height``
    view give about HIDDEN_PHOTONS_PER_TEXEL photons a map texel (1 when the view is already that dense)."""
    texels = view_width * view_height
    return max(1, int(math.ceil(math.sqrt(HIDDEN_PHOTONS_PER_TEXEL * texels / max(1, photons)))))


def map_shape(view_width: int, view_height: int, stride: int) -> tuple[int, int]:
    """(width, height) of a map of ``stride`` × ``stride`` texels of a view of that size."""
    return (view_width + stride - 1) // stride, (view_height + stride - 1) // stride


@wp.func
def map_texel(view: ViewParams, map_w: int, map_h: int, y: wp.vec3) -> wp.vec3i:
    """(column, row, 1) of the map texel of ``view`` (a ``map_w`` × ``map_h`` grid over its image) that ``y`` [m]
    projects to; (0, 0, 0) outside the view."""
    q = world_project(view, y)
    if view.far <= 0.0 or q[2] <= 0.0 or q[0] < 0.0 or q[1] < 0.0 or q[0] >= float(view.width) or q[1] >= float(view.height):
        return wp.vec3i(0, 0, 0)
    i = wp.min(int(q[0] * float(map_w) / float(view.width)), map_w - 1)
    j = wp.min(int(q[1] * float(map_h) / float(view.height)), map_h - 1)
    return wp.vec3i(i, j, 1)


@wp.func
def store_hidden(views: wp.array(dtype=ViewParams), y: wp.vec3, power: wp.vec3, flux: wp.array(dtype=wp.vec3),
                 map_w: int, map_h: int):
    """Add a photon's ``power`` [W] landing at ``y`` [m] to the map texel it projects to in the first of the light's
    whole ``views`` that holds it (each view's map is ``map_w`` × ``map_h`` texels of ``flux``, one after another);
    nothing outside them all, or when the map is empty (a method that keeps none)."""
    if flux.shape[0] == 0:
        return
    for v in range(views.shape[0]):
        t = map_texel(views[v], map_w, map_h, y)
        if t[2] != 0:
            wp.atomic_add(flux, (v * map_h + t[1]) * map_w + t[0], power)
            return


@wp.func
def texel_receiver_area(view: ViewParams, map_w: int, map_h: int, y: wp.vec3, n: wp.vec3) -> float:
    """Area [m²] of the surface through ``y`` with unit normal ``n`` that one map texel (of a ``map_w`` × ``map_h``
    grid over ``view``'s image) covers there: the texel's footprint on the plane of constant depth through ``y``
    ((W/map_w)/fx · (H/map_h)/fy, times depth² in perspective), across the light's ray (× cos between the ray and the
    view axis), then onto the receiver (÷ |cos| between the ray and ``n``)."""
    axis = wp.transform_vector(view.view_to_world, wp.vec3(0.0, 0.0, -1.0))  # the view's forward direction
    a = (float(view.width) / float(map_w)) * (float(view.height) / float(map_h)) / (view.fx * view.fy)
    ray = axis
    if view.orthographic == 0:
        eye = wp.transform_point(view.view_to_world, wp.vec3(0.0))
        ray = wp.normalize(y - eye)
        z = wp.dot(y - eye, axis)
        a = a * z * z * wp.dot(ray, axis)
    return a / wp.max(wp.abs(wp.dot(ray, n)), 1.0e-6)


@wp.func
def hidden_irradiance(views: wp.array(dtype=ViewParams), flux: wp.array(dtype=wp.vec3), map_w: int, map_h: int,
                      gather: int, y: wp.vec3, n: wp.vec3) -> wp.vec3:
    """Irradiance [W/m²] of one light's landed photons at ``y`` (unit normal ``n``): in the first whole view that
    holds ``y`` (where :func:`store_hidden` put the photons landing there), the mean power of the (2 ``gather`` + 1)²
    map texels around ``y``'s (those inside the map), over the receiver's area of one texel; zero outside them all."""
    for v in range(views.shape[0]):
        view = views[v]
        t = map_texel(view, map_w, map_h, y)
        if t[2] != 0:
            total = wp.vec3(0.0)
            count = int(0)
            for j in range(t[1] - gather, t[1] + gather + 1):
                for i in range(t[0] - gather, t[0] + gather + 1):
                    if i >= 0 and j >= 0 and i < map_w and j < map_h:
                        total = total + flux[(v * map_h + j) * map_w + i]
                        count = count + 1
            return total / (float(count) * texel_receiver_area(view, map_w, map_h, y, n))
    return wp.vec3(0.0)


class HiddenFlux:
    """Every light's flux map over its whole views (module docstring), allocated once: per light ``flux[light]``
    ((whole views × map_h × map_w,) vec3), ``views[light]`` (its whole views: ``LightMaps.pilot_views`` when the RSM
    views are fitted cascades, else ``LightMaps.views``; the light's own arrays, refitted with it) and
    ``shape[light]`` = (map_w, map_h)."""

    def __init__(self, lights, photons: int, device):
        self.device = wp.get_device(device)
        self.gather = HIDDEN_GATHER
        self.views, self.flux, self.shape = [], [], []
        sizes = []
        for lm in lights:
            views = lm.pilot_views if lm.fitted else lm.views
            n_views = len(lm.pilot) if lm.fitted else len(lm.rsm)
            edge = lm.rsm_size  # the whole views' edge at the RSM size [texels]
            s = hidden_stride(edge, edge, max(1, photons // n_views))
            w, h = map_shape(edge, edge, s)
            self.views.append(views)
            self.shape.append((w, h))
            sizes.append(n_views * w * h)
        #: every light's map in one allocation, ``flux[light]`` a slice of it: a frame clears them with one write
        #: (:meth:`zero`, or ``common.clear_frame_wide`` with the photon pass's other accumulators)
        self.all_flux = wp.zeros(max(1, sum(sizes)), dtype=wp.vec3, device=self.device)
        start = 0
        for n in sizes:
            self.flux.append(self.all_flux[start : start + n])
            start += n

    def zero(self) -> None:
        self.all_flux.zero_()


__all__ = ["HIDDEN_GATHER", "HIDDEN_PHOTONS_PER_TEXEL", "HiddenFlux", "hidden_irradiance", "hidden_stride",
           "map_shape", "map_texel", "store_hidden", "texel_receiver_area"]
