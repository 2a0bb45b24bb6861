"""``cisp-render``: render a USD scene's caustics and AOVs to a folder."""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

from .errors import SceneError, SceneWarning


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="cisp-render",
        description="Render a USD scene with screen-space caustics (Cascaded Image-Space Photon Tracing) on "
        "NVIDIA Warp. Writes final.png plus every AOV as NAME.exr and NAME.npy (float32, SI units).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("scene", help="USD stage to render (.usda, .usdc, .usd)")
    p.add_argument("--out", default="out", help="output folder (created if missing)")
    p.add_argument("--device", default=None,
                   help="Warp device: cpu or cuda:0 (default: cuda:0 when a GPU is present, else cpu)")
    p.add_argument("--width", type=int, default=None, help="image width [pixels] (default: the stage's render settings, else 640)")
    p.add_argument("--height", type=int, default=None, help="image height [pixels] (default: the stage's render settings, else 360)")
    p.add_argument("--time", type=float, default=None, help="USD time code to render (default: the stage's start time code)")
    p.add_argument("--camera", default=None, help="prim path of the camera (default: the first camera found)")
    p.add_argument("--rsm-size", type=int, default=1024, help="edge of each reflective shadow map view [texels]")
    p.add_argument("--exposure", type=float, default=None, help="tone-mapping exposure in stops (default: automatic)")
    p.add_argument("--no-rsm-aovs", action="store_true", help="do not write the rsm_<light>_* AOVs")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    from .image_io import write_aovs, write_png
    from .render import Renderer, RenderSettings
    from .usd_import import load_usd

    def say(msg):
        if not args.quiet:
            print(msg, file=sys.stderr)

    try:
        wp.init()
        device = args.device or ("cuda:0" if wp.is_cuda_available() else "cpu")
        try:
            wp.get_device(device)
        except (RuntimeError, ValueError) as e:
            raise SceneError(f"unknown --device '{device}': {e}. Use cpu or cuda:N") from e
        settings = RenderSettings(width=args.width, height=args.height, rsm_size=args.rsm_size)
        settings.validate()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", SceneWarning)
            scene = load_usd(args.scene, time_code=args.time, width=args.width, height=args.height, camera_path=args.camera, device=device)
        for w in caught:
            say(f"warning: {w.message}")
        t0 = time.perf_counter()
        renderer = Renderer(scene, settings, device=device)
        renderer.render_frame()
        aovs = renderer.aovs(include_rsm=not args.no_rsm_aovs)
        dt = time.perf_counter() - t0
        written = write_aovs(args.out, aovs)
        exposure = None if args.exposure is None else 2.0 ** args.exposure
        write_png(os.path.join(args.out, "final.png"), aovs["final"], exposure)
        cam = renderer.scene.camera
        say(f"rendered {args.scene} at {cam.width}x{cam.height} on {device} in {dt:.2f} s; "
            f"wrote final.png and {len(written)} AOV files to {args.out}")
    except SceneError as e:
        print(f"cisp-render: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
