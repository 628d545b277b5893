"""Run independent tasks on this machine's cores or on a Ray cluster, with the same results either way.

A task is a module-level function and its (picklable) arguments. :func:`run_tasks` runs a list of them (``holousd
batch``'s captures, ``holousd bench``'s scenes); a :class:`TaskPool` keeps its workers between lists (the search
stage's objects, one depth of the support tree at a time):

- ``ray=None``: in a local process pool of ``workers`` processes (spawned, so that torch and Warp start clean in
  each; Ray is not imported); ``workers=1`` runs them one after another in this process.
- ``ray="local"``: a Ray instance started on this machine for the run; ``ray="auto"`` or ``ray="HOST:PORT"``: the
  running cluster (``ray start --head`` on the head node, ``ray start --address HOST:PORT`` on the others). Each
  task is a Ray task declaring ``num_cpus`` cores and ``memory_mb`` of memory, so that Ray places no more tasks
  on a node than it can hold.

Every task is wrapped: an exception in one (a capture that cannot be read) becomes its one-line error, and the
others go on. Outcomes come back in the order the tasks were given, whatever order they finished in, each with
its wall time inside the worker and the time from submission to its result here.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from holousd._errors import HolousdError

__all__ = ["TaskOutcome", "TaskPool", "available_cores", "machine_info", "overhead", "require_ray", "run_tasks"]


@dataclass(kw_only=True)
class TaskOutcome:
    """What one task gave."""

    key: str
    """The task's name (a capture, a scene and preset)."""
    ok: bool
    """False when the task raised."""
    value: Any = None
    """The task function's return value (None when it failed)."""
    error: str | None = None
    """One line: what went wrong (None when it succeeded)."""
    wall_s: float = 0.0
    """Seconds the task ran inside its worker."""
    turnaround_s: float = 0.0
    """Seconds from submitting the task to holding its result (queueing behind other tasks included)."""
    submitted: float = 0.0
    started: float = 0.0
    ended: float = 0.0
    received: float = 0.0
    """Seconds since the epoch: submitted here, started and ended in its worker, its result held here."""


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _call(fn: Callable[..., Any], args: tuple) -> tuple[bool, Any, float, float, float]:
    """Run ``fn(*args)`` in a worker: ``(ok, value or one-line error, wall_s, started, ended)``, the last two in
    seconds since the epoch (how long a free worker waited for its next task)."""
    started = time.time()
    start = time.perf_counter()
    try:
        ok, value = True, fn(*args)
    except HolousdError as exc:
        ok, value = False, _one_line(str(exc))
    except Exception as exc:  # noqa: BLE001 - one failing task must not stop the others; reported, not hidden
        ok, value = False, f"internal error ({type(exc).__name__}: {_one_line(str(exc))})"
    return ok, value, time.perf_counter() - start, started, time.time()


def _lost(what: str, exc: BaseException) -> tuple[bool, Any, float, float, float]:
    """The result of a task whose worker never returned one (killed, out of memory), as :func:`_call` gives it."""
    now = time.time()
    return False, f"{what} ({type(exc).__name__}: {_one_line(str(exc))[:300]})", 0.0, now, now


def require_ray() -> None:
    """Raise a one-line error when Ray is not installed (checked before any work, not when the first task goes)."""
    try:
        import ray  # noqa: F401
    except ModuleNotFoundError:
        raise HolousdError("--ray needs Ray: pip install 'holousd[ray]' (or run without --ray: local worker "
                           "processes)") from None


def _outcome(key: str, result: tuple[bool, Any, float, float, float], submitted: float) -> TaskOutcome:
    ok, value, wall, started, ended = result
    received = time.time()
    return TaskOutcome(key=key, ok=ok, value=value if ok else None, error=None if ok else value, wall_s=wall,
                       turnaround_s=received - submitted, submitted=submitted, started=started, ended=ended,
                       received=received)  # fmt: skip


