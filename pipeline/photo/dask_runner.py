"""Fitting a batch of photos on a Dask cluster: ``jnr fit FOLDER --out DIR --scheduler ADDRESS``.

:class:`DaskRunner` is a ``run`` for :func:`pipeline.photo.batch.fit_photo_files`: it connects to a
running ``dask.distributed`` scheduler, submits one :func:`~pipeline.photo.task.fit_photo_task` per
photo (:func:`fit_on_worker`) and yields each photo's results as its fit completes (``distributed.as_completed``), so
the
summary rows, the resuming and the outputs are those of the local process pool. A worker writes its
photo's output folder itself, so the workers must see the photos and ``--out`` at the same paths as this
machine (a shared file system) and must have jnr installed (the task is sent by reference to
:func:`~pipeline.photo.task.fit_photo_task`); the paths are sent as absolute paths and the results
name them as the caller gave them.

``distributed`` is imported only here and only when a runner is made, so jnr starts without it.

Example:
    >>> with DaskRunner("tcp://scheduler:8786") as run:  # doctest: +SKIP
    ...     results = fit_photo_files(photos, "out/fits", run=run)
"""

from __future__ import annotations

import asyncio
import os
import threading
from collections.abc import Iterator
from dataclasses import replace

from pipeline.photo.summary import PhotoFileResult
from pipeline.photo.task import PhotoTask, fit_photo_task
from rig.errors import InputError, SetupError

DEFAULT_TIMEOUT_S = 10.0
"""How long :class:`DaskRunner` tries to reach the scheduler, and then waits for its first worker."""


class SchedulerError(SetupError):
    """The Dask scheduler cannot be reached or has no workers (exit status 1)."""


_ONE_FIT_AT_A_TIME = threading.Lock()
"""Fits in one process run one after another: the renderer's Mitsuba variant is process-wide state, so two
fits in two threads of one worker break each other (seen: "Plugin direct_projective not found")."""


def fit_on_worker(task: PhotoTask) -> tuple[PhotoFileResult, ...]:
    """What a Dask worker runs for one photo: :func:`pipeline.photo.task.fit_photo_task`, one fit per
    worker process at a time (a worker started with ``--nthreads 2`` runs its fits in turn; start one
    worker process per core instead: ``dask worker ADDRESS --nworkers N --nthreads 1``)."""
    with _ONE_FIT_AT_A_TIME:
        return fit_photo_task(task)


def _distributed():
    """The ``distributed`` module, or a one-line :class:`~rig.errors.SetupError` saying how to install it."""
    try:
        import distributed
    except ImportError:
        raise SetupError(
            "--scheduler needs Dask's 'distributed' package, which is not installed: "
            "pip install 'jnr[cluster]' (here and on every worker)"
        ) from None
    return distributed


def check_address(address: str) -> str:
    """``address`` as Dask will use it (``tcp://host:port``; a bare ``host:port`` is TCP).

    Raises:
        InputError: not a scheduler address (no port, an unknown scheme); SetupError: ``distributed``
            is not installed.
    """
    _distributed()
    from distributed.comm.addressing import parse_address

    text = str(address).strip()
    try:
        scheme, location = parse_address(text)
        if not location or location.endswith(":"):
            raise InputError("missing port number")
        if scheme == "tcp":
            from distributed.comm.addressing import parse_host_port

            parse_host_port(location)
    except (ValueError, TypeError) as exc:
        raise InputError(
            f"--scheduler {address!r} is not a Dask scheduler address ({exc}); expected e.g. tcp://host:8786"
        ) from None
    return text


async def _probe(address: str, timeout_s: float) -> None:
    """Open and close one connection to the scheduler (a failed ``Client`` would print a traceback
    when Python collects it)."""
    from distributed.comm import connect

    comm = await connect(address, timeout=timeout_s)
    await comm.close()


def _unreachable(address: str, timeout_s: float, exc: BaseException) -> SchedulerError:
    reason = " ".join(str(exc).split()) or type(exc).__name__
    return SchedulerError(
        f"cannot reach the Dask scheduler at {address} within {timeout_s:g} s ({reason}); "
        f"is `dask scheduler` running there?"
    )


def _absolute(task: PhotoTask) -> PhotoTask:
    """``task`` with absolute paths (a worker's working directory is not this one's)."""
    return replace(
        task,
        photo=os.path.abspath(task.photo),
        out=os.path.abspath(task.out),
        inputs=tuple(os.path.abspath(p) for p in task.inputs),
    )


