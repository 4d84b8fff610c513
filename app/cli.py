"""The ``frhc`` command line: run sessions, the paper's experiment, benchmarks, checks, the web demo.

Every user error (a malformed scene, session or device file; an unknown name) is printed to
stderr as one line naming the file and field, with exit code 2 and no traceback. SIGINT (Ctrl-C)
and SIGTERM stop a command the same way: what it started is ended on the way out (a sweep's Ray
instance), what it kept is named in one line, and the exit code is 128 + the signal.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import re
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

from app.config import Range, field_range, fmt_number, repeated
from app.errors import ConfigError, FrhcError, InputError, Interrupted, InvalidField, OutputError
from app.interrupts import signals_held


@contextmanager
def _output_folder(folder: Path) -> Iterator[Path]:
    """Create ``folder`` and turn any OS error while the command works into one :class:`OutputError`.

    The one error path of every command that writes results: the folder is made first (a regular
    file in the way, a read-only file system or a too-long name fails here, before any work),
    and a disk that fills up later fails the same way. Entered after the input files are loaded,
    so a bad input file leaves no folder behind; a command refused later (a device that does not
    answer) removes the folders it made if they are still empty.
    """
    made: list[Path] = []
    try:
        made = [p for p in (folder, *folder.parents) if not p.exists()]  # the leaf first
        folder.mkdir(parents=True, exist_ok=True)
        yield folder
    except OSError as exc:
        raise OutputError(folder, exc) from None
    except FrhcError:
        for p in made:
            try:
                p.rmdir()
            except OSError:  # not empty: it holds what the command kept
                break
        raise


if TYPE_CHECKING:
    from app.device.hand import HandParams


def _cmd_run(args: argparse.Namespace) -> int:
    with signals_held():
        from app.session.run import run_session
        from app.session.spec import load_session, passivity_on_cartesian

        session = load_session(args.session)
    if args.rate is not None:
        session = session.with_changes(servo_rate=args.rate)
    if args.device is not None and session.data.passivity.enabled:
        raise passivity_on_cartesian(session.path or args.session, f"--device {args.device}")
    for notice in session.notices:
        print(f"warning: {notice}", file=sys.stderr)
    if args.device is not None:  # the device link's changes (connect, stall, loss) on stderr
        logging.basicConfig(level=logging.INFO, format="%(message)s")
        logging.getLogger("websockets").setLevel(logging.WARNING)
    out_dir: Path = args.out or Path("runs") / Path(args.session).stem
    with _output_folder(out_dir):
        try:
            result = run_session(
                session,
                out_dir=out_dir,
                plots=not args.no_plots,
                progress=True,
                realtime=args.realtime,
                flush_interval=args.flush_interval,
                device_url=args.device,
            )
        except KeyboardInterrupt as exc:
            # The log's writer has flushed on the way here: say what it holds.
            signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
            raise Interrupted(signum, _kept_log(out_dir)) from None
    s = result.summary
    print(f"log:      {result.log_dir}/ (Parquet)")
    print(f"summary:  {out_dir / 'summary.json'}")
    for p in result.plots:
        print(f"plot:     {p}")
    print(
        f"work (Eq 13): {s['work_eq13']:.3g} J   peak force: {s['peak_contact_force_N']:.2f} N   faults: {s['faults'] or 'none'}"
    )
    for room in ("slave", "device"):
        if s[f"{room}_fault"]:
            print(f"{room} fault: {s[f'{room}_fault']}")
    if s["device_link_ticks"]:
        link = ", ".join(f"{state.lower()} {n} ticks" for state, n in s["device_link_ticks"].items())
        print(f"device link: {link} (stalled and disconnected: no force sent)")
    tick = s["timing"]["tick"]
    print(
        f"tick: median {tick['median_us']:.1f} us, p99 {tick['p99_us']:.1f} us, real-time factor {s['real_time_factor']:.1f}"
    )
    for g in s["grips"]:
        print(f"grip {'close' if g['grip'] else 'open'} at {g['t']:.3f} s: {g['note']}")
    if "pacing" in s:
        pace = s["pacing"]
        print(
            f"pacing: {pace['rate_hz']:.1f} Hz, jitter p99 {pace['jitter_p99_us']:.0f} us, "
            f"max {pace['jitter_max_us']:.0f} us, slips {pace['slips']:.0f}, at {s['scheduling']}"
        )
    return 0


def _kept_log(out_dir: Path) -> str:
    """One line: how much of an interrupted run's log ``out_dir/log`` holds, and how to see it."""
    import pyarrow.parquet as pq

    log = out_dir / "log"
    try:
        t = pq.read_table(log, columns=["t"]).column("t")
    except (OSError, ValueError, KeyError):  # no log yet, or no part written
        return f"nothing logged yet; {out_dir} has no summary"
    if len(t) == 0:
        return f"nothing logged yet; {out_dir} has no summary"
    return f"the log of the first {t[-1].as_py():.3f} s is in {log}/ (no summary; frhc web --replay {out_dir} shows it)"


