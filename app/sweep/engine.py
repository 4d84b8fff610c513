"""The engine that runs independent points: serially in this process, or on Ray.

A *task* is a picklable callable ``task(payload) -> dict`` (a row of results); a *point* is
``(index, payload)``. :func:`run_points` yields ``(index, row)`` as points finish, in any order.
A point that raises (a :class:`~app.errors.ConfigError` from a value out of range, a fault
turned exception, any bug) becomes a row with ``status = "error"`` and the one-line ``error``;
the other points go on. A worker process that dies (a crash, ``os._exit``, the OOM killer) is
replaced: the points queued behind the one it was running are run again elsewhere, the point it
was running is tried once more (the death may not be its fault) and, if it kills a worker
again, becomes a row with ``status = "error"`` and ``error = "worker died ..."``. A worker that
dies before it runs any point (while it starts or loads the task, as on a loaded machine) charges
no point with its death; every point lost with a worker counts towards :data:`MAX_LOSSES`.

Ray (https://docs.ray.io) rather than ``multiprocessing`` because the same code then runs on a
cluster: with ``address`` (or ``RAY_ADDRESS``) it joins an existing Ray cluster, whose nodes must
have this package and its data files installed at the same version; this machine must be one of
its nodes (``ray start --address``), or the head itself. Locally it starts a private Ray instance
with ``workers`` CPUs and no dashboard. ``workers = 1`` runs in this process without Ray.

Network: a local instance, and the driver that joins a head on a loopback address, listen on
127.0.0.1 only (:func:`loopback_ray`). Ray 2.60 turns token authentication on for the clusters it
starts (the token in ``~/.ray/auth_token``, made if missing); joining such a cluster needs
``RAY_AUTH_MODE=token`` and its token (``RAY_AUTH_TOKEN`` or ``RAY_AUTH_TOKEN_PATH``): a refused
token, an unreachable address or a machine that is no node of the cluster is one
:class:`~app.errors.EngineError` line (``sweeps/README.md`` says how to join).

Where the time goes on Ray (``frhc bench sweep`` measures it): starting a local Ray instance
(~10 s on a loaded 2-core machine), then each worker's first point, which imports the package
(~4 s) and loads the numba cache; after that a point costs one remote call of ~1 ms, hidden by
queueing one point ahead on each worker. So an :class:`Engine` keeps its worker processes (an
actor each) for its whole life and gives them each task once: several runs in one ``with``
block (a warm-up and a timed run, the rounds of a search) pay the start-up once.
"""

from __future__ import annotations

import itertools
import os
import signal
import socket
import threading
import traceback
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from types import TracebackType
from typing import Any

from app.errors import EngineError, FrhcError

Task = Callable[[Any], dict[str, Any]]
Point = tuple[int, Any]

#: Points queued per worker beyond the one it runs: hides the round trip without hoarding work.
QUEUE_PER_WORKER = 1
#: Times a point may be running when its worker dies before it is reported as failed.
MAX_KILLS = 2
#: Times a point may be lost with a dead worker in all (running or queued) before it is reported.
MAX_LOSSES = 4


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


#: Ray's switch for multi-node clusters: "0" keeps a node's address on loopback (:func:`loopback_ray`).
RAY_CLUSTER_SWITCH = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
#: Seconds a cluster's address has to accept a TCP connection before Ray is asked to join it (s).
CONNECT_TIMEOUT = 5.0
#: Host names of the loopback interface (a head there is joined on loopback).
LOOPBACK_HOSTS = ("localhost", "::1", "[::1]")


@contextmanager
def loopback_ray() -> Iterator[None]:
    """Ray started or joined inside listens on 127.0.0.1 only.

    Ray binds its gRPC servers (GCS, raylet, each worker's) to loopback only when the node's
    address is 127.0.0.1, and it replaces a loopback address by the machine's routable one (so
    ``_node_ip_address="127.0.0.1"`` alone binds every interface) unless multi-node clusters are
    switched off, ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` (Ray's default on Windows and macOS).
    The switch is set in the environment, which the processes Ray starts from here inherit, and
    in this process's copy of it, read when ``ray`` was imported; both are put back on exit.
    """
    import ray._private.ray_constants as ray_constants

    was_env, was_flag = os.environ.get(RAY_CLUSTER_SWITCH), ray_constants.ENABLE_RAY_CLUSTER
    os.environ[RAY_CLUSTER_SWITCH] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = was_flag
        if was_env is None:
            del os.environ[RAY_CLUSTER_SWITCH]
        else:
            os.environ[RAY_CLUSTER_SWITCH] = was_env


