"""Render a range of time codes: numbered PNGs, an MP4, per-frame timings and memory, all streamed.

``render_sequence(renderer, animation, codes, out_dir)`` drives an :class:`~cisp_warp.animation.Animation`
through ``codes``; the renderer's temporal state (SVGF history, previous camera and points) carries from
one frame to the next. Per frame only the outputs leave the device: ``final`` (and with ``aovs=True`` the
raw and denoised caustic irradiance) as host copies. The image is tone mapped with one exposure for the
whole sequence (the automatic exposure of the first frame unless one is given), so the video does not
flicker, written as ``final.####.png`` (#### = the time code) and appended to ``final.mp4`` (H.264 through
imageio-ffmpeg; without it a warning says so and the PNGs are still written).
"""

from __future__ import annotations

import os
import statistics
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from .animation import Animation, memory_in_use
from .errors import SceneError
from .render import box_filter
from .image_io import atomic_path, auto_exposure, tonemap, write_layers


class VideoWriter:
    """H.264 MP4 through imageio-ffmpeg, fed one 8-bit RGB frame at a time (nothing is buffered).

    ``error`` is None while it works; when imageio-ffmpeg or its ffmpeg is missing or ffmpeg fails, it
    holds the reason, ``append`` does nothing more and a :class:`RuntimeWarning` has said why.
    """

    def __init__(self, path: str, fps: float):
        self.path = path
        self.fps = float(fps)
        self.error: str | None = None
        self._writer = None
        self.frames = 0

    def _fail(self, reason: str) -> None:
        self.error = reason
        self._writer = None
        warnings.warn(f"no video written to '{self.path}': {reason}; the PNG frames are written", RuntimeWarning,
                      stacklevel=3)

    def append(self, rgb: np.ndarray) -> None:
        """Add an (H, W, 3) uint8 frame; odd sizes are padded by one edge row or column (H.264 4:2:0)."""
        if self.error is not None:
            return
        h, w = rgb.shape[:2]
        rgb = np.pad(rgb, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        try:
            if self._writer is None:
                import imageio_ffmpeg

                self._writer = imageio_ffmpeg.write_frames(
                    self.path, (rgb.shape[1], rgb.shape[0]), fps=self.fps, codec="libx264", quality=8,
                    macro_block_size=1, ffmpeg_log_level="error")
                self._writer.send(None)  # start ffmpeg
            self._writer.send(np.ascontiguousarray(rgb))
            self.frames += 1
        except ImportError:
            self._fail("imageio-ffmpeg is not installed (python3 -m pip install imageio-ffmpeg)")
        except (OSError, RuntimeError, StopIteration) as exc:
            self._fail(f"ffmpeg failed ({exc})")

    def close(self) -> None:
        if self._writer is not None:
            try:
                self._writer.close()
            except (OSError, RuntimeError) as exc:
                self._fail(f"ffmpeg failed when finishing the file ({exc})")
            self._writer = None


def render_history_frame(renderer) -> None:
    """A frame rendered for its temporal state only (a chunk's warm-up, not written): what the next frames'
    histories read, nothing else.

    The same steps as :meth:`~cisp_warp.render.Renderer.render_frame` up to the denoiser's history (camera and
    light views, the photons of frame ``renderer.frame``, the temporal stage), leaving out what no later frame
    reads: direct light, sky, shading, composite, and the à-trous levels past the one SVGF feeds back (all of
    them for the caustics denoiser, whose history is the raw photon map's). After it the renderer's history,
    frame number and previous camera are bit for bit those a full frame leaves (``tests/test_distributed.py``);
    ``caustic_irradiance`` and the images are not this frame's.
    """
    from dataclasses import replace

    from .denoise import SVGF, CausticDenoiser

    g = renderer.gbuffer
    g.render(renderer.raster, renderer.view_params, renderer.prev_view_params)
    renderer.fitter.fit(renderer.raster, renderer.view_params, renderer.frame)
    for lm in renderer.lights:
        lm.render(renderer.raster)
    photons, denoiser = renderer.photons, renderer.denoiser
    if photons is not None:
        photons.trace(g, renderer.view_params, renderer.frame)
        if photons.denoise and isinstance(denoiser, (CausticDenoiser, SVGF)):
            full = denoiser.settings
            keep = full.feedback_level + 1 if isinstance(denoiser, SVGF) else 0  # levels the history reads
            denoiser.settings = replace(full, atrous_levels=min(keep, full.atrous_levels))
            try:
                frame_in = (photons.photon_map, g.depth, g.normal, g.motion, g.tri_id, renderer.caustic_irradiance)
                if isinstance(denoiser, CausticDenoiser):
                    denoiser.denoise(*frame_in, photons.photon_m2)
                else:
                    denoiser.denoise(*frame_in)
            finally:
                denoiser.settings = full
    renderer.prev_view_params = renderer.view_params
    renderer.frame += 1


@dataclass
class SequenceStats:
    """What a sequence cost: seconds per frame (render + outputs) and memory [MiB] after each frame."""

    codes: list[int] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)
    memory: list[dict[str, float]] = field(default_factory=list)
    video: str | None = None
    interrupted: bool = False  #: stopped by Ctrl-C: the frames before are written, the video closed

    @property
    def median_seconds(self) -> float:
        return statistics.median(self.seconds) if self.seconds else 0.0

    def summary(self) -> str:
        """One line: frames, median s/frame, and each memory figure at the first and last frame."""
        if not self.seconds:
            return "no frames"
        first, last = self.memory[0], self.memory[-1]
        mem = ", ".join(f"{k} {first[k]:.1f} -> {last[k]:.1f} MiB" for k in first if k in last)
        return (f"{len(self.seconds)} frames, median {self.median_seconds:.3f} s/frame; "
                f"memory at frame {self.codes[0]} -> {self.codes[-1]}: {mem}")


