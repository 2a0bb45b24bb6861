"""One call from a USD stage to images: :func:`render`, and the shipped scenes: :func:`demo`.

>>> import cisp_warp
>>> aovs = cisp_warp.render(cisp_warp.demo("pool"), device="cpu", width=64, height=36, photons=20_000,
...                         rsm_size=128, time=24)
>>> aovs["final"].shape, aovs["final"].dtype.name        # HDR radiance [W/(m² sr)]
((36, 64, 3), 'float32')
>>> float(aovs["caustics"].max()) > 0.0                  # caustic irradiance [W/m²] under the waves
True

``render`` simulates ``cisp:water`` meshes with ``sim/`` at t = time code / timeCodesPerSecond, reads the
camera of that time code from the stage, exactly as ``cisp-render`` does (through
:class:`~cisp_warp.animation.Animation`), and returns the AOVs of :meth:`Renderer.aovs` as numpy arrays:
one dict for one frame, or, with ``frames``, an iterator of dicts whose temporal filter history carries
from frame to frame.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from .errors import SceneError

#: name -> file of the scenes that ship with the package
DEMOS = {"pool": "pool.usda", "cornell": "cornell_flooded.usda"}

#: keyword of :func:`render` -> where it goes in the settings (for messages in the caller's words)
_KEYWORDS = {("RenderSettings", "width"): "width", ("RenderSettings", "height"): "height",
             ("RenderSettings", "method"): "method", ("RenderSettings", "denoiser"): "denoiser",
             ("RenderSettings", "rsm_size"): "rsm_size", ("RenderSettings", "supersample"): "supersample",
             ("PhotonSettings", "photons"): "photons", ("PhotonSettings", "seed"): "seed"}


def scenes_dir() -> Path:
    """Folder of the shipped scenes: ``cisp_warp/scenes`` in an installed package, else the checkout's
    ``scenes_usd/`` (an editable install or ``PYTHONPATH``)."""
    here = Path(__file__).resolve().parent
    for d in (here / "scenes", here.parent / "scenes_usd"):
        if (d / DEMOS["pool"]).is_file():
            return d
    raise SceneError("the shipped scenes are missing from this installation (cisp_warp/scenes); reinstall cisp-warp")


def demo(name: str = "pool") -> str:
    """Path of a scene that ships with cisp_warp: ``"pool"`` (an outdoor pool with simulated water, a sky, a
    sun and a floodlight, and a moving camera) or ``"cornell"`` (a Cornell box flooded with IOR 2.4 water)."""
    if name not in DEMOS:
        raise SceneError(f"there is no demo scene {name!r}; choose one of: {', '.join(DEMOS)}")
    return str(scenes_dir() / DEMOS[name])


def pick_device(device=None) -> str:
    """The Warp device to use: ``device`` checked, else ``cuda:0`` when a GPU is present, else ``cpu``."""
    import warp as wp

    wp.init()
    name = str(device) if device is not None else ("cuda:0" if wp.is_cuda_available() else "cpu")
    try:
        wp.get_device(name)
    except (RuntimeError, ValueError):
        found = ", ".join(d.alias for d in wp.get_devices())
        raise SceneError(f"there is no device {name!r} here (devices: {found}); use 'cpu' or 'cuda:N'") from None
    return name


def stage_path(stage_or_path) -> tuple[str, str | None]:
    """(file to open, temporary file to delete afterwards or None) for a path or an open ``Usd.Stage``."""
    if isinstance(stage_or_path, (str, os.PathLike)):
        return os.fspath(stage_or_path), None
    try:
        from pxr import Usd
    except ImportError:  # pragma: no cover - usd-core is a dependency
        Usd = None
    if Usd is not None and isinstance(stage_or_path, Usd.Stage):
        layer = stage_or_path.GetRootLayer()
        if not layer.anonymous and layer.realPath and not layer.dirty:
            return layer.realPath, None
        fd, tmp = tempfile.mkstemp(suffix=".usdc", prefix="cisp_stage_")
        os.close(fd)
        stage_or_path.Export(tmp)
        return tmp, tmp
    raise SceneError(f"render() needs a USD file path or a pxr Usd.Stage, got {type(stage_or_path).__name__}")


def _frames(frames) -> list[float]:
    if isinstance(frames, str):
        try:
            a, b = (int(v) for v in frames.split(":"))
        except ValueError:
            raise SceneError(f"frames must be 'A:B' with integers A < B, a range or a list of time codes, got {frames!r}") from None
        frames = range(a, b)
    if isinstance(frames, (int, float, np.number)):
        raise SceneError(f"frames must be a range or a list of time codes (use time= for one frame), got {frames!r}")
    try:
        codes = [float(c) for c in frames]
    except (TypeError, ValueError):
        raise SceneError(f"frames must be a range or a list of time codes, got {frames!r}") from None
    if not codes or not all(np.isfinite(codes)):
        raise SceneError(f"frames must hold at least one finite time code, got {frames!r}")
    return codes


def render(stage_or_path, *, time=None, frames=None, method: str = "cisp", photons=1_000_000, device=None,
           width: int | None = None, height: int | None = None, camera: str | None = None, seed: int = 0,
           denoiser: str = "caustic", supersample: int = 2, rsm_size: int = 1024, simulate: bool = True,
           settings=None, include_rsm: bool = False):
    """Render a USD stage: one frame's AOVs as a dict of numpy arrays, or with ``frames`` an iterator of them.

    ``stage_or_path``: a .usda/.usdc/.usd path (e.g. :func:`demo`) or an open ``pxr.Usd.Stage``.
    ``time``: the time code of a single frame (default: the stage's start time code). ``frames``: time
    codes of a sequence (a range, a list, or ``"A:B"`` for A..B-1); the iterator renders lazily, one frame
    per step, carrying the temporal filter's history across frames. ``method``: ``"cisp"``, ``"sspm"``,
    ``"caustics_map"``, ``"reference"`` or ``"none"``; ``photons``: per light per frame (an int, or a
    :class:`PhotonSettings`); ``device``: ``"cpu"``, ``"cuda:0"`` ... (default: the GPU when there is one);
    ``width``/``height``: the image size (default: the stage's render settings); ``camera``: a camera prim
    path; ``supersample``: s × s samples per pixel (anti-aliasing; 1 = off); ``simulate``: False renders
    the stage's own water points instead of simulating ``cisp:water`` meshes; ``settings``: a full
    :class:`RenderSettings` (then method, photons, seed, denoiser, supersample, rsm_size and the size are
    taken from it). Every AOV is (height, width[, C]) float32 (int32 ids) in SI units: ``final``
    [W/(m² sr)], ``caustics``, ``photon_map``, ``direct_irradiance``, ``sky_irradiance`` [W/m²],
    ``depth`` [m], ``normal`` ...; ``include_rsm`` adds the light views' buffers.

    Bad arguments raise :class:`SceneError` with one sentence naming the argument.
    """
    if time is not None and frames is not None:
        raise SceneError("give either time= (one frame) or frames= (a sequence), not both")
    from .photons import PhotonSettings
    from .render import RenderSettings, SettingsError

    if settings is None:
        try:
            ps = photons if isinstance(photons, PhotonSettings) else PhotonSettings(photons=photons, seed=seed)
            settings = RenderSettings(width=width, height=height, method=method, photons=ps, denoiser=denoiser,
                                      supersample=supersample, rsm_size=rsm_size)
        except SettingsError as exc:
            word = _KEYWORDS.get((exc.owner, exc.field))
            raise SceneError(f"render(): {word} {exc.detail}" if word else f"render(): {exc}") from None
    elif not isinstance(settings, RenderSettings):
        raise SceneError(f"settings must be a RenderSettings, got {type(settings).__name__}")
    if time is not None and not (isinstance(time, (int, float, np.number)) and np.isfinite(time)):
        raise SceneError(f"time must be a finite time code, got {time!r}")
    codes = _frames(frames) if frames is not None else None
    dev = pick_device(device)
    path, tmp = stage_path(stage_or_path)
    if not os.path.exists(path):
        raise SceneError("not found: no such USD file", file=path)
    try:
        renderer, animation, first = _build(path, settings, dev, time if codes is None else codes[0], camera, simulate)
    except BaseException:
        if tmp:
            os.unlink(tmp)
        raise
    if codes is None:
        try:
            animation.set_time_code(first)
            renderer.render_frame()
            return renderer.aovs(include_rsm=include_rsm)
        finally:
            if tmp:
                os.unlink(tmp)
    return _sequence(renderer, animation, codes, include_rsm, tmp)


def _build(path, settings, device, first, camera, simulate):
    import warp as wp

    from .animation import Animation
    from .render import Renderer
    from .usd import load_usd

    wp.config.log_level = wp.LOG_WARNING
    scene = load_usd(path, time_code=first, width=settings.width, height=settings.height, camera_path=camera,
                     device=device)
    renderer = Renderer(scene, settings, device=device)
    animation = Animation(renderer, path, camera_path=camera, simulate=simulate)
    return renderer, animation, scene.time_code


def _sequence(renderer, animation, codes: Iterable[float], include_rsm: bool, tmp) -> Iterator[dict]:
    try:
        for code in codes:
            animation.set_time_code(code)
            renderer.render_frame()
            yield renderer.aovs(include_rsm=include_rsm)
    finally:
        if tmp:
            os.unlink(tmp)


__all__ = ["DEMOS", "demo", "pick_device", "render", "scenes_dir"]
