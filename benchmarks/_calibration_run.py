"""Running the replications of the calibration benchmark (``bench_calibration.py``).

A method is a :class:`Group` of :class:`Case` s; case ``c``'s replication ``r`` has the seed
``1000 c + r`` and runs ``fn(*args, seed + offset)``. :func:`run` runs every group's
replications in this process (``jobs = 1``) or in a pool of ``jobs`` worker processes
(started by *spawn*: JAX is not fork-safe), the longest first, so that long cases do not
end up alone at the end. Every process that runs replications has one BLAS / OpenMP thread
and 64-bit JAX on the CPU, and shares the persistent XLA compilation cache
(``BIFID_JAX_CACHE``, default ``.jax_cache/``). A replication is deterministic in its seed,
so its rows, and their order in a group's rows file (by seed), do not depend on the number
of processes; each row carries the replication's wall time ``time_s`` and the CPU time of
its process ``cpu_s``. A group's rows file is rewritten after every replication (an
interrupted run loses only the replications under way); with ``resume`` the seeds already
in it are read back and not rerun.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import json
import multiprocessing
import os
import resource
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: one thread per process for the BLAS / OpenMP libraries (set before a worker loads numpy)
THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
#: XLA on one intra-op thread (``--xla-one-thread``)
XLA_ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
LOG_EVERY = 10  # a progress line every this many replications (and per completed case)


def log(msg: str) -> None:
    print(f"[bench_calibration] {msg}", file=sys.stderr, flush=True)


def default_jobs() -> int:
    """Worker processes by default: the machine's cores, at most 4."""
    return max(1, min(4, os.cpu_count() or 1))


@dataclasses.dataclass(frozen=True)
class Case:
    """One case: ``max(2, round(reps * frac))`` replications of ``fn(*args, seed + offset)``
    (``fn`` module-level, so that worker processes can unpickle it; the last of ``args`` is
    the noise level), expected to take ``cost`` seconds each (the order of the pool)."""

    name: str
    frac: float
    fn: Callable[..., list[dict]]
    args: tuple
    cost: float = 1.0
    offset: int = 0


@dataclasses.dataclass(frozen=True)
class Group:
    """A method's cases; its rows are written to ``rows_path``."""

    name: str
    cases: Sequence[Case]
    rows_path: Path


@dataclasses.dataclass(frozen=True)
class Task:
    group: str
    case: Case
    seed: int


