"""Side-by-side crops of one still scene's final image under several denoisers (and the reference): what the
README shows of the caustics denoiser.

    python tools/denoiser_crop.py --device cuda:0                       # pool, 1920x1080, 2M photons, 16 frames
    python tools/denoiser_crop.py --device cuda:0 --reference-seconds 60 --refdir results_cuda/references
    python tools/denoiser_crop.py --device cpu --width 320 --height 180 --rsm 256 --photons 200k --out /tmp/crop.png

Every panel is the ``final`` image (radiance, tone mapped by ``image_io.tonemap``) of the last of ``--frames``
frames of a still scene (the denoisers' steady state, as ``tools/evaluate.py`` measures it), all with one exposure
(the reference's automatic exposure when there is a reference, else the first panel's), cropped to ``--crop``
(fractions of the image: x0,y0,x1,y1) and labelled. With ``--reference-seconds`` > 0 the converged reference (cached
and accumulated as ``tools/evaluate.py`` does, in ``--refdir``) is the last panel.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools"))
sys.path.insert(0, ROOT)


def parse_crop(text: str) -> tuple[float, float, float, float]:
    try:
        x0, y0, x1, y1 = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--crop takes four fractions x0,y0,x1,y1, got {text!r}") from None
    if not (0.0 <= x0 < x1 <= 1.0 and 0.0 <= y0 < y1 <= 1.0):
        raise argparse.ArgumentTypeError(f"--crop {text!r}: need 0 <= x0 < x1 <= 1 and 0 <= y0 < y1 <= 1")
    return x0, y0, x1, y1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="pool", help="cornell, pool or sinusoid (default pool)")
    ap.add_argument("--method", default="cisp", help="cisp, sspm, caustics_map (default cisp)")
    ap.add_argument("--denoisers", default="none,caustic,svgf", help="comma-separated panels, left to right")
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--rsm", type=int, default=2048, help="RSM size [texels]")
    ap.add_argument("--photons", default="2M", help="photons per light (default 2M)")
    ap.add_argument("--frames", type=int, default=16, help="frames rendered; the last is shown (default 16)")
    ap.add_argument("--crop", type=parse_crop, default=parse_crop("0.297,0.306,0.736,0.639"),
                    help="x0,y0,x1,y1 as fractions of the image (default: the pool's floor)")
    ap.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    ap.add_argument("--reference-seconds", type=float, default=0.0,
                    help="rendering time for the reference panel [s] (0: no reference panel)")
    ap.add_argument("--refdir", default=os.path.join("results", "references"), help="reference cache")
    ap.add_argument("--out", default=os.path.join("docs", "denoiser_crop.png"), help="PNG written")
    args = ap.parse_args(argv)
    if args.frames < 1:
        ap.error("--frames must be >= 1")

    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    from PIL import Image, ImageDraw
    from tqdm import tqdm

    import evaluate as EV
    from cisp_warp import evaluation as E
    from cisp_warp.cli import parse_count
    from cisp_warp.image_io import atomic_path, auto_exposure, tonemap
    from cisp_warp.render import Renderer

    device = wp.get_device(args.device)
    photons = parse_count(args.photons)
    specs = EV.scene_specs([args.scene])
    if not specs:
        raise SystemExit(f"the scene {args.scene!r} is not available")
    spec = specs[0]
    denoisers = args.denoisers.split(",")
    for d in denoisers:
        if d not in E.DENOISERS or not E.applicable(args.method, d):
            raise SystemExit(f"denoiser {d!r} does not apply to {args.method!r} (one of {', '.join(E.DENOISERS)})")
    w, h = args.width, args.height
    panels = []
    for d in tqdm(denoisers, desc=f"{spec.name} {args.method}", unit="denoiser"):
        r = Renderer(spec.make(w, h), E.render_settings(E.Config(args.method, photons, d, "point", "rsm"), args.rsm),
                     device=device)
        if spec.prepare is not None:
            spec.prepare(r)
        for _ in range(args.frames):
            r.render_frame()
        panels.append((d if d != "caustic" else "caustic (default)", np.array(r.final_image(), copy=True)))
    exposure = None
    if args.reference_seconds > 0:
        ref, meta = E.accumulated_reference(args.refdir, f"{spec.name}_{w}x{h}", spec.make(w, h),
                                            E.reference_settings(args.rsm, 4_000_000, 0), device,
                                            seconds=args.reference_seconds, prepare=spec.prepare, key_extra=spec.key)
        exposure = auto_exposure(ref["final"])
        panels.append((f"reference ({meta['photons']:.2g} photons)", ref["final"]))
    if exposure is None:
        exposure = auto_exposure(panels[0][1])
    x0, y0, x1, y1 = (int(round(f * n)) for f, n in zip(args.crop, (w, h, w, h)))
    label_h, gap = 22, 6
    crops = [tonemap(img[y0:y1, x0:x1], exposure) for _, img in panels]
    cw, ch = x1 - x0, y1 - y0
    sheet = Image.new("RGB", (len(crops) * cw + (len(crops) - 1) * gap, ch + label_h), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for k, ((name, _), crop) in enumerate(zip(panels, crops)):
        sheet.paste(Image.fromarray(crop), (k * (cw + gap), label_h))
        draw.text((k * (cw + gap) + 4, 4), name, fill=(0, 0, 0))
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    tmp = atomic_path(args.out)
    sheet.save(tmp, format="PNG")
    os.replace(tmp, args.out)
    print(f"wrote {args.out}: {spec.name}, {args.method}, {w}x{h}, RSM {args.rsm}², {photons:,} photons per light, "
          f"frame {args.frames}, crop x {x0}-{x1}, y {y0}-{y1}; panels: {', '.join(n for n, _ in panels)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
