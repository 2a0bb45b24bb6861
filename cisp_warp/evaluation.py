"""Driving the methods for measurement: which settings a method runs with, frames with stage timing,
and references computed once and cached on disk. Used by ``tools/evaluate.py``, ``tools/stability.py``
and their tests; the figures themselves are :mod:`cisp_warp.metrics`.

Every method runs with every denoiser of the renderer (``caustic``, the default; ``svgf``, the paper's;
``none``, the raw photon map); ``caustics_map`` also with ``own``, seed 004's own filters:

==============  ===================================================================================
method          denoiser
==============  ===================================================================================
cisp, sspm      ``RenderSettings(denoiser=...)``: caustic, svgf or none
caustics_map    own: the 4-frame temporal mean and the 7×7 Gaussian in the light-space caustic map
                (``cmap_history=4``, ``cmap_gather="light"``, eye-space denoiser none); caustic, svgf,
                none: the raw light-space map (``cmap_history=1``, ``cmap_gather="eye"``) through the
                renderer's denoiser
==============  ===================================================================================

References of still scenes (:func:`accumulated_reference`) accumulate independent reference frames until
their own noise over their caustic mask is below a target, cached on disk so that a later run goes on
where an earlier one stopped.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
import warp as wp

from .denoise import CausticSettings
from .photons import PhotonSettings
from .raster.views import camera_view
from .render import Renderer, RenderSettings
from .scene import Scene
from .timing import StageTimer

#: the AOVs every figure needs, copied to the host per measured frame
MEASURED_AOVS = ("photon_map", "caustics", "final", "depth", "position", "normal", "tri_id", "motion")
#: what a cached reference keeps
REFERENCE_AOVS = MEASURED_AOVS + ("caustics_stderr",)
METHODS = ("cisp", "sspm", "caustics_map")


#: revision of what a cached reference holds, part of its cache key: a reference cached before its final image
#: saw the sky (paths leaving the scene, sky irradiance at their ends) is not reused
REFERENCE_REVISION = "sky"

#: the renderer's denoisers every method is measured with, and caustics_map's own filters (seed 004)
DENOISERS = ("caustic", "svgf", "none", "own")
#: the caustics denoiser without the caustic flow (``CausticSettings.caustic_flow`` False: its history follows the
#: surface's motion only, the default before docs/perf_notes.md section 35; cisp only, the other methods have no
#: flow), not in DENOISERS: for the stability suite's ``--denoisers``
SURFACE_DENOISER = "caustic-surface"
#: the caustics denoiser without the caustic flow whose history is forgotten before every frame: the spatial filter
#: alone on each frame's photons, the error a frame reaches when nothing of its past can be used (a caustic that
#: reshapes faster than the history can follow); every method, not in DENOISERS: for the stability suite
SINGLE_DENOISER = "caustic-single"
#: denoisers the stability suite takes beyond DENOISERS
EXTRA_DENOISERS = (SURFACE_DENOISER, SINGLE_DENOISER)


@dataclass(frozen=True)
class Config:
    """One point of the evaluation: a method, its photons per frame and its denoiser (``DENOISERS``)."""

    method: str
    photons: int
    denoiser: str
    splat: str = "point"  #: cisp, sspm: "point" or "wavefront" (``photons`` then counts grid cells per light)
    wavefront_grid: str = "rsm"  #: wavefront splats: cells over the RSM's texels ("rsm") or the water mesh ("mesh")

    @property
    def denoise(self) -> bool:
        """Whether any filter runs on the photon map."""
        return self.denoiser != "none"

    @property
    def curve(self) -> str:
        """The method as a chart names it: ``cisp``, ``cisp wavefront`` or ``cisp wavefront mesh``."""
        if self.splat == "point":
            return self.method
        return f"{self.method} {self.splat}" + (" mesh" if self.wavefront_grid == "mesh" else "")

    @property
    def label(self) -> str:
        return f"{self.curve} {self.photons:,} {self.denoiser}"


def applicable(method: str, denoiser: str) -> bool:
    """``own`` (seed 004's filters) belongs to caustics_map alone, ``caustic-surface`` to cisp alone; every other
    denoiser (``caustic-single`` too) to every method."""
    if denoiser == SURFACE_DENOISER:
        return method == "cisp"
    if denoiser == SINGLE_DENOISER:
        return True
    return denoiser in DENOISERS and (denoiser != "own" or method == "caustics_map")


def render_settings(cfg: Config, rsm_size: int, base: PhotonSettings = PhotonSettings()) -> RenderSettings:
    """The renderer's settings for ``cfg`` (see the module table)."""
    if not applicable(cfg.method, cfg.denoiser):
        raise ValueError(f"denoiser {cfg.denoiser!r} does not apply to method {cfg.method!r}")
    photons = replace(base, photons=int(cfg.photons), splat=cfg.splat, wavefront_grid=cfg.wavefront_grid)
    denoiser, extra = cfg.denoiser, {}
    if cfg.denoiser in EXTRA_DENOISERS:  # the caustics denoiser without the flow (caustic-single: play_case resets it)
        if cfg.denoiser == SURFACE_DENOISER and cfg.splat != "point":
            raise ValueError(f"denoiser {SURFACE_DENOISER!r} needs point splats")
        denoiser, extra = "caustic", {"caustic": CausticSettings(caustic_flow=False)}
    if cfg.method == "caustics_map":
        own = denoiser == "own"
        photons = replace(photons, cmap_gather="light" if own else "eye", cmap_history=4 if own else 1)
        denoiser = "none" if own else denoiser
    return RenderSettings(rsm_size=rsm_size, method=cfg.method, photons=photons, denoiser=denoiser, **extra)


def host_aovs(r: Renderer, keys=MEASURED_AOVS) -> dict[str, np.ndarray]:
    """Host copies of the AOVs named ``keys`` (a device-to-host copy: outside any timed stage). Copies
    indeed: on the CPU a Warp array's ``numpy()`` is a view of memory the next frame overwrites."""
    a = r.aovs(include_rsm=False)
    return {k: np.array(a[k], copy=True) for k in keys if k in a}


@dataclass
class Timing:
    """Stage times [ms] of the timed frames: per-stage medians and the median of whole frames."""

    stages: dict[str, float]
    frame: float  #: median over the timed frames of the sum of that frame's stages
    frames: int


def timing_of(timer: StageTimer) -> Timing:
    medians = timer.medians()  # flushes CUDA events
    per_frame = np.sum([timer.samples[k] for k in medians], axis=0)
    return Timing(medians, float(np.median(per_frame)), len(per_frame))


def run_frames(r: Renderer, warmup: int, timed: int, measured: int,
               before_frame: Callable[[int], None] | None = None) -> tuple[Timing, list[dict]]:
    """Render ``warmup`` untimed frames, then ``timed`` frames through a :class:`StageTimer` (CUDA events on
    a GPU, synchronised wall clock on the CPU); the last ``measured`` of them are copied to the host after
    their stages are timed. ``before_frame(i)`` runs before frame i (moves the scene; untimed)."""
    timer = StageTimer(r.device)
    out = []
    for i in range(warmup + timed):
        if before_frame is not None:
            before_frame(i)
        r.render_frame(timer if i >= warmup else None)
        if i >= warmup + timed - measured:
            out.append(host_aovs(r))
    return timing_of(timer), out


def scene_digest(scene: Scene, extra: str = "") -> str:
    """A short hash of everything a render of ``scene`` depends on (geometry, materials, lights, camera)."""
    h = hashlib.blake2b(digest_size=10)
    for a in (scene.points, scene.normals, scene.indices, scene.triangle_material,
              np.asarray(scene.camera.to_world, np.float64)):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(repr((scene.materials, scene.lights, scene.camera.fov_y, scene.camera.ortho_height,
                   scene.camera.orthographic, scene.camera.width, scene.camera.height, extra)).encode())
    return h.hexdigest()


def reference_settings(rsm_size: int, photons_per_pass: int, total: int, seed: int = 0) -> RenderSettings:
    return RenderSettings(rsm_size=rsm_size, method="reference", denoiser="none",
                          photons=PhotonSettings(photons=photons_per_pass, reference_photons=total, seed=seed))


def advance(r: Renderer, scene: Scene) -> None:
    """Take ``scene`` (same topology, lights of the same kinds) as the next frame: moved points and camera
    (:meth:`Renderer.update_scene`), and lights that moved (:meth:`LightMaps.set_light`)."""
    r.update_scene(scene)
    for lm, light in zip(r.lights, scene.lights):
        if light != lm.light:
            lm.set_light(light)
    r.scene.lights = list(scene.lights)


def cached_reference(cache_dir: str | None, name: str, scenes: list[Scene], settings: RenderSettings, device,
                     prepare: Callable[[Renderer], None] | None = None, key_extra: str = "",
                     progress: Callable[[int, int], None] | None = None) -> tuple[list[dict], dict]:
    """The reference's AOVs (``REFERENCE_AOVS``) for consecutive frames ``scenes`` (motion vectors between
    them): read from ``cache_dir`` when a file of the same scenes, settings and Warp version is there, else
    rendered and written there. ``prepare(renderer)`` runs before the first frame (e.g. sets the water's
    time code). Returns (one dict of AOVs per frame, meta)."""
    ps = settings.photons
    key = hashlib.blake2b("|".join([scene_digest(s) for s in scenes] + [
        key_extra, str(settings.rsm_size), repr(ps), wp.config.version, REFERENCE_REVISION]).encode(),
        digest_size=10).hexdigest()
    path = os.path.join(cache_dir, f"reference_{name}_{key}.npz") if cache_dir else None
    if path and os.path.exists(path):
        with np.load(path) as f:
            meta = json.loads(str(f["meta"]))
            frames = [{k: f[f"{i}_{k}"] for k in REFERENCE_AOVS} for i in range(meta["frames"])]
        meta["cached"] = True
        return frames, meta
    r = Renderer(scenes[0], settings, device=device)
    if prepare is not None:
        prepare(r)
    frames, seconds = [], 0.0
    for i, scene in enumerate(scenes):
        if i > 0:
            advance(r, scene)
        if progress is not None:
            r.photons.progress = lambda k, n, i=i: progress(i * n + k, len(scenes) * n)
        t0 = time.perf_counter()
        r.render_frame()
        wp.synchronize_device(r.device)
        seconds += time.perf_counter() - t0
        frames.append(host_aovs(r, REFERENCE_AOVS))
    meta = {"name": name, "key": key, "frames": len(frames), "photons": int(r.photons.target),
            "passes": int(r.photons.passes), "seconds": seconds, "device": device_name(r.device),
            "width": r.gbuffer.width, "height": r.gbuffer.height, "cached": False}
    if path:
        os.makedirs(cache_dir, exist_ok=True)
        tmp = path + ".tmp.npz"
        np.savez_compressed(tmp, meta=json.dumps(meta), **{f"{i}_{k}": v for i, a in enumerate(frames)
                                                           for k, v in a.items()})
        os.replace(tmp, path)
    return frames, meta


def accumulated_reference(cache_dir: str | None, name: str, scene: Scene, settings: RenderSettings, device,
                          noise: float = 0.02, seconds: float = 60.0, max_chunks: int = 256,
                          prepare: Callable[[Renderer], None] | None = None, key_extra: str = "",
                          progress: Callable[[int, int], None] | None = None) -> tuple[dict, dict]:
    """The reference of a still ``scene``, accumulated in chunks until its own relative noise over its caustic
    mask (:func:`cisp_warp.metrics.reference_noise`) is at most ``noise``.

    A chunk is one reference frame of ``settings`` (its ``reference_photons`` per light, in passes of
    ``photons``); chunk k renders frame k, so every chunk draws new random numbers. The estimate is the mean
    of the chunks' photon maps and final images, its standard error sqrt(Σ_k se_k²) / K. The running sums
    (and those of the even and odd chunks apart, whose two half estimates give FLIP's noise floor) are kept in
    ``cache_dir``: a later call with the same scene, settings and Warp version goes on from there. This call
    renders until the target is met, ``max_chunks`` are done, or ``seconds`` of rendering have passed (0:
    use the cache as it is, rendering only when there is none). Returns (AOVs ``REFERENCE_AOVS`` plus
    ``final_halves`` (2, H, W, 3) when there are two chunks or more, meta)."""
    from . import metrics as M

    ps = settings.photons
    key = hashlib.blake2b("|".join([scene_digest(scene), key_extra, str(settings.rsm_size), repr(ps),
                                    wp.config.version, "chunks", REFERENCE_REVISION]).encode(),
                      digest_size=10).hexdigest()
    path = os.path.join(cache_dir, f"reference_{name}_{key}.npz") if cache_dir else None
    sums, meta = None, {}
    if path and os.path.exists(path):
        with np.load(path) as f:
            meta = json.loads(str(f["meta"]))
            sums = {k: f[k] for k in f.files if k != "meta"}

    def estimate():
        k = int(sums["chunks"])
        est = {key_: sums[key_] for key_ in REFERENCE_AOVS if key_ not in ("photon_map", "caustics", "final",
                                                                           "caustics_stderr")}
        est["photon_map"] = (sums["photon_map"] / k).astype(np.float32)
        est["caustics"] = est["photon_map"]
        est["final"] = ((sums["final_even"] + sums["final_odd"]) / k).astype(np.float32)
        est["caustics_stderr"] = (np.sqrt(sums["stderr_sq"]) / k).astype(np.float32)
        if k >= 2:
            even, odd = (k + 1) // 2, k // 2
            est["final_halves"] = np.stack([sums["final_even"] / even, sums["final_odd"] / odd]).astype(np.float32)
        return est

    def own_noise(est):
        return M.reference_noise(est, M.caustic_mask(est))

    done = int(sums["chunks"]) if sums is not None else 0
    current = own_noise(estimate()) if done else math.inf
    if done == 0 or (seconds > 0 and current > noise and done < max_chunks):
        r = Renderer(scene, settings, device=device)
        if prepare is not None:
            prepare(r)
        t0 = time.perf_counter()
        while done == 0 or (current > noise and done < max_chunks and time.perf_counter() - t0 < seconds):
            r.frame = done  # chunk k: frame k, fresh random numbers
            if progress is not None:
                r.photons.progress = lambda i, n, k=done: progress(k * n + i, max(k + 1, 1) * n)
            r.render_frame()
            a = host_aovs(r, REFERENCE_AOVS)
            if sums is None:
                sums = {k: v for k, v in a.items() if k not in ("photon_map", "caustics", "final", "caustics_stderr")}
                sums.update(photon_map=np.zeros(a["photon_map"].shape), stderr_sq=np.zeros(a["photon_map"].shape),
                            final_even=np.zeros(a["final"].shape), final_odd=np.zeros(a["final"].shape))
            sums["photon_map"] = sums["photon_map"] + a["photon_map"]
            sums["stderr_sq"] = sums["stderr_sq"] + a["caustics_stderr"].astype(np.float64) ** 2
            half = "final_even" if done % 2 == 0 else "final_odd"
            sums[half] = sums[half] + a["final"]
            done += 1
            sums["chunks"] = np.array(done)
            current = own_noise(estimate())
        wp.synchronize_device(r.device)
        meta = {"name": name, "key": key, "chunks": done, "photons_per_chunk": int(r.photons.target),
                "photons": int(r.photons.target) * done, "passes": int(r.photons.passes) * done,
                "seconds": meta.get("seconds", 0.0) + time.perf_counter() - t0, "device": device_name(r.device),
                "width": r.gbuffer.width, "height": r.gbuffer.height}
        if path:
            os.makedirs(cache_dir, exist_ok=True)
            tmp = path + ".tmp.npz"
            np.savez_compressed(tmp, meta=json.dumps(meta), **sums)
            os.replace(tmp, path)
        meta["cached"] = False
    else:
        meta["cached"] = True
    meta["reference_noise"] = current
    meta["noise_target"] = noise
    return estimate(), meta


def source_version() -> str:
    """``git describe --always --dirty`` of the checkout the figures come from ("unknown" outside git)."""
    import subprocess

    try:
        return subprocess.run(["git", "describe", "--always", "--dirty"], cwd=os.path.dirname(os.path.abspath(__file__)),
                              capture_output=True, text=True, timeout=10).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def device_name(device) -> str:
    """``alias (name)`` of a Warp device, e.g. ``cuda:0 (NVIDIA H100 80GB HBM3)``; the CPU's model too."""
    d = wp.get_device(device)
    name = d.name
    if d.is_cpu:
        try:
            with open("/proc/cpuinfo") as f:
                for line in f:
                    if line.startswith("model name"):
                        name = line.split(":", 1)[1].strip()
                        break
        except OSError:
            pass
        name = f"{name}, {len(os.sched_getaffinity(0))} cores"
    return f"{d.alias} ({name})"


# ---- stability cases -------------------------------------------------------------------------------------


@dataclass
class CaseFigures:
    """The stability figures of one case and method (see :mod:`cisp_warp.metrics` for the definitions)."""

    case: str
    method: str
    photons: int
    denoiser: str
    energy_lost: float  #: 1 − power(caustics) / power(reference) over the case's region, mean over frames
    error: float  #: relative RMSE of the caustics over the reference's caustic mask ∩ region, mean over frames
    flicker: float  #: of the denoised caustics, mean over consecutive frame pairs
    flicker_raw: float  #: of the photon map before the renderer's denoiser (same pairs)
    reference_flicker: float  #: of the reference's photon map over its frames: its noise plus the true change
    reference_noise: float  #: the reference's relative standard error over the mask
    ledger: dict  #: last frame's ledger, each entry as a share of the sampled power
    closure: float  #: last frame's ledger closure (0 when every photon's power is booked once)
    finite: bool  #: every measured AOV free of NaN and Inf


def case_frames(case, frames: int, measured: int) -> list[int]:
    """The frames that get a reference: the last ``measured`` when the case is animated; the last two (an
    independent pair, for the reference's own flicker) when only the random numbers change."""
    return list(range(frames - (measured if case.animated else 2), frames))


def case_reference(case, width: int, height: int, frames: int, measured: int, settings: RenderSettings,
                   device, cache_dir: str | None = None, progress=None) -> tuple[list[dict], dict]:
    scenes = [case.scene_at(f, width, height) for f in case_frames(case, frames, measured)]
    return cached_reference(cache_dir, f"case_{case.name}", scenes, settings, device, progress=progress)


def play_case(case, settings: RenderSettings, width: int, height: int, frames: int, measured: int,
              device, reset_history: bool = False) -> tuple[Renderer, list[dict]]:
    """Render ``frames`` frames of ``case`` with ``settings``; host AOVs of the last ``measured``.
    ``reset_history``: the denoiser forgets its history before every frame (``SINGLE_DENOISER``)."""
    r = Renderer(case.scene_at(0, width, height), settings, device=device)
    out = []
    for f in range(frames):
        if f > 0 and case.animated:
            advance(r, case.scene_at(f, width, height))
        if reset_history and r.denoiser is not None:
            r.denoiser.reset()
        r.render_frame()
        if f >= frames - measured:
            out.append(host_aovs(r))
    return r, out


def default_denoiser(method: str) -> str:
    """What "denoised" means for a method when no denoiser is named: the renderer's default (``caustic``)."""
    return "caustic"


def measure_case(case, method: str, reference: list[dict], width: int, height: int, frames: int, measured: int,
                 rsm_size: int, photons: int, device, base: PhotonSettings = PhotonSettings(),
                 denoiser: str | None = None, splat: str = "point", wavefront_grid: str = "rsm") -> CaseFigures:
    """Play ``case`` with ``method`` and ``denoiser`` (:func:`render_settings`; None: the default; ``splat`` and
    ``wavefront_grid`` for cisp and sspm) and measure it against ``reference`` (:func:`case_reference` of the same
    frames)."""
    from . import metrics as M

    denoiser = denoiser or default_denoiser(method)
    settings = render_settings(Config(method, photons, denoiser, splat, wavefront_grid), rsm_size, base)
    r, shots = play_case(case, settings, width, height, frames, measured, device,
                         reset_history=denoiser == SINGLE_DENOISER)
    ref_frames = case_frames(case, frames, measured)
    ref_at = dict(zip(ref_frames, reference))
    first = frames - measured
    last_ref = reference[-1]
    views, masks, errors, lost = {}, {}, [], []
    for i, a in enumerate(shots):
        f = first + i
        views[f] = camera_view(case.scene_at(f, width, height).camera) if case.animated else r.view
        ref = ref_at.get(f, last_ref)  # static cases: the last reference is every frame's
        region = case.region(ref) if case.region is not None else np.ones(ref["depth"].shape, bool)
        masks[f] = M.caustic_mask(ref) & region
        if f in ref_at:
            fp = M.pixel_footprint(ref, views[f])
            errors.append(M.relative_rmse(a["caustics"], ref["photon_map"], masks[f]))
            lost.append(1.0 - M.energy_ratio(a["caustics"], ref["photon_map"], fp, region))
    flick, flick_raw = [], []
    for i in range(1, len(shots)):
        f = first + i
        fp = M.pixel_footprint(shots[i], views[f])
        flick.append(M.flicker(shots[i - 1], shots[i], fp, masks[f], "caustics"))
        flick_raw.append(M.flicker(shots[i - 1], shots[i], fp, masks[f], "photon_map"))
    ref_flick = [M.flicker(reference[i - 1], reference[i], M.pixel_footprint(reference[i], views[ref_frames[i]]),
                           masks[ref_frames[i]], "photon_map") for i in range(1, len(reference))]
    ledger = r.photons.read_ledger()
    whole = ledger.as_dict()["sampled"]
    return CaseFigures(
        case.name, method, int(photons), denoiser, _nanmean(lost), _nanmean(errors), _nanmean(flick), _nanmean(flick_raw),
        _nanmean(ref_flick), M.reference_noise(last_ref, masks[frames - 1]),
        {k: (v / whole if whole > 0 else 0.0) for k, v in ledger.as_dict().items()}, float(ledger.closure()),
        all(np.isfinite(v).all() for a in shots for v in a.values() if v.dtype.kind == "f"))


def _nanmean(values) -> float:
    v = np.asarray([x for x in values if np.isfinite(x)], dtype=np.float64)
    return float(v.mean()) if v.size else float("nan")