def _bounded(cast: Callable[[str], float], lo: float, hi: float, unit: str = "") -> Callable[[str], Any]:
    """An argparse type: ``cast`` of the text, refused outside [lo, hi] (``unit`` in the message)."""

    def parse(text: str) -> Any:
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not {'an integer' if cast is int else 'a number'}: {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be between {fmt_number(lo)} and {fmt_number(hi)}{unit}, got {text}")
        return value

    return parse


_positive_seconds = _bounded(float, 1e-3, 3600.0, " s")
_count = _bounded(int, 0, 10_000_000)


def _cmd_experiment(args: argparse.Namespace) -> int:
    with signals_held():
        from app.study.experiment import run_experiment
        from app.world.scene_file import check_slave_kind

    if args.slave is not None:
        try:
            check_slave_kind(args.slave, "--slave")
        except InvalidField as exc:
            raise ConfigError("frhc experiment", exc.field, exc.reason) from None
    with _output_folder(args.out) as out_dir:
        report = run_experiment(
            out_dir,
            n_operators=args.operators,
            seed=args.seed,
            time_limit=args.time_limit,
            workers=args.workers,
            address=args.address,
            progress=True,
            slave=args.slave,
        )
    print(report.table)
    print(f"\nchart: {report.chart}\nresults: {report.results}\nsummary: {report.json_path}")
    return 0


#: Failed sweep points printed with their error (the rest are counted; all are in the table).
MAX_FAILED_SHOWN = 10


def _cmd_sweep(args: argparse.Namespace) -> int:
    with signals_held():
        from app.sweep import load_sweep, run_sweep

        plan = load_sweep(args.file)
    out_dir: Path = args.out or Path("runs") / "sweeps" / Path(args.file).stem
    with _output_folder(out_dir):
        report = run_sweep(plan, out_dir, args.workers, args.address, args.metric, progress=True)
    print(
        f"results:  {report.results} ({report.table.num_rows} points: {report.ran} run now, {report.skipped} resumed)"
    )
    print(f"failed:   {report.failed}" + (" (see the 'error' column)" if report.failed else ""))
    failed = [row for row in report.table.to_pylist() if row["status"] != "ok"]
    for row in failed[:MAX_FAILED_SHOWN]:
        values = ", ".join(f"{f}={row[f]:g}" if isinstance(row[f], float) else f"{f}={row[f]}" for f in plan.fields)
        print(f"  point {row['point']} ({values}): {row['error']}")
    if len(failed) > MAX_FAILED_SHOWN:
        print(f"  ... and {len(failed) - MAX_FAILED_SHOWN} more")
    if report.plot is not None:
        print(f"plot:     {report.plot}")
    return 0


def _engine_arguments(p: argparse.ArgumentParser) -> None:
    """``--workers`` and ``--address`` of the point engine (sweeps, the experiment, zwidth)."""
    p.add_argument(
        "--workers",
        type=_count,
        default=os.cpu_count() or 1,
        help="parallel workers (default: every core; 1 = serially without Ray; 0 = every CPU of a cluster)",
    )
    p.add_argument("--address", default=None, help="join this Ray cluster (default: RAY_ADDRESS, else local)")


def _cmd_device_serve(args: argparse.Namespace) -> int:
    with signals_held():
        from app.device.cartesian_sim import SimCartesianDevice
        from app.device.haply import DeviceServer
        from app.device.spec import load_device
        from app.listen import url_authority
        from app.session.pacer import SCHEDULING, raise_priority

        spec = load_device(args.device)
    if not 10.0 <= args.rate <= 20000.0:
        raise FrhcError(f"--rate must be in [10, 20000] Hz, got {args.rate:g}")
    if spec.data.cartesian is None:
        raise ConfigError(spec.path, "cartesian", "serving a device needs its [cartesian] table (force limit)")
    server = DeviceServer(SimCartesianDevice(spec), args.host, args.port, period=1.0 / args.rate)
    # The served simulation stands for a device's own processor: it keeps its period whatever else runs.
    scheduling = SCHEDULING[raise_priority()]
    print(
        f"serving {spec.name} (simulated, {args.rate:g} Hz) at ws://{url_authority(args.host, server.port)} ({scheduling})  "
        "(Ctrl-C stops)",
        flush=True,
    )
    logging.basicConfig(level=logging.INFO, format="%(message)s")  # connects and force zeroing
    logging.getLogger("websockets").setLevel(logging.WARNING)
    try:
        server.serve_forever()
    finally:
        server.shutdown()
    return 0


def _device_url(text: str) -> str:
    """An argparse type: a device outside this process (ws://host:port, fd:N, openhaptics:NAME)."""
    from app.device.vendors import check_device_url

    try:
        return check_device_url(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _cmd_bench(args: argparse.Namespace) -> int:
    with signals_held():
        from app import bench

    print(bench.run(args.what, quick=args.quick, window=args.window))
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    with signals_held():
        from app.check import check_file

    failed = 0
    for name in args.files:  # every file, each said in its own line (ok, or the first error in it)
        try:
            print(f"ok: {check_file(name)}")
        except FrhcError as exc:
            print(f"error: {exc}", file=sys.stderr)
            failed += 1
    return 2 if failed else 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    with signals_held():
        from app.device.calibrate import calibrate

    print(calibrate(args.device, write=args.write))
    return 0


def _cmd_web(args: argparse.Namespace) -> int:
    with signals_held():
        from app.web.launch import serve

    serve(
        args.scene,
        args.device,
        host=args.host,
        port=args.port,
        session=args.session,
        insecure=args.insecure,
        replay=args.replay,
        servo_rate=args.rate,
        spin=args.spin,
    )
    return 0


def _cmd_zwidth(args: argparse.Namespace) -> int:
    with signals_held():
        from app.session.stability import device_bound, passivity_bound
        from app.study.zwidth import TABLE_HEADER, zwidth

    device_only = device_bound(args.device, args.rate)
    if args.hand is None:
        print(f"hand released after the first push: bound 2b/T {device_only:,.0f} N/m (the device only)")
    else:
        with_hand = passivity_bound(args.device, args.rate, args.hand)
        print(f"bound 2b/T with the hand {with_hand:,.0f} N/m, device only {device_only:,.0f} N/m")
    with _output_folder(args.out) as out:
        edges = zwidth(
            out,
            renderers=tuple(args.renderers),
            dampings=tuple(args.dampings),
            device=args.device,
            servo_rate=args.rate,
            delay_ms=args.delay_ms,
            iterations=args.iterations,
            progress=True,
            workers=args.workers,
            address=args.address,
            hand=args.hand,
        )
    print(TABLE_HEADER)
    for e in edges:
        print(e.line())
    print(f"table: {out / 'zwidth.parquet'}\nplot:  {out / 'zwidth.png'}")
    return 0


def _list_of(kind: Callable[[str], object]) -> Callable[[str], list[object]]:
    """An argparse type: comma-separated values of ``kind``, each once (a study's axis: a repeat
    would run and tabulate the same design twice)."""

    def parse(text: str) -> list[object]:
        try:
            values = [kind(v) for v in text.split(",") if v.strip()]
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        if not values:
            raise argparse.ArgumentTypeError(f"expected at least one value, got {text!r}")
        again = repeated(values)
        if again is not None:
            raise argparse.ArgumentTypeError(f"value {again[0] + 1} repeats an earlier one ({again[1]!r}) in {text!r}")
        return values

    return parse


def _renderer(text: str) -> str:
    from app.study.zwidth import RENDERERS

    if text not in RENDERERS:
        raise ValueError(f"unknown renderer {text!r} (known: {', '.join(RENDERERS)})")
    return text


def _hand(text: str) -> HandParams | None:
    """``--hand``: ``K,B`` (translational stiffness N/m, damping N s/m) or ``released``."""
    from app.device.hand import HandParams

    if text == "released":
        return None
    try:
        k, b = (float(v) for v in text.split(","))
        return HandParams(stiffness_trans=k, damping_trans=b)
    except (ValueError, InvalidField) as exc:
        raise argparse.ArgumentTypeError(f"expected K,B (N/m, N s/m) or 'released': {exc}") from None


def _schema_number(module: str, owner: str, name: str, what: str) -> Callable[[str], float]:
    """An argparse type: a number held to the range of field ``name`` of schema class ``owner``
    (in ``module``, imported when the argument is parsed), so an argument and a file's field
    accept the same values; ``what`` names the quantity in the message."""

    def parse(text: str) -> float:
        import importlib

        rule = field_range(getattr(importlib.import_module(module), owner), name)
        assert isinstance(rule, Range), f"{owner}.{name} has no range"
        try:
            value = float(text)
            rule.check(name, value)
        except InvalidField as exc:
            raise argparse.ArgumentTypeError(f"expected {what}: {exc}") from None
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}: not a number: {text!r}") from None
        return value

    return parse


_servo_rate = _schema_number("app.session.spec", "SessionFile", "servo_rate", "a servo rate in Hz")
_delay_ms = _schema_number("app.teleop.channel", "ChannelSettings", "delay_ms", "a one-way delay in ms")


#: What ``frhc web`` and ``frhc device serve`` do with a busy port (:class:`~app.errors.ListenError`).
PORT_RULE = "a busy port is refused, not swapped for another (0: any free port, printed)"


def _port(text: str) -> int:
    """A TCP port to listen on (0: any free one)."""
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"expected a TCP port from 0 to 65535, got {text!r}")
    return port