def replicate(task: Task) -> list[dict]:
    """One replication: its rows (case, seed, noise, the quantities) with its wall and CPU
    time; a failed fit is one row with the exception (counted, not hidden)."""
    t0, c0 = time.perf_counter(), time.process_time()
    case, head = task.case, {"case": task.case.name, "seed": task.seed}
    try:
        out = case.fn(*case.args, task.seed + case.offset)
        rows = [{**head, "noise": case.args[-1], **q} for q in out]
    except Exception as exc:
        rows = [{**head, "failed": repr(exc)}]
    timing = {"time_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}
    return [{**r, **timing} for r in rows]


def configure(xla_one_thread: bool) -> None:
    """Environment of the processes that run replications (this one and the workers, which
    inherit it): one BLAS thread, JAX on the CPU in 64 bits, XLA on one thread if asked.
    Call before JAX is first used."""
    for k, v in {**THREAD_ENV, "JAX_PLATFORMS": "cpu", "JAX_ENABLE_X64": "1"}.items():
        os.environ.setdefault(k, v)
    if xla_one_thread:
        flags = os.environ.get("XLA_FLAGS", "")
        os.environ["XLA_FLAGS"] = f"{flags} {XLA_ONE_THREAD}".strip()


def init_process() -> None:
    """One BLAS thread (also where numpy was loaded before :func:`configure`), 64-bit JAX
    and the shared persistent compilation cache."""
    import jax
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
    jax.config.update("jax_enable_x64", True)
    cache = os.environ.get("BIFID_JAX_CACHE", str(ROOT / ".jax_cache"))
    if cache:
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def read_rows(path: Path) -> dict[int, list[dict]]:
    """The rows of ``path`` by seed (empty if absent)."""
    done: dict[int, list[dict]] = {}
    if path.exists():
        for r in json.loads(path.read_text()):
            done.setdefault(r["seed"], []).append(r)
    return done


def _results(tasks: list[Task], jobs: int) -> Iterator[tuple[Task, list[dict]]]:
    """``(task, rows)`` as replications complete: in this process in the given order, or in
    a pool of ``jobs`` spawned workers, the most costly first."""
    if jobs == 1:
        init_process()
        for t in tasks:
            yield t, replicate(t)
        return
    ctx = multiprocessing.get_context("spawn")
    ex = cf.ProcessPoolExecutor(jobs, mp_context=ctx, initializer=init_process)
    try:
        futures = {ex.submit(replicate, t): t for t in sorted(tasks, key=lambda t: -t.case.cost)}
        for fut in cf.as_completed(futures):
            yield futures[fut], fut.result()
    finally:
        ex.shutdown(wait=True, cancel_futures=True)


def _summary(rows: list[dict]) -> dict:
    """Rows and the wall and CPU time summed over their replications."""
    per_seed = {r["seed"]: r for r in rows}.values()
    return {
        "rows": rows,
        "time_s": sum(r.get("time_s", 0.0) for r in per_seed),
        "cpu_s": sum(r.get("cpu_s", 0.0) for r in per_seed),
        "n_replications": len(per_seed),
    }


def _cpu_s() -> float:
    """CPU time of this process and of its waited-for children."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run(
    groups: Sequence[Group],
    reps: int,
    jobs: int = 1,
    resume: bool = False,
    on_done: Callable[[str, dict], None] | None = None,
) -> tuple[dict[str, dict], dict]:
    """Every group's replications; per group its rows in seed order with the summed wall
    (``time_s``) and CPU (``cpu_s``) time of its replications (read-back ones included);
    ``on_done(name, result)`` as soon as a group's rows are all in. Also returns the wall
    and CPU time of the whole run (this process and its workers), ``wall_s`` and ``cpu_s``.
    """
    t0, c0 = time.perf_counter(), _cpu_s()
    rows: dict[str, dict[int, list[dict]]] = {}
    tasks: list[Task] = []
    left: dict[tuple[str, str], int] = {}  # replications still to run per (group, case)
    for g in groups:
        done = read_rows(g.rows_path) if resume else {}
        rows[g.name] = {}
        for c, case in enumerate(g.cases):
            for r in range(max(2, round(reps * case.frac))):
                seed = 1000 * c + r
                if seed in done:
                    rows[g.name][seed] = done[seed]
                else:
                    tasks.append(Task(g.name, case, seed))
                    left[g.name, case.name] = left.get((g.name, case.name), 0) + 1
    n_read = sum(len(v) for v in rows.values())
    log(f"{len(tasks)} replications to run ({n_read} read back), {jobs} process(es)")

    def finish(name: str) -> dict:
        ordered = [r for _, rs in sorted(rows[name].items()) for r in rs]
        path = next(g.rows_path for g in groups if g.name == name)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(ordered))
        return _summary(ordered)

    out = {g.name: finish(g.name) for g in groups if not any(k[0] == g.name for k in left)}
    for name in list(out):
        if on_done is not None:
            on_done(name, out[name])
    for i, (task, result) in enumerate(_results(tasks, jobs), start=1):
        rows[task.group][task.seed] = result
        if "failed" in result[0]:
            log(f"{task.case.name} seed {task.seed}: failed ({result[0]['failed']})")
        summary = finish(task.group)
        left[task.group, task.case.name] -= 1
        elapsed = time.perf_counter() - t0
        if left[task.group, task.case.name] == 0:
            log(f"{task.group} / {task.case.name}: case done, {elapsed:.0f} s since start")
        if i % LOG_EVERY == 0 or i == len(tasks):
            log(f"{i}/{len(tasks)} replications, {elapsed:.0f} s since start")
        if not any(n for k, n in left.items() if k[0] == task.group):
            out[task.group] = summary
            if on_done is not None:
                on_done(task.group, summary)
    whole = {"wall_s": time.perf_counter() - t0, "cpu_s": _cpu_s() - c0, "jobs": jobs}
    return {g.name: out[g.name] for g in groups}, whole
