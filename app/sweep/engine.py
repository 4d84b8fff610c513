"""The engine that runs independent points: serially in this process, or on Ray.

A *task* is a picklable callable ``task(payload) -> dict`` (a row of results); a *point* is
``(index, payload)``. :func:`run_points` yields ``(index, row)`` as points finish, in any order.
A point that raises (a :class:`~app.errors.ConfigError` from a value out of range, a fault
turned exception, any bug) becomes a row with ``status = "error"`` and the one-line ``error``;
the other points go on. A worker process that dies (a crash, ``os._exit``, the OOM killer) is
replaced, and every point lost with it (the one it was running and those queued behind it) is
run again *alone*: on a worker that has loaded the task, with nothing queued behind it. A point
that kills a worker while it runs alone there is charged with the death; one that does so twice
(:data:`MAX_KILLS`) becomes a row with ``status = "error"`` and ``error = "worker died ..."``.
Which of several points on a dead worker was running cannot be told from Ray's replies: the
reply of a point that returned just before the next one killed the process can be lost with it,
and a worker can die while it starts (on a loaded machine) with points queued on it; charging
the first point that did not come back made an innocent point a "worker died" row. A worker that
dies while it loads the task is replaced and charges nobody.

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

import os
import signal
import socket
import threading
import traceback
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager, nullcontext, suppress
from dataclasses import dataclass
from types import TracebackType
from typing import Any

from app.errors import EngineError, FrhcError
from app.sweep.probe import UNAUTHENTICATED, call_grpc, ray_authorization

Task = Callable[[Any], dict[str, Any]]
Point = tuple[int, Any]

#: Points queued per worker beyond the one it runs: hides the round trip without hoarding work.
QUEUE_PER_WORKER = 1
#: Times a point may be running alone when its worker dies before it is reported as failed.
MAX_KILLS = 2
#: Times a point may be lost with a dead worker in all (alone or not) before it is reported.
MAX_LOSSES = 4
#: Workers of one slot that may die in a row while they load the task before the run stops.
MAX_START_DEATHS = 4


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
#: Seconds without a finished point after which the engine checks that the cluster's GCS still
#: accepts a TCP connection (s). Ray's own driver gives a lost GCS 60 s, then ends the process
#: from C++ with nothing flushed (measured: a head killed mid-experiment lost 3 of 16 finished runs
#: and printed no line of ours).
HEAD_CHECK = 5.0
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

    The address must answer as a gRPC server within :data:`CONNECT_TIMEOUT` first, and take the
    token Ray would send (:func:`~app.sweep.probe.call_grpc`), so a wrong one (nothing there, a web
    server, an HTTP/2 proxy, a stopped head, a head that refuses the token) fails at once instead
    of after Ray's retries (~20 s to minutes, a warning line a second). A head on a loopback address is joined on loopback (:func:`loopback_ray`; Ray would look for it on the routable address).

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
        if not host or not port.isdigit() or "/" in host:  # another scheme, or a path
            raise EngineError(f"{where}: not a Ray cluster address (host:port of its head, or 'auto')")
        try:
            answer = call_grpc(host.strip("[]"), int(port), CONNECT_TIMEOUT, ray_authorization())
        except OSError as exc:
            reason = exc.strerror or str(exc) or type(exc).__name__
            raise EngineError(
                f"{where}: no Ray cluster answers there ({reason}); start one with 'ray start --head' (sweeps/README.md)"
            ) from None
        if answer is None:
            # Ray would retry for minutes, printing a warning every second, before giving up.
            raise EngineError(
                f"{where}: something listens there, but it is not a Ray cluster's head (it does not "
                f"answer a gRPC call within {CONNECT_TIMEOUT:g} s); start one with 'ray start --head' (sweeps/README.md)"
            )
        if answer.status == UNAUTHENTICATED:  # Ray would retry for ~20 s, a warning a second
            raise EngineError(_refused_token(where))
        loopback = host.startswith("127.") or host in LOOPBACK_HOSTS
    try:
        with loopback_ray() if loopback else nullcontext(), python_signal_handlers():
            ray.init(address=address, log_to_driver=False, configure_logging=False)
    except Exception as exc:
        causes = _causes(exc)
        # Ray's connection loop keeps only the text of its last error (a formatted traceback).
        last = str(causes[-1]).strip().splitlines() or [type(causes[-1]).__name__]
        if any(isinstance(c, AuthenticationError) for c in causes) or "AuthenticationError" in last[-1]:
            raise EngineError(_refused_token(where)) from None
        reason = " ".join(
            (last[-1] if "Traceback (most recent call last)" in str(causes[-1]) else " ".join(last)).split()
        )
        raise EngineError(f"{where}: cannot join the Ray cluster: {reason[:300]}") from None


def _refused_token(where: str) -> str:
    return (
        f"{where}: the Ray cluster refused this process's token; a cluster with token authentication"
        " is joined with RAY_AUTH_MODE=token and its token in RAY_AUTH_TOKEN or RAY_AUTH_TOKEN_PATH"
        " (sweeps/README.md)"
    )


def _host_port(address: str) -> tuple[str, str]:
    """A cluster address's host (resolved, so ``localhost`` is ``127.0.0.1``) and port."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    host = host.strip("[]")
    with suppress(OSError):  # a name that does not resolve is compared as written
        host = socket.gethostbyname(host)
    return host, port


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
    """A point submitted to worker slot ``k`` during that slot's ``life`` (-th worker); ``alone``:
    as a suspect, on a worker that had loaded the task, with nothing queued behind it."""

    index: int
    payload: Any
    k: int = 0
    life: int = 0
    alone: bool = False
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
        # Per worker slot, the reference of its current worker's ``use`` call of this run (its
        # load of the task): a suspect point runs only on a worker whose load has come back.
        self._loads: list[Any] = []
        # The cluster's GCS stopped answering mid-run: Ray calls that need it would block.
        self._head_lost = False

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
        elif self.address not in (None, "auto"):
            # Ray joins one cluster a process: the address asked for must be the one joined.
            joined = ray.get_runtime_context().gcs_address
            if _host_port(joined) != _host_port(self.address):
                raise EngineError(
                    f"{self._source} {self.address}: this process has already joined the Ray cluster at "
                    f"{joined}, and Ray joins one cluster a process (ray.shutdown() first)"
                )
        n = self._workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        self._worker_cls = ray.remote(num_cpus=1)(_Worker)
        self._actors = [self._worker_cls.remote() for _ in range(n)]
        self._lives = [0] * n

    def close(self) -> None:
        """End the workers, and Ray if this engine started it."""
        if self.serial:
            return
        import ray

        if not self._head_lost:
            for actor in self._actors:
                ray.kill(actor)
        self._actors = []
        if self._started and not self._head_lost:
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

        gcs = ray.get_runtime_context().gcs_address
        task_ref = ray.put(task)
        self._loads = [actor.use.remote(task_ref) for actor in self._actors]
        n = len(self._actors)
        loaded = [False] * n  # the slot's worker has loaded the task
        start_deaths = [0] * n  # its workers that died loading, in a row
        pending: dict[Any, _Job] = {}
        load = [0] * n
        alone = [False] * n  # the slot runs a suspect
        queue = iter(points)
        more = True  # the queue may hold points yet
        suspects: deque[_Job] = deque()  # points lost with a dead worker, to run alone

        def replace(k: int) -> None:
            self._actors[k] = self._worker_cls.remote()
            self._loads[k] = self._actors[k].use.remote(task_ref)
            self._lives[k] += 1
            loaded[k] = False

        def submit(k: int, job: _Job) -> None:
            job.k, job.life = k, self._lives[k]
            pending[self._actors[k].run.remote(job.payload)] = job
            load[k] += 1

        def fill() -> None:
            nonlocal more
            # Only a worker that has loaded the task takes points: one the cluster cannot place
            # (more workers asked for than it has free CPUs) would hold its points for ever.
            for k in range(n):
                if alone[k] or not loaded[k]:
                    continue
                if suspects and load[k] == 0:
                    job = suspects.popleft()
                    job.alone = alone[k] = True
                    submit(k, job)
                    continue
                # While suspects wait, queue nothing behind a running point: the slot comes free.
                while load[k] < (1 if suspects else 1 + QUEUE_PER_WORKER):
                    nxt = next(queue, None)
                    if nxt is None:
                        more = False
                        break
                    submit(k, _Job(*nxt))

        def lost(job: _Job, was_alone: bool, exc: BaseException) -> dict[str, Any] | None:
            """``job``'s worker died (``was_alone``: running it alone): replace the worker; None to
            run the job again alone, else its error row."""
            if self._lives[job.k] == job.life:
                replace(job.k)
            job.losses += 1
            job.kills += was_alone
            if job.kills < MAX_KILLS and job.losses < MAX_LOSSES:
                return None
            return {"status": "error", "error": f"worker died running this point: {' '.join(str(exc).split())[:300]}"}

        fill()
        while pending or suspects or more:
            loads = {self._loads[k]: k for k in range(n) if not loaded[k]}
            done, _ = ray.wait([*pending, *loads], num_returns=1, timeout=HEAD_CHECK)
            if not done:
                self._check_head(gcs)
                continue
            if done[0] in loads:
                k = loads[done[0]]
                try:
                    ray.get(done[0])
                    loaded[k], start_deaths[k] = True, 0
                except RayActorError as exc:
                    start_deaths[k] += 1
                    if start_deaths[k] >= MAX_START_DEATHS:
                        raise EngineError(
                            f"{MAX_START_DEATHS} workers in a row died while loading the task: {' '.join(str(exc).split())[:300]}"
                        ) from None
                    replace(k)  # the points queued on it come back lost, charged nothing
                fill()
                continue
            job = pending.pop(done[0])
            load[job.k] -= 1
            was_alone, job.alone = job.alone, False
            if was_alone:
                alone[job.k] = False
            try:
                yield job.index, ray.get(done[0])
            except RayActorError as exc:
                row = lost(job, was_alone, exc)
                if row is None:
                    suspects.append(job)
                else:
                    yield job.index, row
            except RayTaskError as exc:
                yield job.index, error_row(exc.cause if isinstance(exc.cause, BaseException) else exc)
            fill()

    def _check_head(self, gcs: str) -> None:
        """Raise :class:`~app.errors.EngineError` if the cluster's GCS at ``gcs`` (``host:port``)
        refuses a TCP connection (its head is gone), so the rows finished so far are written and
        the command ends in one line instead of Ray ending it a minute later."""
        host, port = _host_port(gcs)
        try:
            socket.create_connection((host, int(port)), CONNECT_TIMEOUT).close()
        except OSError as exc:
            self._head_lost = True
            reason = exc.strerror or str(exc) or type(exc).__name__
            raise EngineError(
                f"the Ray cluster's head at {gcs} stopped answering mid-run ({reason}): the points "
                "finished so far are kept and the same command resumes them once a cluster answers"
            ) from None


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
