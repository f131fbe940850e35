"""``jnr eval capacity | scans | photos``: the evaluations (:mod:`pipeline.evaluation`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from pipeline.cli.common import (
    EXIT_OK,
    CliError,
    StageBars,
    check_output,
    load_fit_photo_config,
    load_fit_scan_config,
    write_output_file,
)
from rig.errors import InputError

CAPACITY_MODELS = ("jnr", "pca", "asm")
"""``jnr eval capacity --models`` choices (:data:`pipeline.evaluation.capacity.MODEL_GROUPS`)."""


def parse_models(text: str) -> tuple[str, ...]:
    """``--models jnr,pca`` -> ``("jnr", "pca")``; ``all`` -> every model; an unknown name is a usage error."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if names == ("all",):
        return CAPACITY_MODELS
    unknown = [n for n in names if n not in CAPACITY_MODELS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"expected a comma-separated subset of {','.join(CAPACITY_MODELS)} (or all), got {text!r}"
        )
    return names


def capacity_table(result: dict) -> str:
    """The capacity table of :func:`pipeline.evaluation.capacity.evaluate_capacity`'s result: one line per
    split and row (error in mm over heads, model size in floats, fitting seconds per head)."""
    from pipeline.evaluation.capacity import CAPACITY_ROWS

    lines = [
        f"{'split':8s} {'row':26s} {'mean mm':>8s} {'std mm':>7s} {'median':>7s} {'heads':>5s} "
        f"{'model floats':>12s} {'s/head':>9s}"
    ]
    for split, row in result["splits"].items():
        for name in (n for n in CAPACITY_ROWS if n in row):
            r = row[name]
            lines.append(
                f"{split:8s} {name:26s} {r['mean_mm']:8.3f} {r['std_mm']:7.3f} {r['median_mm']:7.3f} "
                f"{r['heads']:5d} {r['model_floats']:12,d} {r['seconds_per_head']:9.4g}"
            )
    return "\n".join(lines)


def cmd_eval_capacity(args: argparse.Namespace) -> int:
    from pipeline.evaluation.capacity import CapacitySettings, evaluate_capacity

    if args.out:
        check_output(Path(args.out), args.force)
    settings = CapacitySettings(
        joint_iterations=args.joint_iterations,
        z_iterations=args.z_iterations,
        cycles=args.cycles,
        seed=args.seed,
        asm_iterations=args.asm_iterations,
    )
    if args.oracle and "jnr" not in args.models:
        raise CliError("--oracle starts from the jnr rows' learned-linear fit; add jnr to --models")
    bars = StageBars(args.quiet)
    try:
        result = evaluate_capacity(
            tuple(args.splits),
            settings,
            neural_path=args.skinning,
            limit=args.limit,
            progress=bars,
            oracle=args.oracle,
            models=args.models,
        )
    finally:
        bars.close()
    text = json.dumps(result, indent=2)
    if args.out:
        write_output_file(Path(args.out), args.force, lambda tmp: tmp.write_text(text + "\n"))
    print(text if args.json else capacity_table(result))
    return EXIT_OK


def _run_evaluation(args: argparse.Namespace, label: str, evaluate) -> int:
    """Shared by the ``jnr eval`` commands over synthetic data: a progress bar over the photos or scans (each
    counted at its first record, whatever the head model or baseline), the Markdown table (or ``--json``), and
    ``--out``."""
    total = args.neutral + args.expressive
    bars = StageBars(args.quiet)
    done: set[tuple[str, str]] = set()

    def progress(record) -> None:
        if (record.name, record.kind) not in done:
            done.add((record.name, record.kind))
            bars(label, len(done), total)

    try:
        result = evaluate(progress)
    except InputError as exc:
        raise CliError(str(exc)) from None
    finally:
        bars.close()
    payload = {
        "summary": result.summary(),
        "records": [r.__dict__ for r in result.records],
        "settings": result.settings,
    }
    text = json.dumps(payload, indent=2, default=float)
    if args.out:
        write_output_file(Path(args.out), args.force, lambda tmp: tmp.write_text(text + "\n"))
    print(text if args.json else result.table_markdown())
    return EXIT_OK


def cmd_eval_scans(args: argparse.Namespace) -> int:
    """``jnr eval scans``: fit-scan vs trimesh's nricp_amberg on simulated scans of held-out heads."""
    from pipeline.evaluation.scans import evaluate_scans

    if args.out:
        check_output(Path(args.out), args.force)
    config = load_fit_scan_config(args, seed_is_fit_seed=False)
    return _run_evaluation(
        args,
        "simulated scans",
        lambda progress: evaluate_scans(
            args.neutral,
            args.expressive,
            seed=args.seed or 0,
            config=config,
            baseline=not args.no_baseline,
            progress=progress,
        ),
    )


def cmd_eval_photos(args: argparse.Namespace) -> int:
    """``jnr eval photos``: the photo fit on synthetic renders of held-out heads (NoW-style errors)."""
    from pipeline.evaluation.photos import evaluate_photos

    if args.out:
        check_output(Path(args.out), args.force)
    config = load_fit_photo_config(args)
    return _run_evaluation(
        args,
        "synthetic photos",
        lambda progress: evaluate_photos(
            args.neutral,
            args.expressive,
            first=args.first,
            seed=args.seed,
            config=config,
            landmarks="dlib" if args.detected else "noisy",
            progress=progress,
        ),
    )


