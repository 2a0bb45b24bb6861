"""``cisp-render``: render a USD scene's caustics and AOVs to a folder."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import warnings

from .errors import SceneError, SceneWarning


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="cisp-render",
        description="Render a USD scene with screen-space caustics (Cascaded Image-Space Photon Tracing) on "
        "NVIDIA Warp. Writes final.png (tone mapped), final.exr (HDR radiance, W/(m2 sr)) and aovs.exr: one "
        "multi-channel EXR of the main AOVs (R,G,B beauty; caustics.*, direct.*, sky.* irradiance in W/m2; "
        "Z depth in m; N.X/Y/Z normal; id triangle id).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("scene", nargs="?", default=None, help="USD stage to render (.usda, .usdc, .usd)")
    p.add_argument("--demo", default=None, metavar="NAME",
                   help="render a scene that ships with cisp_warp instead: pool (the default demo) or cornell")
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    p.add_argument("--out", default="out", help="output folder (created if missing; checked before rendering)")
    p.add_argument("--device", default=None,
                   help="Warp device: cpu or cuda:0 (default: cuda:0 when a GPU is present, else cpu)")
    p.add_argument("--width", type=int, default=None, help="image width [pixels] (default: the stage's render settings, else 640)")
    p.add_argument("--height", type=int, default=None, help="image height [pixels] (default: the stage's render settings, else 360)")
    p.add_argument("--time", type=float, default=None, help="USD time code to render (default: the stage's start time code)")
    p.add_argument("--camera", default=None, help="prim path of the camera (default: the first camera found)")
    p.add_argument("--rsm-size", type=int, default=1024, help="edge of each reflective shadow map view [texels]")
    p.add_argument("--light-views", default="camera", choices=["camera", "scene"],
                   help="cisp, sspm: RSM views fitted to what the camera sees, as cascades (camera), "
                   "or one view over all the specular geometry (scene, for comparison)")
    p.add_argument("--light-cascades", type=int, default=2, help="with --light-views camera: fitted views per light view")
    p.add_argument("--method", default="cisp", choices=["cisp", "sspm", "caustics_map", "reference", "none"],
                   help="caustics method: cisp (Cascaded Image-Space Photon Tracing, Meenrattanakorn & Lambers), sspm "
                   "(world-space Screen-Space Photon Mapping, Kim 2019), caustics_map (light-space Caustics Mapping, "
                   "Wyman & Davis 2006), "
                   "reference (converged world-space photon tracing, no denoising: the ground truth), "
                   "or none (direct light only)")
    p.add_argument("--photons", type=parse_count, default=parse_count("1M"),
                   help="photons per light per frame; accepts 500k, 1M, 2M, or a plain integer")
    p.add_argument("--denoiser", default="caustic", choices=["caustic", "svgf", "gather", "none"],
                   help="photon-map denoiser: caustic (accumulates the raw photon map over frames, reacting where "
                   "the caustic changes, and filters the noise left), SVGF (the paper's), the 7x7 Gaussian gather "
                   "of Caustics Mapping, or none")
    p.add_argument("--no-caustic-flow", action="store_true",
                   help="caustic denoiser with cisp: follow only the surfaces' motion with the history, not the caustic's "
                   "own (by default cisp measures where the photons of the same light-space cell landed the frame "
                   "before, and the history follows a moving caustic along it)")
    p.add_argument("--hidden-rays", default="refracted", choices=["refracted", "both", "none"],
                   help="the composite's view rays that the screen-space march loses (behind a wall, off screen), "
                   "traced on the opaque layer's BVH and shaded with the caustic the photons left there: refracted "
                   "ones (default; reflected ones see the sky), both, or none (screen-space fallbacks only); cisp and sspm with "
                   "point photons, and --method none")
    p.add_argument("--seed", type=int, default=0, help="random seed; with the frame number it reproduces a frame exactly")
    p.add_argument("--footprint", default="exact", choices=["exact", "paper"],
                   help="pixel footprint for irradiance: exact, or the paper's eq. 3 approximation")
    p.add_argument("--roughness-cutoff", type=float, default=0.3, help="RSM texels rougher than this emit no photons")
    p.add_argument("--luminance-cutoff", type=float, default=0.01,
                   help="RSM texels dimmer than this fraction of the brightest emit no photons")
    p.add_argument("--splat", default="point", choices=["point", "wavefront"],
                   help="cisp, sspm: store photons as points, or as a wavefront: photons on a grid of the RSM "
                   "(--photons cells per light), each cell's power spread over the area its corners land on")
    p.add_argument("--wavefront-grid", default="rsm", choices=["rsm", "mesh"],
                   help="--splat wavefront: cells over the RSM's texels, or over the water mesh's own triangles "
                   "(cut n x n; no cell straddles a mesh edge or silhouette)")
    p.add_argument("--wavefront-refine", type=int, default=4,
                   help="--wavefront-grid mesh: cells whose corners diverge (silhouettes, shadow edges) are cut this "
                   "many times per edge and traced again (1: off, points at their corners)")
    p.add_argument("--max-bounces", type=int, default=8, help="sspm, reference: specular bounces before a photon is dropped")
    p.add_argument("--cmap-gather", default="light", choices=["light", "eye"],
                   help="caustics_map: Gaussian gather in the light-space caustic map, or leave it to the eye-space denoiser")
    p.add_argument("--cmap-history", type=int, default=4, help="caustics_map: frames averaged by Caustics Mapping's temporal filter")
    p.add_argument("--reference-photons", type=parse_count, default=None,
                   help="reference: photons per light to accumulate, in passes of --photons (default: 100M on CUDA, 4M on CPU)")
    p.add_argument("--frames", default=None, metavar="A:B",
                   help="render time codes A..B-1 as a sequence: final.####.png and final.mp4, the temporal filter "
                   "carried across frames")
    p.add_argument("--frame-aovs", action="store_true",
                   help="with --frames, also write final, caustics and photon_map of every frame as layers of aovs.####.exr")
    p.add_argument("--no-sim", action="store_true",
                   help="render the stage's own water points (baked time samples or the rest grid) instead of "
                   "simulating cisp:water meshes with sim/")
    p.add_argument("--stats", action="store_true", help="print the photon energy ledger of each frame")
    p.add_argument("--exposure", type=float, default=None, help="tone-mapping exposure in stops (default: automatic)")
    p.add_argument("--aovs", default=None, metavar="LIST",
                   help="more AOVs as layers of aovs.exr, comma separated (photon_map, position, albedo, roughness, "
                   "motion, water_depth, water_normal, ...), or 'all'")
    p.add_argument("--npy", action="store_true", help="also write every AOV of aovs.exr as NAME.npy (float32, int32)")
    p.add_argument("--rsm-aovs", action="store_true",
                   help="also write the light views' buffers (reflective shadow maps) as layers of rsm.exr")
    p.add_argument("--supersample", type=int, default=2,
                   help="anti-aliasing: N x N samples per pixel (1 = off)")
    p.add_argument("--no-rsm-aovs", action="store_true", help=argparse.SUPPRESS)  # the default now
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    d = p.add_argument_group("distributed rendering (with --frames; needs pip install -e '.[distributed]')")
    d.add_argument("--workers", type=int, default=None, metavar="N",
                   help="spread the frames over N Dask workers of a local cluster: one per GPU, else CPU processes")
    d.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="use the workers of a running Dask cluster (e.g. tcp://head:8786; with --workers N, N of "
                   "them); the stage and --out must be at the same paths there")
    d.add_argument("--resume", action="store_true", help="keep the frames already in --out, render the missing ones")
    d.add_argument("--warmup", type=int, default=None, metavar="N",
                   help="frames each chunk renders unwritten before its first frame; None: as many as the "
                   "denoiser's temporal filter needs")
    return p


def _version() -> str:
    from . import __version__

    return __version__


#: RenderSettings / PhotonSettings fields whose cisp-render flag is not --field-name
FLAGS = {"reference_photons": "--reference-photons", "supersample": "--supersample", "fit": "--light-views",
         "cascades": "--light-cascades"}


def flag_of(exc) -> str:
    """A SettingsError's message in the command line's words: the field becomes its flag."""
    flag = FLAGS.get(exc.field, "--" + exc.field.replace("_", "-"))
    return f"{flag} {exc.detail}"


def parse_count(text: str) -> int:
    """Photon counts with SI suffixes: '500k' -> 500000, '1M' -> 1000000; plain integers pass through."""
    t = str(text).strip().lower()
    mult = {"k": 1_000, "m": 1_000_000}.get(t[-1:], 1)
    try:
        value = float(t[:-1] if mult > 1 else t) * mult
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a photon count: {text!r} (use e.g. 500k, 1M or 2000000)") from None
    if not math.isfinite(value) or value < 1 or value != int(value):
        raise argparse.ArgumentTypeError(f"photon count must be a positive integer, got {text!r}")
    return int(value)


MAX_FRAMES = 100_000  #: --frames renders at most this many frames (over an hour at 24 per second)
MAX_TIME_CODE = 1e9  #: |time code| of --time and --frames
MAX_EXPOSURE_STOPS = 64.0  #: |--exposure|: 2^64 is far beyond any display range, and finite in float32
MAX_REFERENCE_PASSES = 1000  #: --reference-photons / --photons: passes of the reference per frame
MAX_COUNT_FLAGS = {"--max-bounces": 1024, "--cmap-history": 1024, "--reference-photons": 10**12}


def parse_frames(text: str) -> range:
    try:
        a, b = (int(v) for v in text.split(":"))
    except ValueError:
        raise SceneError(f"--frames must be A:B with integers A < B, got {text!r}") from None
    if b <= a:
        raise SceneError(f"--frames must be A:B with A < B, got {text!r}")
    if max(abs(a), abs(b)) > MAX_TIME_CODE or b - a > MAX_FRAMES:
        raise SceneError(f"--frames {text}: at most {MAX_FRAMES} frames, with time codes within "
                         f"±{MAX_TIME_CODE:g}")
    return range(a, b)


def check_numbers(args, device: str) -> None:
    """Range checks of the numeric flags that nothing downstream bounds (one SceneError naming the flag)."""
    import math

    if args.exposure is not None and not (math.isfinite(args.exposure) and abs(args.exposure) <= MAX_EXPOSURE_STOPS):
        raise SceneError(f"--exposure must be a finite number of stops in [-{MAX_EXPOSURE_STOPS:g}, "
                         f"{MAX_EXPOSURE_STOPS:g}], got {args.exposure}")
    if args.time is not None and not (math.isfinite(args.time) and abs(args.time) <= MAX_TIME_CODE):
        raise SceneError(f"--time must be a finite time code within ±{MAX_TIME_CODE:g}, got {args.time}")
    for flag, hi in MAX_COUNT_FLAGS.items():
        v = getattr(args, flag[2:].replace("-", "_"))
        if v is not None and v > hi:
            raise SceneError(f"{flag} must be at most {hi}, got {v}")
    reference = args.reference_photons or (10**8 if device.startswith("cuda") else 4 * 10**6)  # the defaults
    if args.method == "reference" and reference > MAX_REFERENCE_PASSES * args.photons:
        raise SceneError(f"--reference-photons {reference} in passes of --photons {args.photons} is more than "
                         f"{MAX_REFERENCE_PASSES} passes: raise --photons")
    for flag in ("--roughness-cutoff", "--luminance-cutoff"):
        v = getattr(args, flag[2:].replace("-", "_"))
        if not (math.isfinite(v) and 0.0 <= v <= 1.0):
            raise SceneError(f"{flag} must lie in [0, 1], got {v}")


def parse_aov_list(text: str | None) -> list[str]:
    if not text:
        return []
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise SceneError(f"--aovs must be a comma-separated list of AOV names or 'all', got {text!r}")
    return names


def write_outputs(out_dir: str, aovs: dict, extra: list[str], exposure, npy: bool = False, rsm: bool = False) -> list[str]:
    """final.png, final.exr and aovs.exr (the main AOVs plus ``extra``); .npy and rsm.exr when asked. Paths."""
    from .image_io import MAIN_AOVS, write_aovs, write_layers, write_png

    paths = [os.path.join(out_dir, n) for n in ("final.png", "final.exr", "aovs.exr")]
    write_png(paths[0], aovs["final"], exposure)
    write_layers(paths[1], {"final": aovs["final"]})  # R, G, B; float16 where it fits
    image = aovs["final"].shape[:2]  # light-space maps (caustics_map's cmap_rsm_*) are not camera images
    views = {k: v for k, v in aovs.items() if not k.startswith("rsm_") and v.shape[:2] == image}
    keep = [k for k in MAIN_AOVS if k in views] + [k for k in views if k not in MAIN_AOVS and ("all" in extra or k in extra)]
    layers = {k: views[k] for k in keep}
    write_layers(paths[2], layers)
    if npy:
        paths += write_aovs(out_dir, layers, exr=False, npy=True)
    if rsm:
        maps = {k: v for k, v in aovs.items() if k.startswith("rsm_") or v.shape[:2] != image}
        by_size = {}
        for k, v in maps.items():
            by_size.setdefault(v.shape[:2], {})[k] = v
        for i, group in enumerate(by_size.values()):
            p = os.path.join(out_dir, "rsm.exr" if i == 0 else f"rsm{i}.exr")
            write_layers(p, group)
            paths.append(p)
    return paths


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING  # no init banner or module-load lines
    from .image_io import check_out_dir
    from .photons import PhotonSettings
    from .denoise import CausticSettings
    from .raster import LightViewSettings
    from .render import Renderer, RenderSettings, SettingsError
    from .usd import load_usd

    def say(msg):
        if not args.quiet:
            print(msg, file=sys.stderr)

    try:
        if (args.scene is None) == (args.demo is None):
            raise SceneError("give a USD file to render or --demo NAME (pool or cornell), not both"
                             if args.scene else "give a USD file to render, or --demo pool for the shipped pool")
        from .api import demo, pick_device

        scene_path = demo(args.demo) if args.demo else args.scene
        if not os.path.exists(scene_path):
            raise SceneError("not found: no such USD file", file=scene_path)
        check_out_dir(args.out)
        try:
            device = pick_device(args.device)
        except SceneError as e:
            raise SceneError(f"--device: {e}") from None
        try:
            photons = PhotonSettings(photons=args.photons, seed=args.seed, footprint=args.footprint,
                                     roughness_cutoff=args.roughness_cutoff, luminance_cutoff=args.luminance_cutoff,
                                     max_bounces=args.max_bounces, cmap_gather=args.cmap_gather,
                                     cmap_history=args.cmap_history, reference_photons=args.reference_photons or 0,
                                     splat=args.splat, wavefront_grid=args.wavefront_grid,
                                     wavefront_refine=args.wavefront_refine)
            settings = RenderSettings(width=args.width, height=args.height, rsm_size=args.rsm_size,
                                      method=args.method, photons=photons, denoiser=args.denoiser,
                                      supersample=args.supersample, hidden_rays=args.hidden_rays,
                                      caustic=CausticSettings(caustic_flow=not args.no_caustic_flow),
                                      light_views=LightViewSettings(fit=args.light_views, cascades=args.light_cascades))
        except SettingsError as e:
            raise SceneError(flag_of(e)) from None
        check_numbers(args, device)
        extra = parse_aov_list(args.aovs)
        frames = parse_frames(args.frames) if args.frames else None
        if args.workers is not None or args.scheduler or args.resume:
            from .distributed import main_distributed

            return main_distributed(args, settings, frames, say, scene_path)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", SceneWarning)
            first = frames.start if frames else args.time
            scene = load_usd(scene_path, time_code=first, width=args.width, height=args.height,
                             camera_path=args.camera, device=device)
        for w in caught:
            say(f"warning: {w.message}")
        exposure = None if args.exposure is None else 2.0 ** args.exposure
        t0 = time.perf_counter()
        renderer = Renderer(scene, settings, device=device)
        from .animation import Animation

        animation = Animation(renderer, scene_path, camera_path=args.camera, simulate=not args.no_sim)
        if getattr(renderer.photons, "passes", 1) > 4 and not args.quiet:
            from tqdm import tqdm

            bar = tqdm(total=renderer.photons.passes, desc="reference passes", unit="pass", leave=False)
            renderer.photons.progress = lambda done, total: bar.update(1)
        if frames is None:
            animation.set_time_code(scene.time_code)
            renderer.render_frame()
            aovs = renderer.aovs(include_rsm=args.rsm_aovs)
            dt = time.perf_counter() - t0
            unknown = [n for n in extra if n != "all" and n not in aovs]
            if unknown:
                raise SceneError(f"--aovs: no AOV named {', '.join(unknown)} (this render has: "
                                 f"{', '.join(sorted(k for k in aovs if not k.startswith('rsm_')))})")
            written = write_outputs(args.out, aovs, extra, exposure, npy=args.npy, rsm=args.rsm_aovs)
            if args.stats and renderer.photons is not None:
                print(renderer.photons.read_ledger().table())
            say(f"rendered {scene_path} at {renderer.width}x{renderer.height} on {device} in {dt:.2f} s; "
                f"wrote {', '.join(os.path.basename(w) for w in written)} to {args.out}")
        else:
            from functools import partial

            from tqdm import tqdm

            from .sequence import render_sequence

            def ledger(code):
                if args.stats and renderer.photons is not None:
                    print(f"frame {code}:\n{renderer.photons.read_ledger().table()}")

            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", RuntimeWarning)
                warnings.simplefilter("ignore", SceneWarning)
                stats = render_sequence(renderer, animation, frames, args.out, exposure, aovs=args.frame_aovs,
                                        on_frame=ledger, progress=partial(tqdm, desc="frames", unit="frame",
                                                                          disable=args.quiet))
            for w in caught:
                say(f"warning: {w.message}")
            if stats.interrupted:
                say(f"cisp-render: interrupted after {len(stats.codes)} of {len(frames)} frames; kept "
                    f"final.####.png of those{' and a closed final.mp4' if stats.video else ''} in {args.out}")
                return 130
            say(f"rendered {scene_path} time codes {frames.start}..{frames.stop - 1} on {device} in "
                f"{time.perf_counter() - t0:.2f} s to {args.out} (final.####.png"
                f"{', final.mp4' if stats.video else ''}): {stats.summary()}")
    except KeyboardInterrupt:
        print(f"cisp-render: interrupted; files already written to {args.out} are complete and kept",
              file=sys.stderr)
        return 130
    except SceneError as e:
        print(f"cisp-render: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
