"""Distributed shots (cisp_warp.distributed): chunks on Dask workers equal one process, faults, resume.

Tiny pool (32x18, RSM 32², 1000 photons per light) on the CPU, where a seed and a frame index reproduce a
frame bit for bit. The Dask tests share one local cluster of 2 single-threaded worker processes and skip when
Dask.distributed is not installed (``pip install -e .[distributed]``).
"""

import importlib.util
import os
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cisp_warp.distributed import Chunk, ShotJob, frame_name, plan_chunks, render_chunk, render_shot, warmup_frames
from cisp_warp.animation import Animation
from cisp_warp.denoise import SVGFSettings
from cisp_warp.errors import SceneError
from cisp_warp.image_io import read_layers
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.sequence import render_sequence
from cisp_warp.usd import load_usd

ROOT = Path(__file__).resolve().parents[1]
POOL = str(ROOT / "scenes_usd" / "pool.usda")
TINY = RenderSettings(width=32, height=18, rsm_size=32, photons=PhotonSettings(photons=1000, seed=3),
                      denoiser="svgf")  # SVGF: a 25-frame warm-up (the default denoiser's is 415 frames)
GATHER = RenderSettings(width=32, height=18, rsm_size=32, photons=PhotonSettings(photons=1000, seed=3),
                        denoiser="gather", supersample=2)  # 2x2 samples: the writers' box filter is checked too
EXPOSURE = 2.0e-3  # tone-mapping scale for the in-process comparisons: near the pool's automatic one (the
# sun-lit deck ~100 W/(m2 sr) at mid grey), so the PNGs span the 8-bit range and a seam would show in them

# Seam tolerance after a chunk's default warm-up (25 frames at SVGF's alpha = 0.2), see warmup_frames(): the
# HDR `final` within one 8-bit step (1/255) of the frame's peak radiance, the PNGs within one code value. Measured
# for the chunk below: 1.6e-3 of the peak after 25 frames, 7e-3 after 8. Without a warm-up its first frames are
# off by ~13% of the peak (checked too, so the tolerance is one a wrong warm-up breaks).
SEAM_HDR = 1.0 / 255.0
SEAM_PNG = 1


def png(folder, code):
    return np.asarray(Image.open(os.path.join(folder, frame_name(code))), dtype=np.int16)


def final_hdr(folder, code):
    """`final` of a frame from aovs.####.exr (float16 there: both runs' frames are rounded alike, 5e-4 at most)."""
    layers = read_layers(os.path.join(folder, f"aovs.{code:04d}.exr"))
    return np.stack([layers[k].astype(np.float32) for k in "RGB"], axis=-1)


def single_process(out, codes, settings=TINY, exposure=EXPOSURE, aovs=False):
    renderer = Renderer(load_usd(POOL, time_code=codes.start, device="cpu"), settings, device="cpu")
    render_sequence(renderer, Animation(renderer, POOL), codes, str(out), exposure, aovs=aovs, video=False)


def job_for(out, codes, settings=TINY, warmup=None, **kw):
    return ShotJob(scene=POOL, out=str(out), settings=settings, shot_start=codes.start, shot_stop=codes.stop,
                   warmup=warmup_frames(settings) if warmup is None else warmup, device="cpu", exposure=EXPOSURE, **kw)


# ---------------------------------------------------------------------------------------------- plan


def test_warmup_follows_the_temporal_filters():
    assert warmup_frames(TINY) == 25  # SVGF's EMA: 0.8^25 < 1/255
    assert warmup_frames(RenderSettings(denoiser="svgf", svgf=SVGFSettings(alpha_color=0.5, alpha_moments=0.5))) == 8  # 0.5^8 < 1/255 < 0.5^7
    assert warmup_frames(RenderSettings(denoiser="svgf", svgf=SVGFSettings(alpha_color=1.0, alpha_moments=1.0))) == 0
    assert warmup_frames(RenderSettings()) == 63 + 352  # caustic: running mean to 64 frames, then (63/64)^352 < 1/255
    assert warmup_frames(RenderSettings(denoiser="gather")) == 0
    assert warmup_frames(RenderSettings(method="reference")) == 0
    light = PhotonSettings(cmap_history=5, cmap_gather="light")
    assert warmup_frames(RenderSettings(method="caustics_map", photons=light)) == 4  # filtered in light space only
    eye = PhotonSettings(cmap_history=5, cmap_gather="eye")
    assert warmup_frames(RenderSettings(method="caustics_map", photons=eye, denoiser="svgf")) == 25


@pytest.mark.parametrize("todo, workers, warmup", [(range(0, 240), 2, 32), (range(10, 1210), 7, 32),
                                                   (range(0, 5), 4, 32), (range(0, 100), 3, 0)])
