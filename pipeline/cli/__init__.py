"""The ``jnr`` command line.

    jnr demo [--out DIR]                       the rig, and jnr fit on the astronaut and a synthetic photo
    jnr rig info [--json]                      sizes of the rig
    jnr rig build [--out FILE | --check]       regenerate the template asset from code
    jnr rig export --format obj|ply|gltf --out FILE [--params PARAMS.json]
    jnr rig edit PARAMS.json --out FILE        write the head edited by named parameters
    jnr data synth --out DIR                   write the synthetic head population
    jnr train                                  learn linear + neural skinning weights
    jnr data scan --out FILE.ply               a simulated depth scan of a held-out synthetic head
    jnr fit PHOTO... --out DIR                 reconstruct the head in a photo (or several, in parallel)
    jnr fit-scan CLOUD --out DIR               fit the rig to a point cloud (non-rigid ICP)
    jnr eval capacity [--json]                 known-correspondence error of each skinning variant
    jnr eval scans [--neutral N --expressive N]  fit-scan vs nricp_amberg on simulated depth scans
    jnr eval photos [--neutral N --expressive N] jnr fit on synthetic renders with known truth
    jnr track VIDEO --out DIR                  follow a face through a video: ARKit curves, animated head, preview
    jnr animate FIT_DIR CURVES.csv --out OUT.glb  drive a fit with ARKit curves: animated glTF + GIF preview
    jnr retarget SOURCE_FIT TARGET_FIT --out DIR  one fit's expression on another fit's identity
    jnr accessory FIT_DIR ACCESSORY.obj --out DIR  glasses, a cap or your mesh skinned to a fitted head

Each command's parser lives beside its handler, one module per command group (:mod:`.demo`,
:mod:`.fit`, :mod:`.fit_scan`, :mod:`.track`, :mod:`.rig`, :mod:`.data`, :mod:`.train`, :mod:`.evaluate`; shared
pieces in :mod:`.common`); a handler parses, calls one library function, prints and maps errors.

Errors in the input (:class:`rig.errors.InputError` and its subclasses: missing or malformed files,
unknown parameter names, values outside limits, refused outputs) end with a one-line message on
stderr and exit status 2; a broken installation (:class:`rig.errors.SetupError`, render's
``LLVMError``), an error while writing or a diverged fit, 1. Any other exception is a defect in jnr, not
the user's input: one line with its type, message and where it was raised (``JNR_TRACEBACK=1`` adds the
traceback), exit status 1. Nothing half-written is left behind.
"""

from __future__ import annotations

import argparse
import logging
import sys

from pipeline.cli import accessory, animate, data, demo, evaluate, fit, fit_scan, rig, track, train
from pipeline.cli.common import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, CliError, PrintableStream, printable

COMMAND_GROUPS = (demo, fit, fit_scan, track, animate, accessory, rig, data, train, evaluate)
"""The modules whose ``add_commands(subparsers)`` make the sub-commands, in the order ``--help`` lists them."""