def overhead(outcomes: list[TaskOutcome], slots: int) -> dict[str, float]:
    """What running ``outcomes`` on ``slots`` workers cost beyond the tasks themselves, seconds per task:
    ``dispatch_s``, how long a free worker waited before its next task started (the first ``slots`` tasks: from
    submission; then each start against the slot the earliest unmatched end freed: start-up, scheduling,
    shipping the arguments), and ``return_s``, from a task's end in its worker to its result here."""
    done = [o for o in outcomes if o.ended >= o.started > 0]
    if not done:
        return {"dispatch_s": 0.0, "return_s": 0.0}
    starts = sorted(o.started for o in done)
    frees = sorted([done[0].submitted] * min(slots, len(done)) + [o.ended for o in done])
    dispatch = [max(0.0, start - frees[j]) for j, start in enumerate(starts)]
    return {"dispatch_s": sum(dispatch) / len(done),
            "return_s": sum(max(0.0, o.received - o.ended) for o in done) / len(done)}  # fmt: skip


def _connect(address: str) -> None:
    require_ray()
    import ray

    if ray.is_initialized():  # a cluster this process already joined (a test's local cluster, a notebook)
        return
    try:
        if address == "local":
            ray.init(include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
    except ConnectionError as exc:
        raise HolousdError(
            f"--ray {address}: no Ray cluster answered ({_one_line(str(exc))}); start one with `ray start --head` "
            "(and `ray start --address HEAD:6379` on the other nodes), or pass --ray local to start one here"
        ) from None


class TaskPool:
    """Workers that stay up between calls of :meth:`run` (a search runs one batch of tasks per depth of the support
    tree; spawning a process per batch would cost more than the tasks): ``with TaskPool(workers=2) as pool:``.

    ``workers`` local processes (None: one per core; 1: in this process, nothing spawned) or, with ``ray``, Ray
    tasks declaring ``num_cpus`` cores and ``memory_mb`` MiB each (Ray keeps its worker processes warm itself).
    """

    def __init__(self, *, workers: int | None = None, ray: str | None = None, num_cpus: float = 1.0,
                 memory_mb: float | None = None) -> None:  # fmt: skip
        self.ray = ray
        self.workers = max(1, workers or available_cores())
        self.num_cpus = num_cpus
        self.memory_mb = memory_mb
        self._pool: Any = None

    def __enter__(self) -> TaskPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the local worker processes (a Ray cluster stays up)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def run(self, fn: Callable[..., Any], tasks: list[tuple[str, tuple]],
            on_done: Callable[[TaskOutcome], None] | None = None) -> list[TaskOutcome]:  # fmt: skip
        """Run ``fn(*args)`` for every ``(key, args)`` of ``tasks``; outcomes in the order of ``tasks``."""
        if not tasks:
            return []
        if self.ray is not None:
            return _run_ray(fn, tasks, self.ray, self.num_cpus, self.memory_mb, on_done)
        outcomes: dict[int, TaskOutcome] = {}
        submitted = time.time()

        def done(k: int, result: tuple[bool, Any, float, float, float]) -> None:
            outcomes[k] = _outcome(tasks[k][0], result, submitted)
            if on_done is not None:
                on_done(outcomes[k])

        if self.workers == 1 or (len(tasks) == 1 and self._pool is None):  # nothing to spread: no process spawned
            for k, (_, args) in enumerate(tasks):
                done(k, _call(fn, args))
        else:
            from concurrent.futures import as_completed

            if self._pool is None:
                import multiprocessing
                from concurrent.futures import ProcessPoolExecutor

                self._pool = ProcessPoolExecutor(max_workers=self.workers,
                                                 mp_context=multiprocessing.get_context("spawn"))  # fmt: skip
            # the workers spawn on submit, with this environment
            with _child_threads(max(1, available_cores() // self.workers)):
                futures = {self._pool.submit(_call, fn, args): k for k, (_, args) in enumerate(tasks)}
            for future in as_completed(futures):
                try:
                    result = future.result()
                except Exception as exc:  # noqa: BLE001 - the worker died (killed, out of memory): that task fails
                    result = _lost("the worker process died", exc)
                done(futures[future], result)
        return [outcomes[k] for k in range(len(tasks))]


_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity; all of the machine's where that is not known)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


@contextlib.contextmanager
def _child_threads(threads: int) -> Iterator[None]:
    """Processes spawned inside take ``threads`` BLAS / OpenMP threads (unless the user set them): two workers on
    two cores each running two BLAS threads made the search's proposals 1.7x slower than one worker alone."""
    saved = {v: os.environ.get(v) for v in _THREAD_VARS}
    for v in _THREAD_VARS:
        os.environ.setdefault(v, str(threads))
    try:
        yield
    finally:
        for v, value in saved.items():
            if value is None:
                os.environ.pop(v, None)
            else:
                os.environ[v] = value


def run_tasks(fn: Callable[..., Any], tasks: list[tuple[str, tuple]], *, workers: int | None = None,
              ray: str | None = None, num_cpus: float = 1.0, memory_mb: float | None = None,
              on_done: Callable[[TaskOutcome], None] | None = None) -> list[TaskOutcome]:  # fmt: skip
    """Run ``fn(*args)`` for every ``(key, args)`` of ``tasks``; outcomes in the order of ``tasks``.

    Args:
        fn: A module-level function (workers import it by name).
        tasks: ``(key, args)`` per task.
        workers: Local processes (None: one per core; 1: in this process). Ignored with ``ray``.
        ray: None (local), ``"local"``, ``"auto"`` or a cluster address ``HOST:PORT``.
        num_cpus: Cores each Ray task declares.
        memory_mb: Memory each Ray task declares, MiB (None: none declared).
        on_done: Called here with each outcome as it arrives (a progress bar).
    """
    workers = max(1, min(workers or available_cores(), len(tasks) or 1))
    with TaskPool(workers=workers, ray=ray, num_cpus=num_cpus, memory_mb=memory_mb) as pool:
        return pool.run(fn, tasks, on_done)


def _run_ray(fn: Callable[..., Any], tasks: list[tuple[str, tuple]], address: str, num_cpus: float,
             memory_mb: float | None, on_done: Callable[[TaskOutcome], None] | None) -> list[TaskOutcome]:  # fmt: skip
    import ray

    _connect(address)
    options: dict[str, Any] = {"num_cpus": num_cpus, "max_retries": 0}
    if memory_mb:
        options["memory"] = int(memory_mb * 2**20)
    remote = ray.remote(**options)(_call)
    submitted = time.time()
    refs = [remote.remote(fn, args) for _, args in tasks]
    index = {ref: k for k, ref in enumerate(refs)}
    outcomes: dict[int, TaskOutcome] = {}
    pending = list(refs)
    while pending:
        ready, pending = ray.wait(pending, num_returns=1)
        for ref in ready:
            k = index[ref]
            try:
                result = ray.get(ref)
            except Exception as exc:  # noqa: BLE001 - the worker died (killed, out of memory): that task fails
                result = _lost("the Ray task failed", exc)
            outcomes[k] = _outcome(tasks[k][0], result, submitted)
            if on_done is not None:
                on_done(outcomes[k])
    return [outcomes[k] for k in range(len(tasks))]


def machine_info() -> dict[str, Any]:
    """Where a benchmark ran: CPU model, core count, memory, OS, Python, torch threads, holousd version."""
    import platform

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    memory_gb = None
    try:
        memory_gb = round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
    except (ValueError, OSError, AttributeError):
        pass
    from holousd import __version__

    cores = available_cores()

    torch_threads = None
    if "torch" in sys.modules:
        torch_threads = sys.modules["torch"].get_num_threads()
    return {"cpu": cpu, "cores": cores, "memory_gb": memory_gb, "os": platform.platform(),
            "python": platform.python_version(), "torch_threads": torch_threads, "holousd": __version__}  # fmt: skip