def _host(text: str) -> str:
    """An address to listen on: a name or an IP address this machine can resolve."""
    import socket

    try:
        socket.getaddrinfo(text, None)
    except (OSError, UnicodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise argparse.ArgumentTypeError(f"cannot resolve {text!r}: {reason}") from None
    return text


def _name(text: str) -> str:
    """A file given by name or path (a session, sweep, scene, device or log): an empty one named the
    working folder, and each command then said something else of it ('.: is a directory')."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a name or a path, got an empty one")
    return text


def _out_dir(text: str) -> Path:
    """An output folder (``--out``); an empty name would write into the working folder."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a folder name, got an empty one")
    return Path(text)


def _spin_share(text: str) -> float:
    """``--spin``: a share of the servo period, 0 to :data:`~app.session.pacer.MAX_SPIN`."""
    from app.session.pacer import MAX_SPIN

    try:
        share = float(text)
    except ValueError:
        share = math.nan
    if not 0.0 <= share <= MAX_SPIN:
        raise argparse.ArgumentTypeError(f"expected a share of the period from 0 to {MAX_SPIN}, got {text!r}")
    return share


def _damping(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1e3:
        raise ValueError(f"damping must be in [0, 1000] N s/m, got {text}")
    return value


class _Parser(argparse.ArgumentParser):
    """argparse's parser, taking every argument that starts with ``-`` and a digit (or ``-.`` and a
    digit) as a value, not an option: ``--hand -1,5``, ``--dampings -1,4`` and ``--rate -1e3`` reach
    the option's own check as ``--hand=-1,5`` does. argparse's own test (a negative int or
    decimal only) called them unknown options ("expected one argument"). No frhc option is a
    dash and a digit; its subcommands' parsers are of this class too (``add_subparsers``
    makes them of the parent's)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-\.?\d")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="frhc",
        description="Cartesian control of force-reflecting hand controllers (Williams 1997): "
        "a haptic virtual environment with a simulated FRHC.",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("run", help="run a headless scripted session", description="Run a session file headless.")
    p.add_argument("session", type=_name, help="session name in sessions/ or a path to a session .toml")
    p.add_argument("--out", type=_out_dir, help="output directory (default runs/<session>)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--realtime", action="store_true", help="pace ticks to the wall clock")
    p.add_argument(
        "--flush-interval",
        type=_positive_seconds,
        default=0.1,
        help="simulated seconds of ticks per write to the log (its tail): the most a crash can lose (default 0.1)",
    )
    p.add_argument(
        "--device",
        type=_device_url,
        default=None,
        help="drive a device outside this process: ws://host:port (frhc device serve, Haply's Inverse "
        "Service), fd:N (Force Dimension), openhaptics:NAME (Touch); the session's device file gives its limits "
        "if it is Cartesian, else inverse3's, omega3's or touch3's",
    )
    p.add_argument(
        "--rate",
        type=_servo_rate,
        default=None,
        help="servo rate (Hz) instead of the session's (e.g. 1000, 2000, 4000)",
    )
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser(
        "experiment",
        help="the paper's Table I experiment",
        description="Dual peg-in-the-holes for several simulated operators, FRHC/NTRFC vs blind (paper Sec 4.3).",
    )
    p.add_argument(
        "--out", type=_out_dir, default="runs/experiment", help="output directory; re-running into it resumes"
    )
    p.add_argument(
        "--operators",
        type=_bounded(int, 1, 10_000_000),
        default=100,
        help="operators drawn from the population (default 100)",
    )
    p.add_argument("--seed", type=_count, default=0, help="seed of the population (default 0)")
    p.add_argument(
        "--time-limit",
        type=_positive_seconds,
        default=12.0,
        help="simulated seconds a run may take before it counts as failed (default 12)",
    )
    _engine_arguments(p)
    p.add_argument("--slave", default=None, help="tool or an arm in slaves/ (default: the scene's)")
    p.set_defaults(func=_cmd_experiment)

    p = sub.add_parser(
        "sweep",
        help="run a sweep of sessions (Ray)",
        description="Run every point of a sweep file (sweeps/README.md) as a headless session; "
        "results to Parquet, resumable, with a plot.",
    )
    p.add_argument("file", type=_name, help="sweep name in sweeps/ or a path to a sweep .toml")
    p.add_argument(
        "--out", type=_out_dir, help="output directory (default runs/sweeps/<file>); re-running into it resumes"
    )
    _engine_arguments(p)
    p.add_argument("--metric", default=None, help="metric to plot (default: the sweep file's metric)")
    p.set_defaults(func=_cmd_sweep)

    p = sub.add_parser("bench", help="benchmarks (median and p99)", description="Print timing benchmarks.")
    p.add_argument(
        "what",
        nargs="?",
        default="all",
        choices=["all", "controller", "plant", "contact", "tick", "arm", "stability", "sweep", "device", "moving"],
        help="what to time",
    )
    p.add_argument("--quick", action="store_true", help="fewer iterations")
    p.add_argument(
        "--window",
        type=_positive_seconds,
        default=None,
        help="stability: how long (s) each pose-mode wall's force is judged while the hand holds it "
        "(default 0.6, the settling window; the bar of issue 26: 8)",
    )
    p.set_defaults(func=_cmd_bench)

    p = sub.add_parser(
        "check", help="check scene/device/session/sweep files", description="Load and check files without running."
    )
    p.add_argument("files", nargs="+", type=_name, help="scene, device or session .toml files (or names)")
    p.set_defaults(func=_cmd_check)

    p = sub.add_parser(
        "calibrate",
        help="calibrate torque curves (Sec 4.2)",
        description="Sweep motor counts on the simulated device and fit 5th-order curves.",
    )
    p.add_argument("device", type=_name, help="device name or path")
    p.add_argument("--write", action="store_true", help="write the fitted curves into the device folder")
    p.set_defaults(func=_cmd_calibrate)

    p = sub.add_parser("device", help="serve a simulated device", description="Device tools.")
    dsub = p.add_subparsers(dest="device_command", required=True)
    p = dsub.add_parser(
        "serve",
        help="serve a simulated device over Haply's Inverse Service protocol (WebSocket)",
        description="Serve a simulated device as a Cartesian device (grip pose out, force in) over the "
        "Inverse Service JSON protocol, for frhc run/web --device ws://host:port (app/device/haply.py).",
    )
    p.add_argument(
        "--device", type=_name, default="kraft", help="device name or path with a [cartesian] table (default: kraft)"
    )
    p.add_argument("--host", type=_host, default="127.0.0.1", help="bind address (default 127.0.0.1)")
    p.add_argument("--port", type=_port, default=10001, help=f"port (default 10001, as Haply's service); {PORT_RULE}")
    p.add_argument("--rate", type=float, default=1000.0, help="simulation rate (Hz, default 1000)")
    p.set_defaults(func=_cmd_device_serve)

    p = sub.add_parser("web", help="the browser demo (viser)", description="Serve the haptic demo in the browser.")
    p.add_argument("--scene", type=_name, default="probe", help="scene name or path (default: probe)")
    p.add_argument(
        "--device",
        type=_name,
        default="kraft",
        help="device name or path (default: kraft), or a device outside this process: ws://host:port "
        "(frhc device serve, Haply's Inverse Service), fd:N, openhaptics:NAME (limits from the session's "
        "device file if it is Cartesian, else from inverse3, omega3 or touch3)",
    )
    p.add_argument("--session", type=_name, default=None, help="start with this session's gains and mode")
    p.add_argument(
        "--host",
        type=_host,
        default="127.0.0.1",
        help="bind address (default 127.0.0.1); any other needs the access token in the printed URL",
    )
    p.add_argument("--port", type=_port, default=8080, help=f"port (default 8080); {PORT_RULE}")
    p.add_argument("--insecure", action="store_true", help="serve a non-loopback --host without an access token")
    p.add_argument(
        "--replay", type=_name, metavar="LOG", help="start replaying a recorded log (runs/<name> or runs/<name>/log)"
    )
    p.add_argument(
        "--rate",
        type=_servo_rate,
        default=None,
        help="servo rate (Hz) of the loop and of every session played (e.g. 1000, 2000, 4000; default: the session's, else 1000)",
    )
    p.add_argument(
        "--spin",
        type=_spin_share,
        default=None,
        metavar="SHARE",
        help="spin the last SHARE (0-0.8) of each servo period instead of sleeping: the ticks run warmer, "
        "but the loop process keeps a CPU busy that share of the time (default: sleep, spin at most 0.3 ms)",
    )
    p.set_defaults(func=_cmd_web)

    p = sub.add_parser(
        "zwidth",
        help="the stable region of a design (largest stable felt stiffness per damping)",
        description="Z-width by bisection on the task-wrench gain, pose-mode probe presses (see app/study/zwidth.py).",
    )
    p.add_argument("--device", type=_name, default="kraft")
    p.add_argument("--rate", type=_servo_rate, default=1000.0, help="servo rate (Hz)")
    p.add_argument("--delay-ms", type=_delay_ms, default=0.0, help="one-way master-slave delay (ms)")
    p.add_argument("--renderers", type=_list_of(_renderer), default=["plain", "pc"], help="e.g. plain,pc,wave")
    p.add_argument("--dampings", type=_list_of(_damping), default=[0.0, 4.0, 16.0], help="K_D values (N s/m)")
    p.add_argument("--iterations", type=int, default=5, choices=range(1, 13), metavar="1..12", help="bisection steps")
    p.add_argument(
        "--hand",
        type=_hand,
        default="400,10",
        help="the hand: K,B (N/m, N s/m; default 400,10) or 'released' (lets go after the first push)",
    )
    p.add_argument("--out", type=_out_dir, default="runs/zwidth", help="output directory")
    _engine_arguments(p)
    p.set_defaults(func=_cmd_zwidth)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``frhc``; returns the exit code (2 for bad input)."""
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        # Each command imports what it needs with the signals held too (app.interrupts says why).
        with signals_held():
            args = build_parser().parse_args(argv)
        func: Callable[[argparse.Namespace], int] = args.func
        return func(args)
    except FrhcError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        if str(exc):
            print(f"interrupted: {exc}", file=sys.stderr)
        return 128 + (exc.signum if isinstance(exc, Interrupted) else signal.SIGINT)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _interrupt(signum: int, frame: FrameType | None) -> None:
    """SIGTERM: unwind like Ctrl-C (Python's default would end the process without cleaning up)."""
    raise Interrupted(signum)


if __name__ == "__main__":
    sys.exit(main())