def _add_outputs(parser: argparse.ArgumentParser) -> None:
    """``--json``, ``--out`` and ``--force`` of ``jnr eval scans`` / ``photos``."""
    parser.add_argument("--json", action="store_true", help="print JSON instead of the table")
    parser.add_argument("--out", help="also write the JSON here")
    parser.add_argument("--force", action="store_true", help="overwrite --out")


def add_commands(sub: argparse._SubParsersAction) -> None:
    """``jnr eval ...``."""
    ev = sub.add_parser("eval", help="evaluations")
    ev_sub = ev.add_subparsers(dest="eval_command", metavar="EVAL_COMMAND")
    ev_sub.required = True
    cap = ev_sub.add_parser(
        "capacity",
        help="known-correspondence error of the rig's skinning variants, a PCA model and ASM",
        description="Fit the rig (initial / learned linear / neural skinning), a PCA shape model "
        "(k = 10, 50, 84, trained on the 85 training heads) and the Adaptive "
        "Skinning Model's ablation rows to the synthetic test and held-out heads; "
        "point-to-point error in mm (mean, std, median over heads), model size in "
        "floats and fitting seconds per head.",
    )
    cap.add_argument("--json", action="store_true", help="print JSON")
    cap.add_argument(
        "--splits",
        nargs="+",
        default=["test", "heldout"],
        choices=["train", "val", "test", "heldout", "makehuman"],
        help="population splits (ICT identities; makehuman: the out-of-distribution MakeHuman heads)",
    )
    cap.add_argument("--limit", type=int, help="only the first N heads of each split")
    cap.add_argument("--skinning", help="learned-skinning artifact (default: the packaged one)")
    cap.add_argument("--joint-iterations", type=int, default=400)
    cap.add_argument("--z-iterations", type=int, default=300)
    cap.add_argument("--cycles", type=int, default=2)
    cap.add_argument("--asm-iterations", type=int, help="iterations of each ASM fit (default: fit_asm's own)")
    cap.add_argument(
        "--models",
        type=parse_models,
        default=CAPACITY_MODELS,
        metavar="M[,M...]",
        help="models to evaluate, a comma-separated subset of jnr,pca,asm (default: all)",
    )
    cap.add_argument("--seed", type=int, default=0, help="population seed (default: 0)")
    cap.add_argument(
        "--oracle",
        action="store_true",
        help="also report per-head optimal weights (the bound for any skinning model with this pattern)",
    )
    cap.add_argument("--out", help="also write the JSON here")
    cap.add_argument("--force", action="store_true", help="overwrite --out")
    cap.add_argument("--quiet", action="store_true", help="no progress bars")
    cap.set_defaults(func=cmd_eval_capacity)
    _add_scans(ev_sub)
    _add_photos(ev_sub)


def _add_scans(ev_sub: argparse._SubParsersAction) -> None:
    sc = ev_sub.add_parser(
        "scans",
        help="fit-scan vs trimesh's nricp_amberg on simulated depth scans",
        description="Simulate one Kinect-like depth scan of each of the first N held-out "
        "heads (neutral and expressive), fit it with jnr fit-scan and with "
        "trimesh.registration.nricp_amberg from the same rigid pre-alignment, and "
        "report scan-to-mesh distance, true vertex error (known correspondence) "
        "and seconds (JNR Tables 2-3 style).",
    )
    sc.add_argument("--neutral", type=int, default=5, help="neutral scans (default: 5)")
    sc.add_argument("--expressive", type=int, default=5, help="expressive scans (default: 5)")
    sc.add_argument("--seed", type=int, help="seed of the scans (default: 0)")
    sc.add_argument("--no-baseline", action="store_true", help="skip nricp_amberg")
    sc.add_argument("--config", help="YAML overriding the fitting settings")
    sc.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one fitting setting")
    _add_outputs(sc)
    sc.add_argument("--quiet", action="store_true", help="no progress bar")
    sc.set_defaults(func=cmd_eval_scans)


def _add_photos(ev_sub: argparse._SubParsersAction) -> None:
    ph = ev_sub.add_parser(
        "photos",
        help="jnr fit on synthetic renders of held-out heads (NoW-style errors)",
        description="Render held-out synthetic heads (neutral and expressive; yaw within +-30 "
        "deg; path-traced with a point light and an environment, unlike the "
        "fitting renderer), give the fit the projected true landmarks + 1 px noise, "
        "align the result to the truth (similarity on the inner landmarks, then "
        "ICP) and report face-region scan-to-mesh distances and the true vertex "
        "error (mm) for the full fit, its landmark-only stage and the template.",
    )
    ph.add_argument("--neutral", type=int, default=5, help="neutral photos (default: 5)")
    ph.add_argument("--expressive", type=int, default=5, help="expressive photos (default: 5)")
    ph.add_argument(
        "--first", type=int, default=20, help="first held-out head (default: 20; the defaults were chosen on heads 0-5)"
    )
    ph.add_argument("--seed", type=int, default=0, help="seed of the photos (default: 0)")
    ph.add_argument("--landmarks-only", action="store_true", help="the landmark fit only (the default)")
    ph.add_argument("--photometric", action="store_true", help="the 'jnr' rows with the photometric stages")
    ph.add_argument(
        "--detected",
        action="store_true",
        help="fit dlib's detections on the renders instead of the true landmarks + 1 px noise",
    )
    ph.add_argument("--config", help="YAML overriding the fitting settings")
    ph.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one fitting setting")
    _add_outputs(ph)
    ph.add_argument("--quiet", action="store_true", help="no progress bar")
    ph.set_defaults(func=cmd_eval_photos)