def test_plan_covers_every_frame_once_and_balances_warmup(todo, workers, warmup):
    chunks = plan_chunks(todo, todo.start, workers, warmup)
    codes = [c for ch in chunks for c in range(ch.start, ch.stop)]
    assert codes == list(todo)  # contiguous, in order, every frame once
    assert len(chunks) <= workers
    cost = [len(ch) + min(warmup, ch.start - todo.start) for ch in chunks]
    assert max(cost) - min(cost) <= max(2, len(todo) // 100), cost  # balanced, warm-up counted
    if len(chunks) > 1 and warmup and len(todo) > 100:
        assert len(chunks[0]) > len(chunks[1])  # the first chunk has no warm-up to pay


def test_plan_for_a_resume_renders_through_short_gaps_only():
    todo = [3, 4, 50, 51, 52, 200]
    chunks = plan_chunks(todo, 0, 2, 8)
    covered = {c for ch in chunks for c in range(ch.start, ch.stop)}
    assert set(todo) <= covered and len(covered) < 20  # long gaps are not rendered
    assert plan_chunks([5, 6, 9], 0, 1, 8) == [Chunk(5, 10)]  # a gap of 2 < warm-up: rendered through


# ---------------------------------------------------------------------------------------------- seams, in process


def test_chunk_after_warmup_matches_single_process_within_the_seam_tolerance(tmp_path):
    codes = range(0, 44)
    single_process(tmp_path / "one", codes, aovs=True)
    errors = {}
    for warmup in (0, 25):  # chunk 36..43 starts 36 frames into the shot: a real (partial-history) warm-up
        out = tmp_path / f"w{warmup}"
        out.mkdir()
        report = render_chunk(job_for(out, codes, warmup=warmup, frame_aovs=True), Chunk(36, 44))
        assert report["written"] == list(range(36, 44)) and report["warmup"] == warmup
        hdr = max(np.abs(final_hdr(out, c) - final_hdr(tmp_path / "one", c)).max() / final_hdr(tmp_path / "one", c).max()
                  for c in range(36, 44))
        ldr = max(np.abs(png(out, c) - png(tmp_path / "one", c)).max() for c in range(36, 44))
        errors[warmup] = (hdr, ldr)
    assert errors[25][0] <= SEAM_HDR and errors[25][1] <= SEAM_PNG, errors
    assert errors[0][0] > 10 * SEAM_HDR and errors[0][1] > 10 * SEAM_PNG, errors  # no warm-up: the seam shows


def test_caustics_map_history_is_rebuilt_exactly(tmp_path):
    settings = RenderSettings(width=32, height=18, rsm_size=32, method="caustics_map",
                              photons=PhotonSettings(photons=1000, seed=3, cmap_history=4))
    codes = range(0, 12)
    single_process(tmp_path / "one", codes, settings)
    report = render_chunk(job_for(tmp_path, codes, settings), Chunk(8, 12))
    assert report["warmup"] == 3
    for c in range(8, 12):
        assert np.array_equal(png(tmp_path, c), png(tmp_path / "one", c)), c


# ---------------------------------------------------------------------------------------------- on Dask workers

HAVE_DASK = importlib.util.find_spec("distributed") is not None
needs_dask = pytest.mark.skipif(not HAVE_DASK, reason="Dask.distributed is not installed: pip install -e .[distributed]")


@pytest.fixture(scope="module")
def client():
    import distributed

    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                       silence_logs=40)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def shot(client, tmp_path_factory):
    """One 10-frame shot on the 2 workers and the same shot in one process, denoised by the Gaussian gather:
    no history, so no warm-up (the SVGF seam is measured above), 2 chunks, and frames that must be identical."""
    root = tmp_path_factory.mktemp("shot")
    codes = range(0, 10)
    stats = render_shot(POOL, codes, str(root / "multi"), GATHER, device="cpu", client=client)
    single_process(root / "one", codes, GATHER, exposure=None)  # automatic exposure of frame 0, like the shot's
    return root, codes, stats


@needs_dask
def test_two_workers_equal_one_process_and_video_has_every_frame_once(shot):
    root, codes, stats = shot
    assert len(stats.chunks) == 2 and len({r["pid"] for r in stats.chunks}) == 2  # both workers rendered
    assert sorted(c for r in stats.chunks for c in r["written"]) == list(codes)
    assert stats.warmup == 0  # the gather keeps no history
    for c in codes:
        assert np.array_equal(png(root / "multi", c), png(root / "one", c)), c
    import imageio_ffmpeg

    video = [np.frombuffer(f, np.uint8).reshape(18, 32, 3).astype(np.int16)
             for f in list(imageio_ffmpeg.read_frames(str(root / "multi" / "final.mp4")))[1:]]
    assert len(video) == len(codes)
    frames = [png(root / "multi", c) for c in codes]
    for i, v in enumerate(video):  # every frame once, in time-code order: each decoded frame is nearest its own PNG
        assert int(np.argmin([np.abs(v - f).mean() for f in frames])) == i


