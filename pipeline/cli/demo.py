"""``jnr demo``: the README's main job on built-in input (:func:`pipeline.demo.run_demo`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.cli.common import EXIT_OK, load_fit_photo_config, progress_bars_wanted


def cmd_demo(args: argparse.Namespace) -> int:
    """Build the rig from code and export/edit it; reconstruct the astronaut portrait and a synthetic photo
    with known truth (the README's main job)."""
    from tqdm import tqdm

    from pipeline.demo import run_demo

    out = Path(args.out)
    config = load_fit_photo_config(args)
    bars = []  # made once the output is accepted

    def progress(step: str, done: int, total: int) -> None:
        if not bars:
            bars.append(
                tqdm(total=total, desc="jnr demo", unit="step", disable=args.quiet or not progress_bars_wanted())
            )
        bars[0].update(done - bars[0].n)

    try:
        summary = run_demo(
            out, config=config, seed=args.seed, spread=args.spread, spp=args.spp, force=args.force, progress=progress
        )
    finally:
        for bar in bars:
            bar.close()
    _print_summary(out, summary)
    return EXIT_OK


def _print_summary(out: Path, summary: dict) -> None:
    astronaut, synthetic = summary["astronaut"], summary["synthetic"]
    print(f"jnr demo: wrote {out}/ in {summary['seconds']:.0f} s")
    for name in sorted(p.name for p in out.iterdir()):
        print(f"  {name}{'/' if (out / name).is_dir() else ''}")
    print(
        f"template rebuilt from code: largest difference to the committed asset "
        f"{summary['rebuild_max_difference_mm']:.2g} mm"
    )
    print(
        f"edited head (seed {summary['seed']}): {summary['edited_parameters']} parameters, largest vertex move "
        f"{summary['edit_max_displacement_mm']:.1f} mm; picture: {out / 'edited.png'}"
    )
    print(
        f"astronaut portrait (scikit-image): landmark error {astronaut['mean_error_px']:.2f} px, NME "
        f"{astronaut['nme']:.4f}, {astronaut['fit_seconds']:.1f} s; see {out / 'astronaut' / 'overlay.png'}"
    )
    print(
        f"synthetic photo of {synthetic['head']} (known truth): face scan-to-mesh median "
        f"{synthetic['s2m_median_mm']:.2f} mm, mean {synthetic['s2m_mean_mm']:.2f} mm; true vertex error "
        f"{synthetic['vertex_mean_mm']:.2f} mm (template {synthetic['template_vertex_mean_mm']:.2f} mm); "
        f"landmark error {synthetic['mean_error_px']:.2f} px, {synthetic['fit_seconds']:.1f} s; "
        f"see {out / 'synthetic' / 'overlay.png'}"
    )


def add_commands(sub: argparse._SubParsersAction) -> None:
    """``jnr demo``."""
    demo = sub.add_parser(
        "demo",
        help="the README's main job on built-in input: the rig, and two photo fits",
        description="Rebuild the template from code and compare it with the committed asset, "
        "export it as OBJ/PLY/glTF, make a randomly edited head and a picture of both; "
        "then reconstruct the astronaut portrait that scikit-image ships and a "
        "synthetic photo of a held-out head with known truth (jnr fit), and print "
        "where the outputs are and the errors.",
    )
    demo.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    demo.add_argument("--force", action="store_true", help="replace the output folder if it exists")
    demo.add_argument("--seed", type=int, default=7, help="seed of the random edit (default: 7)")
    demo.add_argument(
        "--spread",
        type=float,
        default=0.3,
        help="random edit strength, a fraction of each parameter's range (default: 0.3)",
    )
    demo.add_argument("--spp", type=int, default=32, help="samples per pixel of the picture (default: 32)")
    demo.add_argument(
        "--landmarks-only", action="store_true", help="fit the photos with the landmark fit only (default)"
    )
    demo.add_argument("--photometric", action="store_true", help="add the photometric stages to the photo fits")
    demo.add_argument("--config", help="YAML overriding the photo-fitting settings (configs/fit_photo.yaml)")
    demo.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one photo-fitting setting")
    demo.add_argument("--quiet", action="store_true", help="no progress bar")
    demo.set_defaults(func=cmd_demo)
