"""Cascaded Image-Space Photon Tracing: photons from the RSMs, traced light view -> camera view."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..errors import SceneError
from ..raster import GBuffer, LightMaps
from ..raster.views import View
from . import kernels_cisp as K


@dataclass(frozen=True)
class PhotonSettings:
    """Settings of the photon pass; every field reaches the kernel."""

    photons: int = 1 << 20  #: photons per light per frame, split evenly over a light's RSM views
    seed: int = 0  #: with the frame number, reproduces a frame exactly
    roughness_cutoff: float = 0.3  #: texels rougher than this are culled (seed 000, 3.1)
    luminance_cutoff: float = 0.01  #: texels dimmer than this fraction of the brightest are culled
    max_steps: int = 2048  #: march steps per view (about the image diagonal at 1080p)
    thickness: float = 0.02  #: [m] absolute surface thickness of the depth buffers
    thickness_rel: float = 0.02  #: relative surface thickness (× depth)
    footprint: str = "exact"  #: "exact" pixel footprint, or "paper" (seed 000 eq. 3) to reproduce its numbers
    cascade: bool = True  #: march on in the camera view (False: light view only, for comparison)

    def validate(self) -> None:
        if not isinstance(self.photons, (int, np.integer)) or self.photons < 1 or self.photons > 1 << 28:
            raise SceneError(f"--photons must be an integer in [1, 2^28], got {self.photons!r}")
        if self.footprint not in ("exact", "paper"):
            raise SceneError(f"footprint must be 'exact' or 'paper', got {self.footprint!r}")
        if self.max_steps < 1:
            raise SceneError(f"max_steps must be at least 1, got {self.max_steps}")
        for name in ("roughness_cutoff", "luminance_cutoff", "thickness", "thickness_rel"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise SceneError(f"{name} must be a finite number >= 0, got {v!r}")


def frame_random(seed: int, frame: int, stream: int) -> tuple[int, int, int]:
    """Per (seed, frame, stream): the R2 sequence's Cranley-Patterson rotation as two uint32 fixed-point
    offsets, and the seed of the photons' random streams; all as int32 bit patterns for the kernel."""
    h = hashlib.blake2b(f"{seed}:{frame}:{stream}".encode(), digest_size=12).digest()
    words = [int.from_bytes(h[4 * i : 4 * i + 4], "little") for i in range(3)]
    a, b, c = (v - (1 << 32) if v >= 1 << 31 else v for v in words)
    return a, b, c


def camera_pixel_solid_angle(view: View) -> np.ndarray:
    """Exact solid angle of every camera pixel, flat (H*W,) float32 (zeros for orthographic views)."""
    if view.orthographic:
        return np.zeros(view.width * view.height, np.float32)
    return view.texel_solid_angle().astype(np.float32).reshape(-1)


class Ledger:
    """Where the photons' power went in one frame, per RGB channel [W]."""

    def __init__(self, values: np.ndarray):
        self.values = np.asarray(values, dtype=np.float64).reshape(K.LEDGER_ENTRIES, 3)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[K.LEDGER_NAMES.index(name)]

    def parts(self) -> dict[str, np.ndarray]:
        return {n: self.values[i] for i, n in enumerate(K.LEDGER_NAMES) if n not in ("sampled", "reflected", "refracted")}

    def closure(self) -> float:
        """Relative mismatch |sampled − Σ parts| / sampled, summed over channels (0 when it closes)."""
        whole = self["sampled"].sum()
        parts = sum(v.sum() for v in self.parts().values())
        return abs(whole - parts) / whole if whole > 0 else 0.0

    def as_dict(self) -> dict[str, float]:
        return {n: float(self.values[i].sum()) for i, n in enumerate(K.LEDGER_NAMES)}

    def table(self) -> str:
        whole = self["sampled"].sum()
        rows = [f"{'entry':<18}{'power [W]':>14}{'share':>9}"]
        for i, n in enumerate(K.LEDGER_NAMES):
            v = self.values[i].sum()
            share = f"{100.0 * v / whole:8.3f}%" if whole > 0 else "      -"
            rows.append(f"{n:<18}{v:14.6g}{share}")
        rows.append(f"closes to {self.closure():.2e} relative (reflected + refracted = traced, not summed)")
        return "\n".join(rows)


class CISP:
    """The photon pass of seed 000: allocates once, ``trace`` fills ``photon_map`` each frame."""

    def __init__(self, gbuffer: GBuffer, camera_view: View, lights: list[LightMaps], settings: PhotonSettings, device,
                 t_max: float):
        """``t_max``: the longest ray a photon may travel [m] (the renderer's scene-wide bound)."""
        settings.validate()
        self.settings = settings
        self.device = wp.get_device(device)
        self.lights = lights
        n = gbuffer.width * gbuffer.height
        self.photon_map = wp.zeros(n, dtype=wp.vec3, device=self.device)
        self.ledger = wp.zeros(3 * K.LEDGER_ENTRIES, dtype=wp.float64, device=self.device)
        self.max_lum = wp.zeros(len(lights), dtype=wp.float32, device=self.device)
        self._max_lum_of = [self.max_lum[i : i + 1] for i in range(len(lights))]  # per-light views, made once
        per_view = max(max(1, settings.photons // max(1, len(lm.rsm))) for lm in lights) if lights else 1
        self.hits = wp.zeros(per_view, dtype=wp.vec4, device=self.device)
        self.solid_angle = wp.array(camera_pixel_solid_angle(camera_view), dtype=wp.float32, device=self.device)
        self.t_max = float(t_max)

    def photons_per_view(self, lm: LightMaps) -> int:
        return max(1, self.settings.photons // len(lm.rsm))

    def trace(self, gbuffer: GBuffer, camera: wp.struct, frame: int) -> None:
        """Trace every light's photons for ``frame`` into ``photon_map`` (zeroed first) and the ledger."""
        s = self.settings
        self.photon_map.zero_()
        self.ledger.zero_()
        self.max_lum.zero_()
        mode = K.FOOTPRINT_EXACT if s.footprint == "exact" else K.FOOTPRINT_PAPER
        for li, lm in enumerate(self.lights):
            lum = self._max_lum_of[li]
            for r in lm.rsm:
                wp.launch(K.max_luminance, dim=r.width * r.height, inputs=[r.flux, lum], device=self.device)
            light = lm.light
            for vi, (params, r) in enumerate(zip(lm.params, lm.rsm)):
                n = self.photons_per_view(lm)
                sx, sy, rng_seed = frame_random(s.seed, frame, li * 64 + vi)
                sp = r.specular
                wp.launch(K.trace_photons, dim=n, device=self.device, inputs=[
                    params, int(light.kind), wp.vec3(*np.asarray(light.position, np.float32)),
                    wp.vec3(*np.asarray(light.direction, np.float32)),
                    r.opaque_depth, sp.depth, sp.position, sp.normal, r.flux, sp.roughness, sp.ior, sp.tri_id,
                    lm.scene.triangle_material, lm.scene.opacity, lm.scene.albedo, lum,
                    camera, gbuffer.depth, gbuffer.position, gbuffer.normal, self.solid_angle,
                    n, rng_seed, wp.vec2i(sx, sy),
                    float(s.roughness_cutoff), float(s.luminance_cutoff), int(s.max_steps),
                    float(s.thickness), float(s.thickness_rel), self.t_max, mode, int(s.cascade),
                    self.photon_map, self.ledger, self.hits])

    def read_ledger(self) -> Ledger:
        """Host copy of this frame's ledger (a device->host copy: not for the inner frame loop)."""
        return Ledger(self.ledger.numpy())
