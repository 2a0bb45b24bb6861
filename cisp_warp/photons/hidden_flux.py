"""Photons that land where the camera cannot see, kept in light space for the composite's hidden hits.

A screen-space photon map holds irradiance only on the camera's surfaces: a photon whose landing point the camera
does not see (CISP's reprojection behind a camera surface, SSPM's depth test; both book it ``occluded``, or
``lost_camera`` where it lands outside the image) is dropped from it. The composite's refracted rays reach such
points all the same (the pool's floor in the coping's lee, docs/perf_notes.md sections 22, 28 and 31), so those
photons are kept here instead: each light view (RSM view) the photon left from has a *hidden flux map*, a grid of
``stride`` × ``stride`` RSM texels, into which the photon's power [W] is added at the texel its landing point
projects to (:func:`store_hidden`). At a hidden hit ``y`` with normal ``n``, :func:`hidden_irradiance` turns the
texel's power into irradiance [W/m²] by dividing by the area of the receiver that texel covers there
(:func:`texel_receiver_area`: the light view's texel footprint at ``y``, across the light's ray, over |cos| of the
ray and ``n``): a histogram density estimate in light space, no fudge factor.

The power is not new energy: it is what the ledger books as ``occluded`` / ``lost_camera`` (the photon map's
ledger says where the power went relative to the camera's map; this map is a second record of part of it, so the
booking stays as it was and the ledger still closes).

Buffers (one per light view, zeroed with the photon map each frame):

``flux``  ((H_l // stride rounded up) * (W_l // stride rounded up),) vec3: power [W] per map texel, RGB (accumulate)
"""

from __future__ import annotations

import math

import warp as wp

from ..raster.views import ViewParams, world_project

#: photons per map texel the stride aims for where a light view's specular texels all emit (relative noise of one
#: texel's estimate ~ 1/sqrt(count) before the gather)
HIDDEN_PHOTONS_PER_TEXEL = 16
#: the lookup's gather: (2 g + 1)² map texels averaged (g = 1: 3 × 3)
HIDDEN_GATHER = 1


def hidden_stride(view_width: int, view_height: int, photons: int) -> int:
    """RSM texels per hidden-map texel along each axis: ``photons`` spread over a ``view_width`` × ``view_height``
    view give about HIDDEN_PHOTONS_PER_TEXEL photons a map texel (1 when the view is already that dense)."""
    texels = view_width * view_height
    return max(1, int(math.ceil(math.sqrt(HIDDEN_PHOTONS_PER_TEXEL * texels / max(1, photons)))))


def map_shape(view_width: int, view_height: int, stride: int) -> tuple[int, int]:
    """(width, height) of a hidden flux map of stride ``stride`` over a view of that size."""
    return (view_width + stride - 1) // stride, (view_height + stride - 1) // stride


@wp.func
def store_hidden(view: ViewParams, y: wp.vec3, power: wp.vec3, flux: wp.array(dtype=wp.vec3), stride: int):
    """Add a photon's ``power`` [W] landing at ``y`` [m] to the map texel of ``view`` it projects to (nothing when it
    lies outside the view, or when the map is empty: a method that keeps none)."""
    if flux.shape[0] == 0:
        return
    q = world_project(view, y)
    if q[2] <= 0.0 or q[0] < 0.0 or q[1] < 0.0 or q[0] >= float(view.width) or q[1] >= float(view.height):
        return
    mw = (view.width + stride - 1) / stride
    wp.atomic_add(flux, (int(q[1]) / stride) * mw + int(q[0]) / stride, power)


@wp.func
def texel_receiver_area(view: ViewParams, stride: int, y: wp.vec3, n: wp.vec3) -> float:
    """Area [m²] of the surface through ``y`` with unit normal ``n`` that one map texel (``stride`` × ``stride``
    texels of ``view``) covers there: the texel's footprint on the plane of constant depth through ``y``
    ((s/fx)(s/fy), times depth² in perspective), across the light's ray (× cos between the ray and the view axis),
    then onto the receiver (÷ |cos| between the ray and ``n``)."""
    axis = wp.transform_vector(view.view_to_world, wp.vec3(0.0, 0.0, -1.0))  # the view's forward direction
    s = float(stride)
    a = s * s / (view.fx * view.fy)
    ray = axis
    if view.orthographic == 0:
        eye = wp.transform_point(view.view_to_world, wp.vec3(0.0))
        ray = wp.normalize(y - eye)
        z = wp.dot(y - eye, axis)
        a = a * z * z * wp.dot(ray, axis)
    return a / wp.max(wp.abs(wp.dot(ray, n)), 1.0e-6)


@wp.func
def hidden_irradiance(view: ViewParams, flux: wp.array(dtype=wp.vec3), stride: int, gather: int, y: wp.vec3,
                      n: wp.vec3) -> wp.vec3:
    """Irradiance [W/m²] of the hidden photons of ``view`` at ``y`` (unit normal ``n``): the mean power of the
    (2 ``gather`` + 1)² map texels around the one ``y`` projects to (those inside the map), over the receiver's area
    of one texel; zero outside the view."""
    q = world_project(view, y)
    if q[2] <= 0.0 or q[0] < 0.0 or q[1] < 0.0 or q[0] >= float(view.width) or q[1] >= float(view.height):
        return wp.vec3(0.0)
    mw = (view.width + stride - 1) / stride
    mh = (view.height + stride - 1) / stride
    ix = int(q[0]) / stride
    iy = int(q[1]) / stride
    total = wp.vec3(0.0)
    count = int(0)
    for j in range(iy - gather, iy + gather + 1):
        for i in range(ix - gather, ix + gather + 1):
            if i >= 0 and j >= 0 and i < mw and j < mh:
                total = total + flux[j * mw + i]
                count = count + 1
    return total / (float(count) * texel_receiver_area(view, stride, y, n))


class HiddenFlux:
    """Every light view's hidden flux map (module docstring), allocated once: ``flux[light][view]``, ``stride[light]``
    (one per light: its views share a size)."""

    def __init__(self, lights, photons: int, device):
        self.device = wp.get_device(device)
        self.gather = HIDDEN_GATHER
        self.stride, self.flux = [], []
        for lm in lights:
            r0 = lm.rsm[0]
            per_view = max(1, photons // max(1, len(lm.rsm)))
            s = hidden_stride(r0.width, r0.height, per_view)
            self.stride.append(s)
            self.flux.append([wp.zeros(max(1, map_shape(r.width, r.height, s)[0] * map_shape(r.width, r.height, s)[1]),
                                       dtype=wp.vec3, device=self.device) for r in lm.rsm])

    def zero(self) -> None:
        for maps in self.flux:
            for m in maps:
                m.zero_()


__all__ = ["HIDDEN_GATHER", "HIDDEN_PHOTONS_PER_TEXEL", "HiddenFlux", "hidden_irradiance", "hidden_stride",
           "map_shape", "store_hidden", "texel_receiver_area"]
