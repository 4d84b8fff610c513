"""The engine that runs independent points: serially in this process, or on Ray.

A *task* is a picklable callable ``task(payload) -> dict`` (a row of results); a *point* is
``(index, payload)``. :func:`run_points` yields ``(index, row)`` as points finish, in any order.
A point that raises (a :class:`~app.errors.ConfigError` from a value out of range, a fault
turned exception, any bug) or whose worker process dies becomes a row with ``status = "error"``
and the one-line ``error``; the other points go on.

Ray (https://docs.ray.io) rather than ``multiprocessing`` because the same code then runs on a
cluster: with ``address`` (or ``RAY_ADDRESS``) it joins an existing Ray cluster, whose nodes must
have this package and its data files installed at the same version. Locally it starts a private
Ray instance with ``workers`` CPUs and no dashboard. Each worker is a Ray actor that keeps its
process (and its imported, compiled code) for the whole run and holds the task once, so a point
costs one small remote call. ``workers = 1`` runs in this process without Ray.
"""

from __future__ import annotations

import os
import traceback
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from app.errors import EngineError, FrhcError

Task = Callable[[Any], dict[str, Any]]
Point = tuple[int, Any]

#: Points queued per worker beyond the one it runs: hides the round trip without hoarding work.
QUEUE_PER_WORKER = 1


def error_row(exc: BaseException) -> dict[str, Any]:
    """The row of a failed point: ``status = "error"`` and a one-line message."""
    if isinstance(exc, FrhcError):
        message = str(exc)
    else:
        frame = traceback.extract_tb(exc.__traceback__)[-1:] if exc.__traceback__ else []
        where = f" (at {os.path.basename(frame[0].filename)}:{frame[0].lineno})" if frame else ""
        message = f"{type(exc).__name__}: {exc}{where}"
    return {"status": "error", "error": " ".join(message.split())}


def run_one(task: Task, payload: Any) -> dict[str, Any]:
    """``task(payload)`` with ``status = "ok"``, or the :func:`error_row` of what it raised."""
    try:
        return {**task(payload), "status": "ok", "error": ""}
    except Exception as exc:
        return error_row(exc)


def run_points(task: Task, points: Iterable[Point], workers: int = 1, address: str | None = None) -> Iterator[Point]:
    """Run ``task`` on every point; yields ``(index, row)`` as each finishes.

    Args:
        task: Picklable callable, payload -> row (a dict of column values).
        points: ``(index, payload)`` pairs.
        workers: Parallel workers (1 = serially in this process). With an ``address`` the
            default 0 means every CPU of the cluster.
        address: A Ray cluster to join (``"auto"``, ``"ray://host:10001"``, ...); None = the
            ``RAY_ADDRESS`` environment variable, else a private local instance.
    """
    address = address or os.environ.get("RAY_ADDRESS") or None
    if workers == 1 and address is None:
        for index, payload in points:
            yield index, run_one(task, payload)
        return
    yield from _run_ray(task, points, workers, address)


def _run_ray(task: Task, points: Iterable[Point], workers: int, address: str | None) -> Iterator[Point]:
    import ray
    from ray.exceptions import RayActorError, RayTaskError

    started = not ray.is_initialized()
    if started:
        try:
            if address is None:
                ray.init(
                    num_cpus=workers or os.cpu_count(),
                    include_dashboard=False,
                    log_to_driver=False,
                    configure_logging=False,
                )
            else:
                ray.init(address=address, log_to_driver=False, configure_logging=False)
        except Exception as exc:
            where = f"the Ray cluster at {address}" if address else "a local Ray instance"
            raise EngineError(f"cannot start {where}: {' '.join(str(exc).split())}") from None
    try:
        n = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        worker_cls = ray.remote(num_cpus=1)(_Worker)
        task_ref = ray.put(task)
        actors = [worker_cls.remote(task_ref) for _ in range(n)]
        pending: dict[Any, tuple[int, int, Any]] = {}
        load = [0] * n
        queue = iter(points)

        def submit(k: int) -> bool:
            nxt = next(queue, None)
            if nxt is None:
                return False
            index, payload = nxt
            pending[actors[k].run.remote(payload)] = (index, k, actors[k])  # type: ignore[attr-defined]
            load[k] += 1
            return True

        for k in range(n):
            for _ in range(1 + QUEUE_PER_WORKER):
                submit(k)
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            ref = done[0]
            index, k, actor = pending.pop(ref)
            load[k] -= 1
            try:
                row = ray.get(ref)
            except RayActorError as exc:
                # The worker process died (a crash, out of memory): this point fails, a new worker takes over.
                row = {"status": "error", "error": f"worker died: {' '.join(str(exc).split())[:300]}"}
                if actors[k] is actor:
                    actors[k] = worker_cls.remote(task_ref)
            except RayTaskError as exc:
                row = error_row(exc.cause if isinstance(exc.cause, BaseException) else exc)
            yield index, row
            while load[k] < 1 + QUEUE_PER_WORKER and submit(k):
                pass
    finally:
        if started:
            ray.shutdown()


class _Worker:
    """A Ray actor: one process that keeps the task and runs points with :func:`run_one`."""

    def __init__(self, task: Task) -> None:
        self.task = task

    def run(self, payload: Any) -> dict[str, Any]:
        return run_one(self.task, payload)