@contextmanager
def python_signal_handlers() -> Iterator[None]:
    """Put back this process's SIGINT and SIGTERM handlers on exit (main thread only).

    ``ray.init`` starts a core worker in this process whose failure handler (C++) replaces
    SIGTERM's, logging the signal and aborting: the command would end without unwinding, so
    without ending the Ray processes it started or writing the rows it holds. The command line
    turns SIGTERM into an :class:`~app.errors.Interrupted` (:mod:`app.cli`).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in handlers.items():
            if handler is not None:
                signal.signal(s, handler)


def init_local_ray(cpus: int) -> None:
    """Start a private local Ray instance of ``cpus`` CPUs (no dashboard, quiet, on loopback).

    ``address="local"``: a new instance even when another one's address is recorded on this
    machine (``ray start`` leaves it in ``/tmp/ray/ray_current_cluster``, which a bare
    ``ray.init()`` would join).

    Ray runs its worker processes at nice +15 by default, so that they yield to everything else
    on the machine: on a machine shared with other work that starves the sweep (its workers got
    a tenth of a core each, against a whole one for the same session run serially). Sweep workers
    do the work the user asked for, at the priority of the command that asked (nice 0 here).
    """
    import ray

    with loopback_ray(), python_signal_handlers():
        ray.init(
            address="local",
            num_cpus=cpus,
            include_dashboard=False,
            log_to_driver=False,
            configure_logging=False,
            _node_ip_address="127.0.0.1",
            _system_config={"worker_niceness": 0},
        )


def join_ray(address: str, source: str = "--address") -> None:
    """Join the Ray cluster at ``address`` (its GCS ``host:port``, ``"auto"`` or ``ray://host:port``).

    The address must accept a TCP connection within :data:`CONNECT_TIMEOUT` first, so a wrong
    one fails at once instead of after Ray's retries (~20 s). A head on a loopback address is
    joined on loopback (:func:`loopback_ray`; Ray would look for it on the routable address).

    Args:
        source: Where the address came from (``--address`` or ``RAY_ADDRESS``), named in errors.

    Raises:
        EngineError: one line naming ``source``: nothing answers at the address, the cluster
            refused this process's token, or Ray could not join for another reason.
    """
    import ray
    from ray.exceptions import AuthenticationError

    where = f"{source} {address}"
    loopback = False
    if address != "auto":
        host, _, port = address.removeprefix("ray://").rpartition(":")
        if not host or not port.isdigit():
            raise EngineError(f"{where}: not a Ray cluster address (host:port of its head, or 'auto')")
        try:
            socket.create_connection((host.strip("[]"), int(port)), CONNECT_TIMEOUT).close()
        except OSError as exc:
            reason = exc.strerror or str(exc) or type(exc).__name__
            raise EngineError(
                f"{where}: no Ray cluster answers there ({reason}); start one with 'ray start --head' (sweeps/README.md)"
            ) from None
        loopback = host.startswith("127.") or host in LOOPBACK_HOSTS
    try:
        with loopback_ray() if loopback else nullcontext(), python_signal_handlers():
            ray.init(address=address, log_to_driver=False, configure_logging=False)
    except Exception as exc:
        causes = _causes(exc)
        # Ray's connection loop keeps only the text of its last error (a formatted traceback).
        last = str(causes[-1]).strip().splitlines() or [type(causes[-1]).__name__]
        if any(isinstance(c, AuthenticationError) for c in causes) or "AuthenticationError" in last[-1]:
            raise EngineError(
                f"{where}: the Ray cluster refused this process's token; a cluster with token"
                " authentication is joined with RAY_AUTH_MODE=token and its token in RAY_AUTH_TOKEN"
                " or RAY_AUTH_TOKEN_PATH (sweeps/README.md)"
            ) from None
        reason = " ".join(
            (last[-1] if "Traceback (most recent call last)" in str(causes[-1]) else " ".join(last)).split()
        )
        raise EngineError(f"{where}: cannot join the Ray cluster: {reason[:300]}") from None


def _causes(exc: BaseException) -> list[BaseException]:
    """``exc`` and the exceptions it was raised from, outermost first."""
    chain = [exc]
    while (nxt := chain[-1].__cause__ or chain[-1].__context__) is not None and nxt not in chain:
        chain.append(nxt)
    return chain


def run_points(task: Task, points: Iterable[Point], workers: int = 1, address: str | None = None) -> Iterator[Point]:
    """Run ``task`` on every point; yields ``(index, row)`` as each finishes.

    One :class:`Engine` for this run (see it for ``workers`` and ``address``).
    """
    with Engine(workers, address) as engine:
        yield from engine.run(task, points)


@dataclass
class _Job:
    """A point submitted to worker slot ``k`` during that slot's ``life`` (-th worker), ``seq``-th overall."""

    index: int
    payload: Any
    k: int
    life: int
    seq: int
    kills: int = 0
    losses: int = 0


class Engine:
    """Workers that run points, kept from ``__enter__`` to ``__exit__`` (a context manager).

    Args:
        workers: Parallel workers (1 = serially in this process, without Ray). With an
            ``address`` the default 0 means every CPU of the cluster.
        address: A Ray cluster to join (its head's ``"host:port"``, or ``"auto"``); None = the
            ``RAY_ADDRESS`` environment variable, else a private local instance (started here
            unless Ray is already initialised in this process, and shut down on exit).

    Raises:
        EngineError: on entry, when Ray cannot start or the cluster cannot be reached.
    """

    def __init__(self, workers: int = 1, address: str | None = None) -> None:
        self.address = address or os.environ.get("RAY_ADDRESS") or None
        self._source = "--address" if address else "RAY_ADDRESS"
        self.serial = workers == 1 and self.address is None
        self._workers = workers
        self._started = False
        self._actors: list[Any] = []
        self._lives: list[int] = []
        # Per worker slot, the reference of its current worker's ``use`` call of this run: an
        # actor runs its calls in order, so whether that one finished says whether the worker
        # started (loaded the task) before it died.
        self._loads: list[Any] = []

    @property
    def size(self) -> int:
        """Workers running points (1 when serial)."""
        return 1 if self.serial else len(self._actors)

    def __enter__(self) -> Engine:
        if not self.serial:
            self._start()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    def _start(self) -> None:
        import ray

        if not ray.is_initialized():
            if self.address is not None:
                join_ray(self.address, self._source)
            else:
                try:
                    init_local_ray(self._workers or os.cpu_count() or 1)
                except Exception as exc:
                    raise EngineError(f"cannot start a local Ray instance: {' '.join(str(exc).split())}") from None
            self._started = True
        n = self._workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        self._worker_cls = ray.remote(num_cpus=1)(_Worker)
        self._actors = [self._worker_cls.remote() for _ in range(n)]
        self._lives = [0] * n

    def close(self) -> None:
        """End the workers, and Ray if this engine started it."""
        if self.serial:
            return
        import ray

        for actor in self._actors:
            ray.kill(actor)
        self._actors = []
        if self._started:
            ray.shutdown()
            self._started = False

    def run(self, task: Task, points: Iterable[Point]) -> Iterator[Point]:
        """Run ``task`` on every point; yields ``(index, row)`` as each finishes (any order)."""
        if self.serial:
            for index, payload in points:
                yield index, run_one(task, payload)
            return
        yield from self._run_ray(task, points)

    def _run_ray(self, task: Task, points: Iterable[Point]) -> Iterator[Point]:
        import ray
        from ray.exceptions import RayActorError, RayTaskError

        task_ref = ray.put(task)
        self._loads = [actor.use.remote(task_ref) for actor in self._actors]
        n = len(self._actors)
        pending: dict[Any, _Job] = {}
        load = [0] * n
        queue = iter(points)
        again: deque[_Job] = deque()  # points of dead workers, run before new ones
        # (slot, life) of a dead worker -> seq of the point it was running (None: it ran none)
        culprit: dict[tuple[int, int], int | None] = {}
        seq = itertools.count()

        def submit(k: int) -> bool:
            if again:
                job = again.popleft()
            else:
                nxt = next(queue, None)
                if nxt is None:
                    return False
                job = _Job(nxt[0], nxt[1], k, 0, 0)
            job.k, job.life, job.seq = k, self._lives[k], next(seq)
            pending[self._actors[k].run.remote(job.payload)] = job
            load[k] += 1
            return True

        def fill() -> None:
            for k in range(n):
                while load[k] < 1 + QUEUE_PER_WORKER and submit(k):
                    pass

        fill()
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            job = pending.pop(done[0])
            load[job.k] -= 1
            try:
                yield job.index, ray.get(done[0])
            except RayActorError as exc:
                row = self._lost(job, exc, culprit, pending, task_ref)
                if row is None:
                    again.append(job)
                else:
                    yield job.index, row
            except RayTaskError as exc:
                yield job.index, error_row(exc.cause if isinstance(exc.cause, BaseException) else exc)
            fill()

    def _lost(
        self,
        job: _Job,
        exc: BaseException,
        culprit: dict[tuple[int, int], int | None],
        pending: dict[Any, _Job],
        task_ref: Any,
    ) -> dict[str, Any] | None:
        """``job``'s worker died: replace the worker; None to run the job again, else its error row."""
        life = (job.k, job.life)
        if life not in culprit:
            culprit[life] = self._running(job, life, pending)
        if self._lives[job.k] == job.life:
            self._actors[job.k] = self._worker_cls.remote()
            self._loads[job.k] = self._actors[job.k].use.remote(task_ref)
            self._lives[job.k] += 1
        job.losses += 1
        job.kills += job.seq == culprit[life]
        if job.kills < MAX_KILLS and job.losses < MAX_LOSSES:
            return None
        return {"status": "error", "error": f"worker died running this point: {' '.join(str(exc).split())[:300]}"}

    def _running(self, job: _Job, life: tuple[int, int], pending: dict[Any, _Job]) -> int | None:
        """The seq of the point the worker of ``life`` (slot, life) was running when it died, of
        ``job`` (lost with it) and the calls it still holds in ``pending``; None if it ran none.

        Every call on a dead actor settles at once (a result it returned, or its death), so they
        are waited for here. The actor ran its calls in order: ``use`` (its load, if it was this
        life's, :attr:`_loads`), then the points by seq. If the load died, no point ran; else the
        point running was the first one that did not return. Taking the first one still pending
        instead charged a point whose worker died while it started (on a loaded machine), or one
        that had returned but whose result was not yet taken.
        """
        import ray
        from ray.exceptions import RayActorError

        held = [ref for ref, j in pending.items() if (j.k, j.life) == life]
        load = self._loads[job.k] if self._lives[job.k] == job.life else None
        ray.wait([*held, *([load] if load is not None else [])], num_returns=len(held) + (load is not None))

        def died(ref: Any) -> bool:
            try:
                ray.get(ref)
            except RayActorError:
                return True
            except Exception:
                return False  # the call itself raised: it finished
            return False

        if load is not None and died(load):
            return None
        return min([job.seq, *(pending[ref].seq for ref in held if died(ref))])


class _Worker:
    """A Ray actor: one process that keeps the current task and runs points with :func:`run_one`."""

    def __init__(self) -> None:
        self.task: Task | None = None

    def use(self, task: Task) -> None:
        """Run ``task`` from now on (unpickling it imports its modules, once per worker)."""
        self.task = task

    def run(self, payload: Any) -> dict[str, Any]:
        assert self.task is not None, "use() is called before run()"
        return run_one(self.task, payload)
