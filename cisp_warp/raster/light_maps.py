"""A light's maps: its RSM views (whole, or fitted to the camera as cascades), and its shadow maps.

With ``LightViewSettings(fit="scene")`` a light has today's whole views (one orthographic view over the
specular geometry for a sun, the cone for a spot, six cube faces for a point light), and its RSM views
are those. With ``fit="camera"`` (the default) each whole view is also drawn small as a *pilot*, and
the RSM views photons start from are ``cascades`` windows of it per whole view, refitted every frame
to what the camera sees (:meth:`LightMaps.set_windows`, from ``cisp_warp.photons.fit``):

============  ======================  =====================================================================
list          views                   what reads them
============  ======================  =====================================================================
``rsm``       fitted cascades, or     photon emission (``rsm_batches``); an inactive cascade emits nothing
              the whole views
``pilot``     whole views, small      the fit's pilot photons; the brightest texel (luminance cutoff); the
                                      power outside every window (booked ``outside_fitted_view``); each
                                      view's cascades are windows of it turned about its axis
shadows       whole views             direct light: a sun's scene-wide view, and a spot or point light's
                                      whole views when its RSM views are fitted
============  ======================  =====================================================================

Nothing is allocated per frame: every cascade keeps its ``rsm_size``² buffers and only its view moves.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..errors import SceneError
from ..scene.device import DeviceScene
from ..scene.model import LAYER_OPAQUE, LAYER_SPECULAR, Light, LightKind
from . import kernels as K
from .rasterizer import Rasterizer, RSMView
from .views import (LightViewSettings, View, ViewParams, light_views, resized_view, rotated_view, shadow_view,
                    window_view)

EMPTY_WINDOW = (0.0, 0.0, 0.0, 0.0)


@wp.kernel
def _nearest_depth(spec_depth: wp.array(dtype=wp.float32), opaque_depth: wp.array(dtype=wp.float32),
                   out: wp.array(dtype=wp.float32)):
    p = wp.tid()
    d = spec_depth[p]
    out[p] = wp.where(d > 0.0, d, opaque_depth[p])


@wp.kernel
def texel_solid_angles(view: ViewParams, out: wp.array(dtype=wp.float32)):
    """Exact solid angle [sr] of every texel of a perspective view (``View.texel_solid_angle`` on the
    device, float64 inside: a fitted view's texels are small and the formula subtracts near-equal terms).

    ``out``: (H*W,) float32 (write)."""
    p = wp.tid()
    i = p % view.width
    j = p / view.width
    fx = wp.float64(view.fx)
    fy = wp.float64(view.fy)
    x0 = (wp.float64(i) - wp.float64(view.cx)) / fx
    x1 = (wp.float64(i + 1) - wp.float64(view.cx)) / fx
    y0 = (wp.float64(j) - wp.float64(view.cy)) / fy
    y1 = (wp.float64(j + 1) - wp.float64(view.cy)) / fy
    out[p] = wp.float32(_corner(x1, y1) - _corner(x0, y1) - _corner(x1, y0) + _corner(x0, y0))


@wp.func
def _corner(x: wp.float64, y: wp.float64) -> wp.float64:
    return wp.atan(x * y / wp.sqrt(wp.float64(1.0) + x * x + y * y))


def _view_key(v: View) -> tuple:
    return (np.asarray(v.to_world, np.float64).tobytes(), v.fx, v.fy, v.cx, v.cy, v.width, v.height)


class _ShadowView:
    """A depth-only view of every layer (a shadow map)."""

    def __init__(self, view: View, device):
        n = view.width * view.height
        self.view, self.params = view, view.params()
        self.visibility = wp.zeros(n, dtype=wp.uint64, device=device)
        self.depth = wp.zeros(n, dtype=wp.float32, device=device)
        self.tri = wp.zeros(n, dtype=wp.int32, device=device)

    def render(self, raster: Rasterizer) -> None:
        s = raster.scene
        raster.draw(self.params, LAYER_OPAQUE | LAYER_SPECULAR, self.visibility)
        wp.launch(K.resolve_depth, dim=self.view.width * self.view.height, device=s.device,
                  inputs=[self.params, self.visibility, s.points, s.indices, self.depth, self.tri])


class LightMaps:
    """All views of one light: RSM views (whole or fitted cascades), the fit's pilot views, shadow maps."""

    def __init__(self, scene: DeviceScene, light: Light, rsm_size: int,
                 view_settings: LightViewSettings | None = None):
        vs = view_settings or LightViewSettings(fit="scene")
        vs.validate()
        self.scene = scene
        self.light = light
        self.view_settings = vs
        self.fitted = vs.fit == "camera"
        self.rsm_size = int(rsm_size)
        whole = light_views(scene.scene, light, rsm_size)
        d = scene.device
        if self.fitted:
            self.pilot = [RSMView.allocate(resized_view(v, vs.pilot_size, f"pilot_{v.name[4:]}"), d) for v in whole]
            self.rsm = [RSMView.allocate(window_view(v, (0, 0, v.width, v.height), rsm_size, f"{v.name}_c{c}"), d)
                        for v in whole for c in range(vs.cascades)]
            self.cascades = vs.cascades
        else:
            self.pilot = []
            self.rsm = [RSMView.allocate(v, d) for v in whole]
            self.cascades = 1
        self.params = [r.view.params() for r in self.rsm]
        #: per RSM view: emits this frame; the finer cascade's window in its pixels; texels of the whole
        #: (pilot, or itself) view per texel, for the luminance cutoff
        self.active = [True] * len(self.rsm)
        self.skip_windows = [EMPTY_WINDOW] * len(self.rsm)
        self.texel_scale = [1.0] * len(self.rsm)
        #: per pilot view: its coarsest window, outside which nothing is sampled (pilot pixels)
        self.outside_windows = [EMPTY_WINDOW] * len(self.pilot)
        self.outside_angles = [0.0] * len(self.pilot)  #: the turn [rad] of those windows' frame
        self._shadows: list[_ShadowView] = []
        self._make_shadows(whole)

    def _make_shadows(self, whole: list[View]) -> None:
        sv = shadow_view(self.scene.scene, self.light, self.rsm_size)
        views = [sv] if sv is not None else (whole if self.fitted else [])
        if len(self._shadows) == len(views):
            for s, v in zip(self._shadows, views):
                s.view, s.params = v, v.params()
        else:
            self._shadows = [_ShadowView(v, self.scene.device) for v in views]

    @property
    def whole_rsm(self) -> list[RSMView]:
        """The views over all the light's specular geometry (pilot views when fitted)."""
        return self.pilot if self.fitted else self.rsm

    def set_light(self, light: Light) -> None:
        """Move or re-aim the light for the next frame: its views are refitted, every buffer is kept.

        The light must keep its kind and its number of views (a spot's cone may change: the texels'
        solid angles are rewritten). Every pass reads ``light`` and ``params`` at launch.
        """
        whole = light_views(self.scene.scene, light, self.rsm_size)
        n_whole = len(self.pilot) if self.fitted else len(self.rsm)
        if light.kind != self.light.kind or len(whole) != n_whole:
            raise SceneError(f"light '{light.name}' changes its kind or its views; build a new renderer",
                             prim=light.name)
        if self.fitted:
            for r, v in zip(self.pilot, whole):
                r.view = resized_view(v, r.width, r.view.name)
            for k, r in enumerate(self.rsm):
                r.view = window_view(whole[k // self.cascades], (0, 0, self.rsm_size, self.rsm_size), r.width, r.view.name)
                self.active[k] = True
            self._refresh_solid_angles(self.pilot)
        else:
            for r, v in zip(self.rsm, whole):
                r.view = v
        self._refresh_solid_angles(self.rsm)
        self.params = [r.view.params() for r in self.rsm]
        self._make_shadows(whole)
        self.light = light

    def _refresh_solid_angles(self, views: list[RSMView]) -> None:
        for r in views:
            if not r.view.orthographic:
                wp.launch(texel_solid_angles, dim=r.width * r.height, device=self.scene.device,
                          inputs=[r.view.params(), r.solid_angle])

    def set_windows(self, windows: list[list[tuple[float, float, float, float]]], angles: list[float] | None = None) -> None:
        """Fit the cascades for this frame: ``windows[b]`` are pilot view b's windows (x0, y0, x1, y1) in the
        pixels of that view turned by ``angles[b]`` [rad] about its axis (``views.rotated_view``; 0 when
        None), finest first and nested (``views.fit_windows``); fewer than ``cascades`` leaves the finest
        cascades inactive, none leaves them all inactive (nothing of b is seen). Views and texel solid
        angles are updated on the device; nothing is allocated."""
        if not self.fitted:
            raise ValueError("set_windows needs LightViewSettings(fit='camera')")
        angles = [0.0] * len(self.pilot) if angles is None else [float(a) for a in angles]
        changed = []
        for b, (pilot, wins) in enumerate(zip(self.pilot, windows)):
            base = rotated_view(pilot.view, angles[b])
            c_empty = self.cascades - len(wins)
            self.outside_windows[b] = tuple(wins[-1]) if wins else EMPTY_WINDOW
            self.outside_angles[b] = angles[b]
            for c in range(self.cascades):
                k = b * self.cascades + c
                r = self.rsm[k]
                if c < c_empty:
                    self.active[k] = False
                    self.skip_windows[k] = EMPTY_WINDOW
                    continue
                win = wins[c - c_empty]
                view = window_view(base, win, r.width, r.view.name)
                finer = wins[c - c_empty - 1] if c > c_empty else None
                self.active[k] = True
                sx, sy = r.width / (win[2] - win[0]), r.height / (win[3] - win[1])
                self.texel_scale[k] = 1.0 / (sx * sy)  # pilot texels per cascade texel
                self.skip_windows[k] = EMPTY_WINDOW if finer is None else (
                    (finer[0] - win[0]) * sx, (finer[1] - win[1]) * sy, (finer[2] - win[0]) * sx, (finer[3] - win[1]) * sy)
                if _view_key(view) != _view_key(r.view):
                    r.view = view
                    changed.append(r)
        self._refresh_solid_angles(changed)
        self.params = [r.view.params() for r in self.rsm]

    def shadow_maps(self) -> list[tuple[K.ViewParams, wp.array]]:
        """(view, depth of nearest surface of any layer) pairs that together cover what the light reaches."""
        if self._shadows:
            return [(s.params, s.depth) for s in self._shadows]
        return [(p, r.shadow_depth) for p, r in zip(self.params, self.rsm)]

    @property
    def shadow_view(self) -> View | None:
        """A sun's scene-wide shadow view (None for point and spot lights)."""
        sv = [s.view for s in self._shadows if s.view.orthographic]
        return sv[0] if sv else None

    def _render_rsm(self, raster: Rasterizer, view: K.ViewParams, r: RSMView) -> None:
        s = self.scene
        light = self.light
        n = r.width * r.height
        rgb = light.radiometric_rgb.astype(np.float32)
        axis = np.asarray(light.direction, dtype=np.float32)
        raster.draw(view, LAYER_OPAQUE, r.visibility)
        wp.launch(K.resolve_depth, dim=n, device=s.device, inputs=[view, r.visibility, s.points, s.indices, r.opaque_depth, r.opaque_tri])
        raster.draw(view, LAYER_SPECULAR, r.specular.visibility)
        r.specular.resolve(s, view, r.opaque_depth)
        wp.launch(K.rsm_flux, dim=n, device=s.device,
                  inputs=[view, wp.vec3(*rgb), wp.vec3(*axis), int(light.kind == LightKind.SPOT),
                          float(light.cone_angle), float(light.cone_softness), r.solid_angle, r.specular.tri_id, r.flux])
        wp.launch(_nearest_depth, dim=n, device=s.device, inputs=[r.specular.depth, r.opaque_depth, r.shadow_depth])

    def render_pilot(self, raster: Rasterizer) -> None:
        """Draw the pilot views (before the fit); nothing when the views are not fitted."""
        for r in self.pilot:
            self._render_rsm(raster, r.view.params(), r)

    def render(self, raster: Rasterizer) -> None:
        """Draw the active RSM views and the shadow maps."""
        for view, r, active in zip(self.params, self.rsm, self.active):
            if active:
                self._render_rsm(raster, view, r)
        for sv in self._shadows:
            sv.render(raster)
