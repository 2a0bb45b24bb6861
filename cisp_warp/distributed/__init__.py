"""Long shots on many devices: contiguous chunks of a frame range rendered by Dask.distributed workers.

>>> stats = render_shot("scenes_usd/pool.usda", range(0, 1200), "shot", RenderSettings(width=1920, height=1080),
...                     workers=2)                    # a LocalCluster, one worker per GPU (or per CPU process)
>>> stats = render_shot(..., scheduler="tcp://head:8786")  # the workers of a running cluster

Plan (client side, :func:`render_shot`): the frames still to write are cut into one contiguous chunk per worker
(:func:`plan_chunks`, balanced by cost: a chunk's warm-up frames count against it at their measured cost); one
exposure for the whole shot is rendered once (the shot's first frame with a fresh history, exactly as
:func:`cisp_warp.sequence.render_sequence` picks it) or taken from ``--exposure`` or an earlier run's ``shot.json``;
then every chunk is a Dask task (:func:`render_chunk`), and the MP4 is assembled once, from the PNGs in time-code
order, fed while the chunks render (:class:`~.client.VideoAssembler`).

A chunk, on its worker: the renderer and animation of the shot are built once per worker process and kept
(:func:`worker_renderer`); the temporal state is restarted (:func:`restart_history`) and the chunk renders
``warmup`` frames before its first frame to write (not written), so that its denoiser history matches a
single-process run's (see :func:`warmup_frames` for how many, and what is left). A frame's random streams
come from the seed and its index in the shot (time code − shot start), so every frame, warm-up or not, gets
the photons it gets in one process. Frames go to ``final.####.png`` (#### = the time code: chunks never
collide), filtered down and tone mapped on the device (:mod:`.ldr`), copied to pinned host memory without the
render loop waiting, and PNG-encoded by a per-worker thread pool (:class:`FrameWriter`) while the device renders the
next frame, written to a temporary name and renamed, so a frame on disk is always complete. A frame that is not
written (a warm-up) renders only what the history reads (:func:`cisp_warp.sequence.render_history_frame`).

Faults: a worker that dies (process killed, host lost) loses its task, and the scheduler runs the chunk
again on another worker (Dask's ``distributed.scheduler.allowed-failures``); the re-run skips the frames
already written in this run and warms up before its first missing one. ``resume=True`` renders only frames
missing from ``out``. Progress over all frames is one bar fed by the frames appearing in ``out``.

Modules: :mod:`.plan` (warm-up length, chunks), :mod:`.ldr` (the 8-bit frame on the device, pinned readback),
:mod:`.worker` (what runs on a worker: the job, the renderer kept per worker process, the chunk loop, the PNG writer
threads), :mod:`.client` (cluster, exposure, tasks, progress, manifest, video, the command line's call).
"""

from .client import ShotStats, main_distributed, render_shot
from .plan import Chunk, caustic_seam_factor, plan_chunks, warmup_frames
from .worker import FrameWriter, ShotJob, frame_name, render_chunk, restart_history

__all__ = ["Chunk", "FrameWriter", "caustic_seam_factor", "ShotJob", "ShotStats", "frame_name", "main_distributed", "plan_chunks",
           "render_chunk", "render_shot", "restart_history", "warmup_frames"]