def render_sequence(renderer, animation: Animation, codes, out_dir: str, exposure: float | None = None,
                    aovs: bool = False, video: bool = True, on_frame=None, progress=None) -> SequenceStats:
    """Render time codes ``codes`` into ``out_dir`` (see the module docstring).

    ``exposure``: tone-mapping scale (linear), None = automatic from the first frame; ``aovs``: also write
    ``final``, ``caustics`` and ``photon_map`` per frame as layers of ``aovs.####.exr``; ``on_frame(code)``
    is called after each frame is written; ``progress``: wraps the iterable of codes (e.g. tqdm).
    Ctrl-C (KeyboardInterrupt) stops after the files of the frame in flight are either complete or absent
    (each is written under a temporary name and renamed), closes the MP4 (playable up to the last frame
    written) and returns with ``interrupted`` set.
    """
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as exc:
        raise SceneError(f"cannot create output directory: {exc.strerror}", file=out_dir) from None
    g = renderer.gbuffer
    shape = (g.height, g.width, 3)
    ss = renderer.settings.supersample
    stats = SequenceStats()
    writer = VideoWriter(os.path.join(out_dir, "final.mp4"), animation.clock.time_codes_per_second) if video else None
    from PIL import Image

    codes = list(codes)
    try:
        for code in (progress(codes) if progress else codes):
            t0 = time.perf_counter()
            animation.set_time_code(code)
            renderer.render_frame()
            final = renderer.final_image()  # the one host copy a frame needs
            if exposure is None:
                exposure = auto_exposure(final)
            ldr = tonemap(final, exposure)
            png = os.path.join(out_dir, f"final.{code:04d}.png")
            Image.fromarray(ldr).save(atomic_path(png), format="PNG")
            os.replace(atomic_path(png), png)
            if writer is not None:
                writer.append(ldr)
            if aovs:
                keep = {"final": final}
                if renderer.photons is not None:
                    full = {"caustics": renderer.caustic_irradiance, "photon_map": renderer.photons.photon_map}
                    keep.update({k: box_filter(v.numpy().reshape(shape), ss) for k, v in full.items()})
                write_layers(os.path.join(out_dir, f"aovs.{code:04d}.exr"), keep)
            wp.synchronize_device(renderer.device)
            stats.seconds.append(time.perf_counter() - t0)
            stats.codes.append(int(code))
            stats.memory.append(memory_in_use(renderer.device))
            if on_frame is not None:
                on_frame(code)
    except KeyboardInterrupt:
        stats.interrupted = True
        for name in os.listdir(out_dir):  # a file interrupted while being written is never left behind
            if name.startswith(".") and name.endswith(".partial"):
                os.remove(os.path.join(out_dir, name))
    finally:
        if writer is not None:
            writer.close()
    if writer is not None and writer.error is None and writer.frames:
        stats.video = writer.path
    return stats


__all__ = ["SequenceStats", "VideoWriter", "render_history_frame", "render_sequence"]