@needs_dask
def test_resume_renders_only_missing_frames(shot, client, tmp_path):
    root, codes, _ = shot
    out = tmp_path / "resume"
    shutil.copytree(root / "multi", out)
    for c in (3, 7):
        os.remove(out / frame_name(c))
    address = client.scheduler.address  # as `--scheduler ADDRESS`: the workers of a running cluster
    stats = render_shot(POOL, codes, str(out), GATHER, device="cpu", resume=True, video=False, scheduler=address)
    assert sorted(c for r in stats.chunks for c in r["written"]) == [3, 7]
    for c in codes:
        assert np.array_equal(png(out, c), png(root / "multi", c)), c  # same exposure (shot.json), same pixels
    again = render_shot(POOL, codes, str(out), GATHER, device="cpu", resume=True, video=False, client=client)
    assert again.frames == 0 and again.rendered == 0
    other = replace(GATHER, photons=PhotonSettings(photons=1000, seed=4))
    with pytest.raises(SceneError, match="resume"):
        render_shot(POOL, codes, str(out), other, device="cpu", resume=True, video=False, client=client)


@needs_dask
def test_killed_worker_chunk_is_redone_without_rewriting_frames(client, tmp_path):
    codes = range(0, 12)
    marker = tmp_path / "killed"
    stats = render_shot(POOL, codes, str(tmp_path / "out"), TINY, device="cpu", warmup=2, video=False,
                        client=client, fault=(9, str(marker)))
    assert marker.exists()  # a worker process died (SIGKILL) at time code 9
    chunk = next(r for r in stats.chunks if r["chunk"][0] <= 9 < r["chunk"][1])
    # the re-run chunk wrote only what the dead worker had not: frames from 9 on, after a 2-frame warm-up
    assert chunk["written"] == list(range(9, chunk["chunk"][1])) and chunk["warmup"] == 2
    assert all(os.path.exists(tmp_path / "out" / frame_name(c)) for c in codes)
    assert not [p for p in os.listdir(tmp_path / "out") if p.endswith(".tmp")]


def test_workers_without_dask_say_so_in_one_sentence(monkeypatch, capsys, tmp_path):
    from cisp_warp import cli

    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    assert cli.main([POOL, "--frames", "0:4", "--workers", "2", "--out", str(tmp_path), "--device", "cpu"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "pip install" in err and "distributed" in err
    assert not os.listdir(tmp_path)


@needs_dask
def test_bench_smoke(client):
    import subprocess

    run = subprocess.run([sys.executable, str(ROOT / "tools" / "bench_distributed.py"), "--smoke",
                          "--scheduler", client.scheduler.address], capture_output=True,
                         text=True, timeout=120, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert run.returncode == 0, run.stderr[-2000:]
    rows = [line.split("|") for line in run.stdout.splitlines() if "|" in line and line.split("|")[0].strip() in "12"]
    assert [r[0].strip() for r in rows] == ["1", "2"]
    assert int(rows[1][9]) > 0  # the second worker's chunk warmed up (not from the shot's start)
    assert int(rows[1][-2]) <= SEAM_PNG  # its frames within the seam tolerance of the 1-worker (single-chunk) run


@needs_dask
@pytest.mark.skipif(importlib.util.find_spec("dask_cuda") is not None, reason="dask-cuda pins GPUs itself")
def test_gpu_workers_are_pinned_one_per_visible_gpu(monkeypatch):
    import distributed

    from cisp_warp.distributed.client import local_cluster

    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "3,5")  # this process may use GPUs 3 and 5: one worker each
    cluster = local_cluster(distributed, 2, gpus=2)  # the cluster alone: its workers need no GPU for this
    try:
        with distributed.Client(cluster) as c:
            c.wait_for_workers(2, timeout=60)
            seen = c.run(lambda: os.environ.get("CUDA_VISIBLE_DEVICES"))
    finally:
        cluster.close()
    assert sorted(seen.values()) == ["3", "5"]
    with pytest.raises(SceneError, match="more GPU workers"):
        local_cluster(distributed, 3, gpus=2)


@needs_dask
def test_a_workers_scene_error_reaches_the_client_as_one_sentence(client, tmp_path):
    with pytest.raises(SceneError, match="/NoSuchCamera") as info:
        render_shot(POOL, range(0, 4), str(tmp_path), GATHER, device="cpu", camera="/NoSuchCamera", client=client)
    assert "\n" not in str(info.value)
    assert not [p for p in os.listdir(tmp_path) if p.startswith("final.")]