def _as_given(result: PhotoFileResult, task: PhotoTask, sent: PhotoTask) -> PhotoFileResult:
    """A worker's result, its paths named as the caller gave them in ``task`` (``sent``: what was sent)."""

    def given(text: str | None) -> str | None:
        if text is None:
            return None
        return text.replace(sent.photo, task.photo).replace(sent.out, task.out)

    summary = result.summary
    if summary is not None:
        summary = {**summary, "photo": task.photo, "output": given(summary["output"])}
    return replace(result, photo=task.photo, summary=summary, error=given(result.error))


def _worker_failure(task: PhotoTask, exc: BaseException) -> tuple[PhotoFileResult, ...]:
    """The result of a task whose worker failed (it died, or could not run jnr)."""
    message = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, ImportError):
        message += " (is jnr installed on the Dask workers?)"
    return (PhotoFileResult(task.photo, error=f"{task.photo}: Dask worker: {type(exc).__name__}: {message}"),)


class DaskRunner:
    """``run(tasks)`` for :func:`pipeline.photo.batch.fit_photo_files` on a ``dask.distributed`` cluster.

    Connects when made (so a wrong address fails before any output is written); use it as a context
    manager, or call :meth:`close`. Calling it submits one task per photo and yields, as each completes,
    the tuple of its :class:`~pipeline.photo.summary.PhotoFileResult` (a worker that died or cannot run
    jnr becomes that photo's error row); closing the generator early (an interrupt) cancels the tasks
    not yet done (a fit already running on a worker still writes its output, kept by the next resume).

    Args:
        address: the scheduler, e.g. ``tcp://host:8786`` (``dask scheduler`` prints it).
        timeout_s: how long to try to reach the scheduler, then to wait for a worker (default:
            :data:`DEFAULT_TIMEOUT_S`).

    Raises:
        InputError: a malformed address; :class:`SchedulerError`: the scheduler cannot be reached in
            ``timeout_s`` or has no worker; SetupError: ``distributed`` is not installed.
    """

    def __init__(self, address: str, *, timeout_s: float | None = None):
        distributed = _distributed()
        self.address = check_address(address)
        self.timeout_s = float(DEFAULT_TIMEOUT_S if timeout_s is None else timeout_s)
        try:
            asyncio.run(_probe(self.address, self.timeout_s))
        except RuntimeError as exc:  # called inside a running event loop (a notebook): the Client checks
            if "event loop" not in str(exc):
                raise
        except (OSError, asyncio.TimeoutError) as exc:
            raise _unreachable(self.address, self.timeout_s, exc) from None
        except (ValueError, TypeError) as exc:
            raise InputError(f"--scheduler {address!r}: {exc}") from None
        try:
            self.client = distributed.Client(self.address, timeout=self.timeout_s, set_as_default=False)
        except (OSError, asyncio.TimeoutError) as exc:
            raise _unreachable(self.address, self.timeout_s, exc) from None
        try:
            self.client.wait_for_workers(1, timeout=self.timeout_s)
        except (OSError, asyncio.TimeoutError, TimeoutError):
            self.close()
            raise SchedulerError(
                f"the Dask scheduler at {self.address} has no workers (waited "
                f"{self.timeout_s:g} s); start some with `dask worker {self.address}`"
            ) from None

    @property
    def workers(self) -> int:
        """How many workers the scheduler has now."""
        return len(self.client.nthreads())

    def __call__(self, tasks: list[PhotoTask]) -> Iterator[tuple[PhotoFileResult, ...]]:
        from distributed import as_completed

        sent = [_absolute(t) for t in tasks]
        futures = {self.client.submit(fit_on_worker, s, pure=False): (t, s) for t, s in zip(tasks, sent)}
        try:
            for future in as_completed(futures, loop=self.client.loop):
                task, remote = futures[future]
                try:
                    results = future.result()
                except Exception as exc:
                    yield _worker_failure(task, exc)
                    continue
                yield tuple(_as_given(r, task, remote) for r in results)
        finally:
            pending = [f for f in futures if not f.done()]
            if pending:
                self.client.cancel(pending)

    def close(self) -> None:
        """Disconnect from the scheduler (the cluster keeps running)."""
        client = getattr(self, "client", None)
        if client is not None:
            client.close()
            self.client = None

    def __enter__(self) -> DaskRunner:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ["DEFAULT_TIMEOUT_S", "DaskRunner", "SchedulerError", "check_address", "fit_on_worker"]
