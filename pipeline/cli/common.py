"""What the ``jnr`` commands share: exit statuses, :class:`CliError`, the output check, progress bars,
``--set`` overrides and the fit configurations built from the options."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable, Iterable
from pathlib import Path

from rig.errors import JnrError

log = logging.getLogger("jnr")

EXIT_OK, EXIT_FAILURE, EXIT_USAGE = 0, 1, 2


def printable(text: str) -> str:
    """``text`` with its control characters (an escape sequence, a bell) written as ``\\xNN`` and line breaks
    as spaces, so a name cannot clear or recolour the terminal or break a one-line message."""
    return "".join(
        " " if c in "\n\r\t" else c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text
    )


class PrintableStream:
    """A text stream that writes control characters other than line breaks and tabs as ``\\xNN`` (so a file
    name printed in a summary cannot clear or recolour the terminal); everything else is the wrapped stream's."""

    def __init__(self, stream) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        self.stream.write(
            "".join(c if c in "\n\t" or c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)
        )
        return len(text)

    def __getattr__(self, name: str):
        return getattr(self.stream, name)


class CliError(JnrError):
    """An error to report to the user in one line (exit status ``code``)."""

    def __init__(self, message: str, code: int = EXIT_USAGE) -> None:
        super().__init__(message)
        self.code = code


def check_output(path: str | Path, force: bool, inputs: Iterable = (), kind: str = "file") -> None:
    """Refuse an output before any work (:func:`pipeline.files.check_output`: it exists and ``--force`` was
    not given, it is an input, ...); its :class:`~pipeline.files.OutputError` is an InputError, which
    :func:`pipeline.cli.main` reports with exit 2."""
    from pipeline.files import check_output as check

    check(path, force=force, inputs=[p for p in inputs if p], kind=kind)


def write_output_file(out: Path, force: bool, write: Callable[[Path], object]) -> None:
    """``write(tmp_path)`` into a staged file that replaces ``out`` atomically when it succeeds."""
    from pipeline.files import staged_file

    with staged_file(out, force) as tmp:
        write(tmp)


def command_line(default: str) -> str:
    """The command as the user typed it (``jnr fit a.png --out o``), recorded in the outputs."""
    return "jnr " + " ".join(sys.argv[1:]) if sys.argv[1:] else default


def progress_bars_wanted(stream=None) -> bool:
    """Whether to draw progress bars: only on a terminal (not into a log file or a pipe), and never when
    the ``TQDM_DISABLE`` environment variable is set to anything but ``""``/``0``/``false``."""
    import os
    import sys

    if os.environ.get("TQDM_DISABLE", "").strip().lower() not in ("", "0", "false"):
        return False
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())


class StageBars:
    """One tqdm bar per stage name: ``bars(stage, done, total)`` (the progress callback of the fits);
    drawn only where :func:`progress_bars_wanted` says so and ``disable`` (``--quiet``) is not set."""

    def __init__(self, disable: bool = False) -> None:
        self.disable = disable or not progress_bars_wanted()
        self.bar = None
        self.stage = None
        self.done = 0
        self.started = 0.0

    def __call__(self, stage: str, done: int, total: int) -> None:
        import time

        from tqdm import tqdm

        if stage != self.stage:
            self.close()
            self.stage, self.started = stage, time.perf_counter()
            self.bar = tqdm(total=total, desc=stage, disable=self.disable, leave=False)
        self.done = done
        self.bar.n = done
        self.bar.refresh() if done == total or done % 10 == 0 else None
        if done >= total:  # the stage is over: its log line says its own time, not the outputs' after it
            self.close()

    def close(self) -> None:
        """End the current stage's bar; with ``-v`` a log line says what it did and how long it took."""
        import time

        if self.bar is not None:
            log.info(
                "%s: %d/%d steps in %.1f s", self.stage, self.done, self.bar.total, time.perf_counter() - self.started
            )
            self.bar.close()
            self.bar = None
            self.stage = None


def parse_overrides(items: list[str] | None) -> dict:
    """``--set KEY=VALUE`` options as a nested dict (:func:`pipeline.config.parse_overrides`)."""
    from pipeline.config import ConfigError
    from pipeline.config import parse_overrides as parse

    try:
        return parse(items)
    except ConfigError as exc:
        raise CliError(str(exc)) from None


# ------------------------------------------------------------------------------------------------------
# The fit configurations from --config, --set and the options that stand for settings: the one place
# where options become config overrides.
# ------------------------------------------------------------------------------------------------------


def fit_photo_overrides(args: argparse.Namespace) -> dict:
    """The photo fit's overrides: ``--set`` items, ``--landmarks-only`` (``photometric.enabled: false``),
    ``--photometric`` (``photometric.enabled: true``), ``--units`` (``outputs.units``), ``--outputs``
    (``outputs.files``) and ``--ply-up`` (``outputs.ply_up``)."""
    overrides = parse_overrides(args.set)
    photometric = getattr(args, "photometric", False)
    if args.landmarks_only and photometric:
        raise CliError("--landmarks-only and --photometric contradict each other; give one")
    # dotted keys, applied after any group (a whole group here would replace the user's --set group.key)
    if args.landmarks_only or photometric:
        overrides["photometric.enabled"] = bool(photometric)
    for option, key in (("units", "units"), ("outputs", "files"), ("ply_up", "ply_up")):  # outputs.<key>
        value = getattr(args, option, None)
        if value is not None:
            overrides[f"outputs.{key}"] = value
    return overrides


def fit_scan_overrides(args: argparse.Namespace, seed_is_fit_seed: bool = True) -> dict:
    """The scan fit's overrides: ``--set`` items, and ``--seed`` (the cloud subsampling's) when
    ``seed_is_fit_seed`` (``jnr eval scans`` has a ``--seed`` of its own)."""
    overrides = parse_overrides(args.set)
    if seed_is_fit_seed and args.seed is not None:
        overrides["seed"] = args.seed
    return overrides


def load_fit_photo_config(args: argparse.Namespace):
    """:class:`pipeline.photo.fit.FitPhotoConfig` from ``--config``, ``--set`` and ``--landmarks-only``."""
    from pipeline.config import ConfigError, load_config
    from pipeline.photo.fit_config import FitPhotoConfig

    overrides = fit_photo_overrides(args)
    try:
        return load_config(FitPhotoConfig, args.config, overrides)
    except ConfigError as exc:
        raise CliError(str(exc)) from None


def load_fit_scan_config(args: argparse.Namespace, seed_is_fit_seed: bool = True):
    """:class:`pipeline.scan.fit.FitScanConfig` from ``--config``, ``--set`` and ``--seed``."""
    from pipeline.config import ConfigError, load_config
    from pipeline.scan.fit_config import FitScanConfig

    overrides = fit_scan_overrides(args, seed_is_fit_seed)
    try:
        return load_config(FitScanConfig, args.config, overrides)
    except ConfigError as exc:
        raise CliError(str(exc)) from None