class JnrArgumentParser(argparse.ArgumentParser):
    """argparse with jnr's errors: one line ``jnr: error: <command>: <what>`` and exit status 2, not a usage
    block (the sub-commands' parsers are of this class too: argparse makes them with their parent's)."""

    def error(self, message: str):
        self.exit(EXIT_USAGE, f"jnr: error: {self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``jnr`` parser: every command's parser, made by its module."""
    parser = JnrArgumentParser(
        prog="jnr",
        description="Joint-based Neural Rig: a 52-joint face rig, fitted to photos and point clouds.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Units: millimetres in rig space (right-handed, +Y up, +Z out of the face); rotations in "
        'degrees; scales as factors.\nParameter files: JSON {"joints": {"nose_tip.translate_y": 2.0, ...}}.',
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument(
        "--version", action="version", version=f"jnr {package_version()}", help="print jnr's version and exit"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for group in COMMAND_GROUPS:
        group.add_commands(sub)
    _add_verbose_everywhere(sub)
    return parser


def _add_verbose_everywhere(sub: argparse._SubParsersAction) -> None:
    """``-v/--verbose`` and ``--quiet`` also after every (nested) sub-command: ``jnr fit a.jpg -v`` as
    ``jnr -v fit a.jpg`` (``SUPPRESS``: a sub-command's parser does not reset a flag given before it)."""
    for command in sub.choices.values():
        nested = [a for a in command._actions if isinstance(a, argparse._SubParsersAction)]
        if nested:
            for action in nested:
                _add_verbose_everywhere(action)
            continue
        command.add_argument(
            "-v", "--verbose", action="store_true", default=argparse.SUPPRESS, help="log progress details (as jnr -v)"
        )
        quiet = next((a for a in command._actions if "--quiet" in a.option_strings), None)
        if quiet is None:
            command.add_argument(
                "--quiet", action="store_true", default=argparse.SUPPRESS, help="no progress bars (as jnr --quiet)"
            )
        else:
            quiet.default = argparse.SUPPRESS


def package_version() -> str:
    """The installed package's version (``pyproject.toml``), or ``unknown`` outside an installation."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("jnr")
    except PackageNotFoundError:
        return "unknown"


def _format_warning(message, category, filename, lineno, line=None) -> str:
    """Warnings as one line for users: no Python file, line number or source line."""
    return f"warning: {message}"


def _one_line(exc: BaseException) -> str:
    """An exception's message on one line (OSError: strerror and the file)."""
    if isinstance(exc, OSError) and exc.strerror and exc.filename:
        return f"{exc.filename}: {exc.strerror}"
    text = " ".join(printable(str(exc)).split())
    return text or type(exc).__name__


def run() -> None:
    """The ``jnr`` console command: :func:`main`, then a quick exit. Once the command is done (its outputs
    written, closed and moved into place) the interpreter's own teardown of torch, Dr.Jit and LiteRT takes
    a noticeable part of a short command (``benchmarks/bench_fit_command.py``; ``docs/fit_photo.md``, "Speed of the
    whole command"); it is skipped when nothing else runs (no other non-daemon thread, no child process), after
    the output streams and the logs are flushed."""
    import multiprocessing
    import os
    import threading

    from pipeline.signals import Terminated, ignore_termination, terminate_as_exception

    terminate_as_exception()  # from the first moment: a signal during start-up is one line too
    try:
        code = main(restore_signals=False)
    except KeyboardInterrupt:  # before main's own handling began (reading the arguments)
        print("jnr: interrupted", file=sys.stderr)
        code = 130
    except Terminated as exc:
        print(f"jnr: terminated ({exc.name})", file=sys.stderr)
        code = 128 + exc.signum
    ignore_termination()  # the command is over: a late signal must not turn it into a failure
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (BrokenPipeError, ValueError):  # the reader went away, or a stream was closed
        code = code or 141
    logging.shutdown()
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon]
    if not others and not multiprocessing.active_children():
        os._exit(code)
    sys.exit(code)


def main(argv: list[str] | None = None, *, restore_signals: bool = True) -> int:
    """Run ``jnr`` with ``argv`` (default: ``sys.argv[1:]``); returns the exit status: 0, 2 for bad input
    (:class:`rig.errors.InputError`, a missing or refused file), 1 for other failures
    (:class:`rig.errors.JnrError`, render's ``LLVMError``, OSError, a diverged fit's FloatingPointError; any other
    exception is a defect, reported on one line with where it was raised), 130 on Ctrl-C, 128 + the
    signal's number on SIGTERM (143), SIGHUP (129) or SIGQUIT (131), 141 when the reader of its output goes
    away (``| head``); errors are one line on stderr. Once the command's work is done, signals are ignored
    (a finished output is never reported as a failure); ``restore_signals`` puts the caller's handlers back
    at the end (the console command, :func:`run`, leaves them ignored until it exits)."""
    import os
    import signal
    import threading
    import warnings

    from pipeline.signals import TERMINATING, Terminated, ignore_termination, terminate_as_exception

    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="jnr: %(message)s")
    logging.captureWarnings(True)
    saved_format, warnings.formatwarning = warnings.formatwarning, _format_warning
    from render.backend import LLVMError
    from rig.errors import InputError, JnrError

    main_thread = threading.current_thread() is threading.main_thread()
    saved = {n: signal.getsignal(n) for n in (signal.SIGINT, *TERMINATING)} if main_thread else {}
    if main_thread:
        terminate_as_exception()
    saved_stdout, sys.stdout = sys.stdout, PrintableStream(sys.stdout)  # names printed as text, not terminal codes
    try:
        try:
            code = args.func(args)
        except Exception as exc:
            # a signal that arrived inside an import or a class body comes wrapped (RuntimeError from
            # __set_name__): handle it as the signal it is
            cause = _interruption(exc)
            if cause is None:
                raise
            raise cause from None
        if main_thread:
            ignore_termination()  # the work is done and written
        return code
    except CliError as exc:
        print(f"jnr: error: {exc}", file=sys.stderr)
        return exc.code
    except (
        InputError,
        FileNotFoundError,
        FileExistsError,
        IsADirectoryError,
        NotADirectoryError,
        PermissionError,
    ) as exc:
        print(f"jnr: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # the reader went away (``jnr rig info --json | head``): stop quietly, as on SIGPIPE
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so that the interpreter's final flush does not fail again
        return 141
    except (JnrError, LLVMError, OSError, FloatingPointError) as exc:  # set-up, system, a diverged fit
        print(f"jnr: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FAILURE
    except Exception as exc:  # not raised on purpose: a defect in jnr (or a library), never the user's input
        print(f"jnr: internal error: {_defect_report(exc)}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        if main_thread:
            ignore_termination()
        print("jnr: interrupted; nothing half-written was left behind", file=sys.stderr)
        return 130
    except Terminated as exc:
        print(f"jnr: terminated ({exc.name}); nothing half-written was left behind", file=sys.stderr)
        return 128 + exc.signum
    finally:
        sys.stdout = saved_stdout
        warnings.formatwarning = saved_format
        if restore_signals:
            for signum, handler in saved.items():
                signal.signal(signum, handler if handler is not None else signal.SIG_DFL)


def _defect_report(exc: BaseException) -> str:
    """One line for an exception jnr did not raise on purpose: its type, message and where it was raised
    (the innermost frame, and the innermost frame in jnr's own packages when that is another one), asking
    for a report; ``JNR_TRACEBACK=1`` in the environment prints the whole traceback too."""
    import os
    import traceback

    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if _package_path(f.filename) is not None]

    def where(frame: traceback.FrameSummary) -> str:
        return f"{_package_path(frame.filename) or os.path.basename(frame.filename)}:{frame.lineno} in {frame.name}"

    places = [where(frames[-1])] if frames else []
    if ours and ours[-1] is not frames[-1]:
        places.append(f"called from {where(ours[-1])}")
    if os.environ.get("JNR_TRACEBACK"):
        traceback.print_exception(exc, file=sys.stderr)
    at = f" (at {', '.join(places)})" if places else ""
    return (
        f"{type(exc).__name__}: {_one_line(exc)}{at}; this is a defect in jnr, not in the input: please report it "
        "with this line (JNR_TRACEBACK=1 prints the whole traceback)"
    )


def _package_path(filename: str) -> str | None:
    """``filename`` relative to the folder holding jnr's packages when it is one of their files, else None."""
    import os

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    path = os.path.abspath(filename)
    rel = os.path.relpath(path, root)
    if rel.split(os.sep)[0] in ("rig", "pipeline", "landmarks", "render"):
        return rel
    return None


def _interruption(exc: BaseException) -> BaseException | None:
    """The KeyboardInterrupt or :class:`pipeline.signals.Terminated` an exception was raised from or during
    (its ``__cause__``/``__context__`` chain), or None."""
    from pipeline.signals import Terminated

    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, KeyboardInterrupt | Terminated):
            return exc
        exc = exc.__cause__ or exc.__context__
    return None


__all__ = ["EXIT_FAILURE", "EXIT_OK", "EXIT_USAGE", "CliError", "build_parser", "main", "run"]
