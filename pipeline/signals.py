"""SIGTERM, SIGHUP and SIGQUIT handled like Ctrl-C, and worker processes that die with their parent.

SIGINT raises :class:`KeyboardInterrupt`; :func:`terminate_as_exception` makes SIGTERM, SIGHUP (a closed
terminal, a dropped ssh session) and SIGQUIT raise :class:`Terminated`, so the same ``try/finally`` blocks
(the staged output folders of :mod:`pipeline.files`) clean up in every case (SIGKILL cannot be caught: what
it leaves, the next run of the command removes, :func:`rig.io.atomic.remove_stale_temporaries`).
Worker processes (``jnr fit FOLDER --jobs N``) call
:func:`worker_init`: they get SIGTERM when their parent dies (Linux ``PR_SET_PDEATHSIG``), and the
parent terminates them when it is interrupted (:func:`stop_children`).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager

_PR_SET_PDEATHSIG = 1


TERMINATING = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP", "SIGQUIT") if hasattr(signal, name))
"""The signals that raise :class:`Terminated` (SIGINT raises KeyboardInterrupt)."""


class Terminated(BaseException):
    """Raised in the main thread by SIGTERM, SIGHUP or SIGQUIT (a BaseException, so ``except Exception`` does
    not swallow it); ``signum`` is the signal's number (the exit status is ``128 + signum``)."""

    def __init__(self, message: str = "terminated", signum: int = signal.SIGTERM) -> None:
        super().__init__(message)
        self.signum = int(signum)

    @property
    def name(self) -> str:
        """The signal's name, e.g. ``SIGHUP``."""
        try:
            return signal.Signals(self.signum).name
        except ValueError:
            return f"signal {self.signum}"


def _raise_terminated(signum, frame) -> None:
    # A second signal must not interrupt the clean-up the first one started.
    ignore_termination()
    raise Terminated(f"terminated by signal {signum}", signum)


def terminate_as_exception() -> None:
    """Make SIGTERM, SIGHUP and SIGQUIT raise :class:`Terminated` in the main thread (call from the main
    thread)."""
    for signum in TERMINATING:
        signal.signal(signum, _raise_terminated)


def run_interruptibly(function, *args, **kwargs):
    """``function(*args, **kwargs)`` in a daemon thread while this (the main) thread waits in short steps, so
    that Ctrl-C or SIGTERM (:func:`terminate_as_exception`) is acted on at once even while the function is in a
    long native call (a Mitsuba render releases the GIL but would hold the main thread until it returns: a
    SIGTERM came 33 s late, issue 38). The interrupted call is abandoned: the command's clean-up runs and the
    process ends (``jnr``'s :func:`pipeline.cli.run` exits without waiting for daemon threads).

    Returns:
        What ``function`` returned; raises what it raised."""
    import threading

    outcome: dict = {}

    def target() -> None:
        try:
            outcome["value"] = function(*args, **kwargs)
        except BaseException as exc:  # passed on to the caller below
            outcome["error"] = exc

    worker = threading.Thread(target=target, name=getattr(function, "__name__", "work"), daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(0.05)
    if "error" in outcome:
        raise outcome["error"]
    return outcome.get("value")


def ignore_termination() -> None:
    """Ignore SIGINT, SIGTERM, SIGHUP and SIGQUIT from now on (the clean-up has started, or the command's work
    is done and written: a signal then must neither interrupt the clean-up nor turn a finished command
    into a failed one)."""
    for signum in (signal.SIGINT, *TERMINATING):
        signal.signal(signum, signal.SIG_IGN)


_in_task = False
_is_worker = False


def _worker_sigterm(signum, frame) -> None:
    if not _in_task:
        os._exit(128 + signum)  # idle: nothing to clean up
    _raise_terminated(signum, frame)


@contextmanager
def worker_task() -> Iterator[None]:
    """Run one task in a worker: SIGTERM raises :class:`Terminated` inside it (the task's ``finally`` and
    staged outputs clean up), then the worker process exits (a process pool would otherwise catch the
    exception as the task's result and wait for more work, outliving its parent)."""
    global _in_task
    if not _is_worker:  # in the main process Terminated goes on to the command's own handling
        yield
        return
    _in_task = True
    try:
        yield
    except Terminated:
        os._exit(143)
    finally:
        _in_task = False


def worker_init(parent_pid: int) -> None:
    """Initialiser of a worker process: SIGTERM ends it (inside :func:`worker_task`, after the task's
    clean-up), SIGINT is left to the parent (which stops the workers), and the worker gets SIGTERM as
    soon as its parent dies, even by SIGKILL (Linux)."""
    global _is_worker
    _is_worker = True
    for signum in TERMINATING:
        signal.signal(signum, _worker_sigterm)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os.kill(os.getpid(), signal.SIGTERM)


def stop_children(timeout: float = 10.0) -> None:
    """Terminate this process's multiprocessing children (SIGTERM, so they clean up), then kill the
    ones still alive after ``timeout`` seconds."""
    import multiprocessing
    import time

    children = multiprocessing.active_children()
    for child in children:
        child.terminate()
    deadline = time.monotonic() + timeout
    for child in children:
        child.join(max(0.0, deadline - time.monotonic()))
        if child.is_alive():
            child.kill()
            child.join(1.0)
