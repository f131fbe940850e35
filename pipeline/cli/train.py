"""``jnr train``: learn the linear and neural skinning weights from the synthetic population."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from pipeline.cli.common import (
    EXIT_OK,
    CliError,
    StageBars,
    check_output,
    parse_overrides,
)


def _train_artifact(args: argparse.Namespace, option: str, default_path, build) -> dict:
    """The shared part of ``jnr train --identity-prior`` / ``--identity-regressor`` / ``--asm-init``: only
    ``--out``, ``--force`` and ``--quiet`` apply (``--cache`` too for the regressor); the default output (a
    packaged asset) is overwritten, another only with ``--force``; ``build(out, progress)`` runs under progress
    bars. Returns what it returned."""
    several = sum(bool(x) for x in (args.identity_prior, args.identity_regressor, args.asm_init)) > 1
    if args.config or args.set or args.log or several or (args.cache and not args.identity_regressor):
        extra = ", --cache" if args.identity_regressor else ""
        raise CliError(f"{option} takes only --out{extra}, --force and --quiet")
    out = Path(args.out) if args.out else default_path()
    check_output(out, args.force or args.out is None)
    bars = StageBars(args.quiet)
    try:
        return {"artifact": str(out), **build(out, bars)}
    finally:
        bars.close()


def cmd_identity_prior(args: argparse.Namespace) -> int:
    from pipeline.fitting.identity import default_identity_prior_path
    from pipeline.train import train_identity_prior

    result = _train_artifact(
        args,
        "--identity-prior",
        default_identity_prior_path,
        lambda out, bars: train_identity_prior(out, progress=bars).meta,
    )
    print(json.dumps(result, indent=2))
    return EXIT_OK


def cmd_identity_regressor(args: argparse.Namespace) -> int:
    from pipeline.fitting.identity_regression import default_identity_regressor_path
    from pipeline.identity_training import train_identity_regressor

    def build(out, bars) -> dict:
        meta = train_identity_regressor(out, cache=args.cache, progress=bars).meta
        # the headline figures; the cross-validation tables stay in the asset's meta
        return {k: v for k, v in meta.items() if k not in ("cv_mse_u", "residual_cv_log_likelihood")}

    print(json.dumps(_train_artifact(args, "--identity-regressor", default_identity_regressor_path, build), indent=2))
    return EXIT_OK


def cmd_asm_init(args: argparse.Namespace) -> int:
    from rig.skinning.asm import INIT_COMPONENTS, default_init_path, save_initial_gmm

    def build(out, bars) -> dict:
        arrays = save_initial_gmm(out, progress=bars)
        return {
            f"K={k}": dict(
                zip(
                    ("rms_weight_error", "max_weight_error", "seconds"),
                    (round(float(x), 4) for x in arrays[f"k{k}_report"]),
                )
            )
            for k in INIT_COMPONENTS
        }

    print(json.dumps(_train_artifact(args, "--asm-init", default_init_path, build), indent=2))
    return EXIT_OK


def cmd_train(args: argparse.Namespace) -> int:
    from pipeline.train import load_config, train
    from rig.asset import default_skinning_path

    if args.asm_init:
        return cmd_asm_init(args)
    if args.identity_prior:
        return cmd_identity_prior(args)
    if args.identity_regressor:
        return cmd_identity_regressor(args)
    if args.cache:
        raise CliError("--cache applies to --identity-regressor only")
    try:
        config = load_config(args.config, parse_overrides(args.set))
    except (TypeError, ValueError) as exc:
        raise CliError(str(exc)) from None
    out = Path(args.out) if args.out else default_skinning_path()
    check_output(out, args.force or args.out is None)
    log_path = Path(args.log) if args.log else out.with_suffix(".log.json")
    bars = StageBars(args.quiet)
    try:
        report = train(config, out, log_path=log_path, progress=bars)
    finally:
        bars.close()
    print(
        json.dumps(
            {
                "artifact": str(out),
                "log": str(log_path),
                "counts": report.counts,
                "seconds": report.seconds,
                "train_rmse_mm_per_joint_fit": report.rmse_train_mm["per_joint_fit"],
            },
            indent=2,
        )
    )
    return EXIT_OK


def add_commands(sub: argparse._SubParsersAction) -> None:
    """``jnr train``."""
    tr = sub.add_parser(
        "train",
        help="learn the linear and neural skinning weights from the synthetic population",
        description="Fit joints, learn global linear weights (alternating), synthesise "
        "skinning-weight sets, train the auto-encoder and fine-tune the decoder "
        "WGAN-style. Writes rig/assets/jnr_skinning_v3.npz unless --out is given.",
    )
    tr.add_argument(
        "--identity-prior",
        action="store_true",
        help="instead: fit the joints of the training population (85 train heads + 215 more from the "
        "same distribution, ~3 min) and write the identity prior of the photo fit, a PPCA Gaussian "
        "of the fitted joints (rig/assets/jnr_identity_prior_v3.npz unless --out is given)",
    )
    tr.add_argument(
        "--identity-regressor",
        action="store_true",
        help="instead: photograph 20,000 ICT heads drawn afresh (10,000 from ICT's own distribution, 10,000 from "
        "one 1.5 x as wide; half with an expression; random pose, skin, light and focal length), read each with "
        "MediaPipe, and learn the map from its 478 3D points (and from their mirror images; its weights changing "
        "with the face's yaw) to the joints that the photo fit's conditional identity prior uses (~5 h on 2 cores, "
        "25 min from a full --cache; "
        "rig/assets/jnr_identity_regressor_v3.npz unless --out is given)",
    )
    tr.add_argument(
        "--cache",
        metavar="DIR",
        help="--identity-regressor: keep the rendered photos' points in DIR and reuse them (an interrupted run "
        "resumes; default .cache/identity_regressor)",
    )
    tr.add_argument(
        "--asm-init",
        action="store_true",
        help="instead: fit the initial Gaussian mixtures of the ASM skinning model (K = 2, 3, 5 per "
        "bone) to the rig's painted weights in UV space, ~10 min (rig/assets/jnr_asm_init_v3.npz "
        "unless --out is given)",
    )
    tr.add_argument("--config", help="YAML file overriding TrainConfig fields (configs/train.yaml)")
    tr.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one setting (repeatable)")
    tr.add_argument("--out", help="artifact path (default: the packaged rig/assets/jnr_skinning_v3.npz)")
    tr.add_argument("--log", help="training log JSON (default: next to the artifact)")
    tr.add_argument("--force", action="store_true", help="overwrite --out")
    tr.add_argument("--quiet", action="store_true", help="no progress bars")
    tr.set_defaults(func=cmd_train)
