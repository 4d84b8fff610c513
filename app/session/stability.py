"""Contact stability of the whole loop: press the probe into a surface and watch the force settle.

Used by ``frhc bench stability`` (a stiffness sweep, compared with the passivity bound
``K < 2 b / T`` for a sampled-data virtual wall), by ``frhc zwidth`` (:mod:`app.study.zwidth`)
and by the tests (the shipped surfaces settle). Every press is an ordinary headless session
(:func:`press`), so a sweep engine can run the same points anywhere.

**Felt stiffness** (pose mode) is measured as the operator would: the hand holds one push, then
a deeper one, and the felt stiffness is the secant between the two plateaus, the change of the
force the motors rendered at the grip over the change of the grip's position, both along that
force (:class:`FeltStiffness`). A secant needs no contact point: the slave's lag at first touch,
its sag under the tool's weight and the grip's rebound all cancel. The grip position is the
simulation's true one, not the encoders': on these devices one count is ~0.1 mm at the grip, so
a wall stiffer than the push step over one count is felt (and measured) only to within a count.
"""

from __future__ import annotations

import math
import re
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from app.device.dissipation import grip_damping_matrix
from app.device.hand import HandParams
from app.device.spec import load_device
from app.session.metrics import SETTLE_MIN_FORCE, SETTLE_RIPPLE, SETTLE_WINDOW
from app.session.run import run_session
from app.session.spec import Session, SwitchEvent, Waypoint, load_session
from app.session.tick import TickObserver, TickRecord
from app.teleop.channel import ChannelSettings, Coupling
from app.world.scene import SCENES_DIR

#: A press's verdicts (:attr:`PressResult.verdict`).
VERDICTS = ("stable", "oscillating", "drifting", "saturated", "pushed")
#: Share of the judged window's ticks at the motors' limit from which a press pushed through to
#: the slave's limit lacked capacity: the motors spent most of the window saturated. Measured
#: (issue 26): a Kraft with twice the link weight under the default hand's push, 0.66-1.00 (the
#: PC's cut lets some ticks through); walls the PC let the hand push through, 0. Oscillations
#: that swing through the limit reach 0.4-0.8 too, which is why only a pushed press is split.
SATURATED_SHARE = 0.5
#: Grip travel (m) over the judged window beyond which the grip is not at rest (a reading, not
#: physical): about one encoder count at the grip on the shipped devices (~0.1 mm), the least
#: motion the device itself can see. Measured (issue 26's stability matrix, 1,872 presses, 0.6 s
#: windows; those settled, unsaturated and within the slave's limit): held presses 741 of 780
#: under 0.01 mm and 768 under 0.1 mm; released ones either rest (< 0.01 mm: 179 of 390) or
#: still creep or coast off the wall, spread from 0.01 mm to several cm (plain on the Kraft at 2x,
#: released: 3.7 mm since the release, 0.47 mm within the window).
DRIFT_TOLERANCE = 1e-4


@dataclass(frozen=True)
class PressResult:
    """How the contact force behaved while the operator held the tool pressed on the surface.

    Attributes:
        mean_force: Mean contact force magnitude over the settling window (N).
        ripple: Peak-to-peak contact force over that window (N).
        settled: ``ripple`` below 5 % of the mean (and finite), the mean at least 0.1 N
            (:data:`~app.session.metrics.SETTLE_MIN_FORCE`: in contact); for a released press,
            ``ripple`` below 5 % of the force the hand held before letting go (:func:`press`).
        felt_stiffness: Pose mode: the secant stiffness between the press's two plateaus (N/m,
            :class:`FeltStiffness`); NaN in rate mode, where the grip commands a velocity.
        saturated: Pose mode: the motors saturated on some tick of a plateau's window, so the
            wall was rendered as the motors' limit, a force source, not as a stiffness; for a
            released press, :func:`released_saturated` on the judged window.
        pushed_through: The mean contact force reached 95 % of the slave's force limit: the
            slave pushed as hard as it can, the wall the hand felt did not hold it back.
        summary: The whole session summary.
        saturated_share: Share of the judged window's ticks on which the uniform saturation
            (paper Sec 3.4) scaled the motors' torque below 1 (0..1).
        grip_drift: Pose mode: how far (m) the grip's true position moved along +z of the base
            {0} (out of the probe surface) over the judged window, the mean of its last tenth
            less the mean of its first (:class:`GripTravel`); NaN in rate mode.
        release_drift: Released press: how far (m) the grip moved along +z from the moment the
            hand let go to the end of the judged window; NaN otherwise.
    """

    mean_force: float
    ripple: float
    settled: bool
    felt_stiffness: float
    saturated: bool
    pushed_through: bool
    summary: dict[str, Any]
    saturated_share: float = 0.0
    grip_drift: float = math.nan
    release_drift: float = math.nan

    @property
    def drifting(self) -> bool:
        """The grip moved more than :data:`DRIFT_TOLERANCE` over the judged window: not at rest."""
        return abs(self.grip_drift) > DRIFT_TOLERANCE

    @property
    def stable(self) -> bool:
        """Settled, the grip at rest, the motors and the slave within their limits: a wall was rendered."""
        return self.settled and not self.drifting and not self.saturated and not self.pushed_through

    @property
    def verdict(self) -> str:
        """Why a press is or is not a stable wall, one of :data:`VERDICTS`.

        A press that pushed the slave through to its force limit, or whose grip went on into
        the surface over the judged window by more than :data:`DRIFT_TOLERANCE` under a settled
        contact force (the wall gave way; an oscillating grip's travel is its phase), is ``"saturated"`` when the motors were at their limit on at
        least :data:`SATURATED_SHARE` of the judged window's ticks: the uniform saturation (Sec
        3.4) scales the whole torque, gravity compensation included, so the device sags under
        the hand: it lacks the capacity for this push, a hardware limit, not a stability
        failure. Otherwise it is ``"pushed"``: the motors had the capacity and the rendered wall
        did not hold the hand back. A press within the slave's limit is ``"oscillating"`` when
        not settled, ``"drifting"`` when settled but the grip moved out of the surface by more
        than :data:`DRIFT_TOLERANCE`, or either way out of contact (a steady force, a grip not
        at rest: a released tool the rendering threw off the wall and that still coasts), ``"saturated"`` when settled with
        the motors saturated in a plateau's window (:attr:`saturated`: a force source, not a
        wall), else ``"stable"``.
        """
        pressed = self.settled and self.mean_force >= SETTLE_MIN_FORCE
        if self.pushed_through or (pressed and self.grip_drift < -DRIFT_TOLERANCE):
            return "saturated" if self.saturated_share >= SATURATED_SHARE else "pushed"
        if not self.settled:
            return "oscillating"
        if self.drifting:
            return "drifting"
        return "saturated" if self.saturated else "stable"


def released_saturated(mean_force: float, share: float) -> bool:
    """Whether a released press (the hand let go) rendered a force source rather than a resting tool.

    Only the judged window counts, the hand being gone. With the tool pressed on the surface
    (``mean_force`` (N) at least :data:`~app.session.metrics.SETTLE_MIN_FORCE`), a motor at its
    limit on any of the window's ticks (``share`` > 0, the share of its ticks the uniform
    saturation acted on) means the rendering pushed it as a force source, as for a held press.
    Resting at (near) zero force, off the wall or just touching it, there is no wall force for a
    saturated motor to have rendered: the motors then count only if they spent at least
    :data:`SATURATED_SHARE` of the window at their limit (the device being driven, not resting);
    a few saturated ticks of a settling bounce do not make a resting tool "saturated" (measured,
    issue 26: 75 of 480 released presses on the stability matrix rest at 0 N with a share of
    0-0.83, most below 0.02).
    """
    if mean_force >= SETTLE_MIN_FORCE:
        return share > 0.0
    return share >= SATURATED_SHARE


def probe_scene_with_stiffness(stiffness: float, damping: float, folder: Path) -> Path:
    """A copy of the probe scene with another surface stiffness (N/m) and damping (N s/m)."""
    text = (SCENES_DIR / "probe.toml").read_text()
    text = re.sub(r"(?m)^stiffness = .*$", f"stiffness = {stiffness!r}", text, count=1)
    text = re.sub(r"(?m)^damping = .*$", f"damping = {damping!r}", text, count=1)
    path = folder / f"probe_k{stiffness:g}.toml"
    path.write_text(text)
    return path


def grip_damping(device: str | Path, hand: HandParams | None = None) -> float:
    """Physical damping (N s/m) that resists the grip moving along z of the device base {0}.

    The z-z entry of the device's joint damping seen at the grip at the home pose
    (:func:`~app.device.dissipation.grip_damping_matrix`) plus the hand's translational damping:
    the ``b`` of the sampled-wall bound ``K < 2 b / T``. A device with an undamped joint has none
    of its own.
    """
    B = grip_damping_matrix(load_device(device))
    return (0.0 if B is None else float(B[2, 2])) + (hand or HandParams()).damping_trans


def passivity_bound(device: str | Path, servo_rate: float = 1000.0, hand: HandParams | None = None) -> float:
    """The sampled-data virtual-wall bound ``2 b / T`` (N/m) of Colgate & Brown (1994) for ``device``
    at ``servo_rate`` (Hz), with ``b`` from :func:`grip_damping`."""
    return 2.0 * grip_damping(device, hand) * servo_rate


#: The hand with no impedance at all: the grip let go (:func:`device_bound`, released presses).
RELEASED = HandParams(stiffness_trans=0.0, damping_trans=0.0, stiffness_rot=0.0, damping_rot=0.0)


def device_bound(device: str | Path, servo_rate: float = 1000.0) -> float:
    """The bound ``2 b / T`` (N/m) with the device's own damping only: the hand let go."""
    return passivity_bound(device, servo_rate, RELEASED)


#: Hands of the stability tools, ``(label, hand)``: the corners and middle of a human arm's
#: endpoint impedance. Stiffness 100-1000 N/m spans a relaxed to a stiffened arm (Mussa-Ivaldi,
#: Hogan & Bizzi 1985, J. Neurosci. 5(10): 300-900 N/m in the horizontal plane at rest); damping
#: 1-10 N s/m spans a fingertip grasp (Hajian & Howe 1997, J. Biomech. Eng. 119(1): ~1-4 N s/m)
#: to a whole-hand grip (the default hand, 10 N s/m). ``"released"`` is the hand let go.
HANDS: tuple[tuple[str, HandParams], ...] = (
    ("default 400/10", HandParams()),
    ("soft 100/1", HandParams(stiffness_trans=100.0, damping_trans=1.0)),
    ("soft 120/3", HandParams(stiffness_trans=120.0, damping_trans=3.0)),
    ("soft 100/10", HandParams(stiffness_trans=100.0, damping_trans=10.0)),
    ("stiff 1000/1", HandParams(stiffness_trans=1000.0, damping_trans=1.0)),
    ("stiff 1000/10", HandParams(stiffness_trans=1000.0, damping_trans=10.0)),
)


def design_stiffness(k_t: float, surface: float = 1e5, device: str | Path = "kraft") -> float:
    """The pose-mode wall stiffness (N/m) a press with task gain ``k_t`` renders at the grip:
    ``K_T K_P k_s``, with ``k_s`` the probe slave's tracking spring in series with a surface of
    stiffness ``surface`` (N/m) and ``K_P`` the device's translational pose gain along z."""
    session = load_session("probe_rate").with_changes(device=str(device))
    kp = session.scene.spec.slave.kp_lin
    return k_t * session.gains.k_p[2] * kp * surface / (kp + surface)


#: Hand-target depths (m) below the grip's start of a pose-mode press with the default hand: it
#: holds the first, then the second, so the felt stiffness is a secant between two pushes (~3 N
#: and ~9 N at the grip with the default hand and K_P; both within every device's motors and the
#: slave's force limit). Other hands push to :func:`push_depths`.
PUSH_DEPTHS = (0.03, 0.045)
#: Largest share of the slave's force limit each push may ask of the slave (``|F_grip| / K_T``).
PUSH_SLAVE_SHARE = (0.25, 0.75)


def push_depths(session: Session) -> tuple[float, float]:
    """The hand-target depths (m) of a pose-mode press ``session``: ``gap + F_i / k_hand``.

    ``gap`` is the grip's travel to the surface (the translational deadband plus the tip's height
    above the probe surface over ``K_P``), and ``F_i`` the smaller of the force the default hand
    pushes with at :data:`PUSH_DEPTHS` and :data:`PUSH_SLAVE_SHARE` of the slave's force limit
    times ``K_T`` (z): a stiff hand then pushes as hard as the default one instead of driving the
    slave to its limit, and a low ``K_T`` never asks the slave for more than it can push. A hand
    no stiffer than the default one keeps the fixed depths (softer hands push less). Depths are
    along -z; the hand's stiffness is its translational one (N/m).
    """
    tool, gains = session.scene.tool, session.gains
    tip = float(tool.T_w_MRF_home[2, 3] - tool.T_T_MRF[2, 3] + np.min(tool.centers_T[:, 2] - tool.radii))
    gap = float(gains.deadband[2]) + tip / float(gains.k_p[2])
    k_hand = session.data.hand.stiffness_trans
    k_default = HandParams().stiffness_trans
    limit = session.scene.spec.slave.force_limit * float(gains.k_t[2])
    depths = []
    for depth, share in zip(PUSH_DEPTHS, PUSH_SLAVE_SHARE, strict=True):
        force = min(k_default * (depth - gap), share * limit)
        depths.append(depth if k_hand <= 0.0 else min(depth, gap + force / k_hand))
    return depths[0], depths[1]


#: Simulated time (s) of a press: rate mode holds the probe session's push to the end; pose mode
#: reaches the first depth at 1.0 s, the second at ``POSE_SECONDS - 2 SETTLE_WINDOW + 0.2``.
RATE_SECONDS, POSE_SECONDS = 2.8, 3.4


class FeltStiffness:
    """Tick observer: the rendered grip force and the true grip position, averaged over the window
    ``[end - SETTLE_WINDOW, end)`` of two plateaus, and the secant stiffness between them.

    The rendered force is ``K_T F_MRF`` at the grip as the motors delivered it (after the PC's cut
    and the uniform saturation), in base {0} axes (N); the grip position is ``T_0_G``'s (m).

    Args:
        ends: End times (s) of the two plateaus' windows.
    """

    def __init__(self, ends: tuple[float, float]) -> None:
        self._ends = ends
        self._sums = np.zeros((2, 6))
        self._counts = np.zeros(2)
        #: The motors saturated (uniform scale below 1) on some tick of a window.
        self.saturated = False

    def on_tick(self, tick: TickRecord) -> None:
        for i, end in enumerate(self._ends):
            if end - SETTLE_WINDOW <= tick.time < end:
                out, T_0_G = tick.out, tick.reading.T_0_G
                scale = (1.0 - out.pc_cut) * out.saturation_scale
                self._sums[i, 0:3] += scale * (T_0_G[0:3, 0:3] @ out.G_F_T[0:3])
                self._sums[i, 3:6] += T_0_G[0:3, 3]
                self._counts[i] += 1
                self.saturated |= out.saturation_scale < 1.0

    def plateau_force(self, i: int) -> float:
        """Magnitude of the mean rendered grip force over plateau ``i``'s window (N; NaN if no tick)."""
        if not self._counts[i]:
            return math.nan
        return float(np.linalg.norm(self._sums[i, 0:3])) / self._counts[i]

    def stiffness(self) -> float:
        """``(F_2 - F_1) . n / ((p_1 - p_2) . n)`` (N/m), ``n`` the unit second-plateau force: the
        grip pushed further in (against ``n``) meets more force. NaN if a window saw no tick, no
        force, or no travel."""
        if not np.all(self._counts):
            return math.nan
        mean = self._sums / self._counts[:, None]
        force = float(np.linalg.norm(mean[1, 0:3]))
        if force == 0.0:
            return math.nan
        n = mean[1, 0:3] / force
        travel = float((mean[0, 3:6] - mean[1, 3:6]) @ n)
        return float((mean[1, 0:3] - mean[0, 0:3]) @ n) / travel if travel > 0.0 else math.nan


#: Time (s) the hand holds the second push of a pose-mode press before the judged window opens.
HOLD_SECONDS = 0.2


def _pose_push(
    seconds: float,
    hold: float,
    released: bool = False,
    depths: tuple[float, float] = PUSH_DEPTHS,
    window: float = SETTLE_WINDOW,
) -> tuple[tuple[Waypoint, ...], tuple[float, float]]:
    """The hand's waypoints of a pose-mode press lasting ``seconds`` to ``depths`` (m) that holds
    its second push ``hold`` (s) before the judged ``window`` (s), and its plateaus' window ends.
    ``released``: the hand holds only the first push, and lets go where the second would start
    (:func:`release_time`)."""
    first, second = (Waypoint(0.0, (0.0, 0.0, -d)) for d in depths)
    end_1 = release_time(seconds, hold, window)  # the second push starts here, reached 0.2 s later
    waypoints: tuple[Waypoint, ...] = (Waypoint(0.3), replace(first, t=1.0), replace(first, t=end_1))
    if not released:
        waypoints += (replace(second, t=end_1 + 0.2), replace(second, t=seconds))
    return waypoints, (end_1, seconds + 1e-9)


def release_time(seconds: float, hold: float, window: float = SETTLE_WINDOW) -> float:
    """When (s) the first plateau of a pose press lasting ``seconds`` with ``hold`` before its
    judged ``window`` ends: the second push starts there, or a released press's hand lets go."""
    return seconds - window - hold - 0.2


def press_session(
    scene: Path,
    mode: str = "rate",
    seconds: float | None = None,
    hold: float = HOLD_SECONDS,
    released: bool = False,
    window: float = SETTLE_WINDOW,
    **changes: Any,
) -> Session:
    """The probe session's push (reflection on, the device's gains and the hand) on ``scene``, in
    ``mode``, for ``seconds`` of simulated time (default :data:`RATE_SECONDS`, or
    :data:`POSE_SECONDS` lengthened by the ``hold`` beyond :data:`HOLD_SECONDS` and the
    ``window`` beyond :data:`~app.session.metrics.SETTLE_WINDOW`); in pose mode the hand pushes
    in two steps (:func:`push_depths`) and holds the second ``hold`` (s) before the judged
    ``window`` (s), and on to the end; ``released`` (pose mode): it holds the first push, then
    lets go of the grip with the tool on the surface and the judged window comes ``hold`` + 0.2 s
    later. ``changes`` are further session-file fields."""
    base = load_session("probe_rate")
    if mode == "pose":
        seconds = seconds or POSE_SECONDS + hold - HOLD_SECONDS + window - SETTLE_WINDOW
        depths = push_depths(base.with_changes(scene=str(scene), mode=mode, **changes))
        changes.setdefault("waypoints", _pose_push(seconds, hold, released, depths, window)[0])
        if released:
            let_go = SwitchEvent(release_time(seconds, hold, window), hand=False)
            changes.setdefault("events", (*base.data.events, let_go))
    elif released:
        raise ValueError("a released press is a pose-mode press")
    duration = seconds or RATE_SECONDS
    return base.with_changes(scene=str(scene), mode=mode, duration=duration, **changes)


def press(
    stiffness: float,
    mode: str = "rate",
    gains: dict[str, Any] | None = None,
    damping: float = 3.0,
    seconds: float | None = None,
    hold: float = HOLD_SECONDS,
    released: bool = False,
    window: float = SETTLE_WINDOW,
    observers: Sequence[TickObserver] = (),
    **changes: Any,
) -> PressResult:
    """Run the probe session's push on a surface of another stiffness; judge how the force settles.

    Args:
        stiffness: Surface stiffness (N/m). ``damping``: surface damping (N s/m).
        mode: ``"rate"`` or ``"pose"``. ``gains``: overrides of the device's gains.
        seconds: Simulated time (default per mode, see :func:`press_session`); the force is
            judged over the last ``window`` s, while the hand still holds the (second) push.
        hold: Pose mode: how long (s) the hand holds the second push before that window.
        window: Pose mode: how long (s) the judged window lasts (the issue's bar: an 8 s hold).
        released: Pose mode: the hand lets go after the first push (the device-only case). The
            tool is left resting on the surface, pressed only by what the rendering does, so
            the force may settle anywhere from zero up: *settled* is then a ripple below 5 % of
            the force the hand held (the first plateau's rendered grip force), and the felt
            stiffness is NaN. ``changes``: further session fields (``passivity``, ``hand``...).
        observers: Further tick observers, run beside the press's own (a bench's force trace).
    """
    with tempfile.TemporaryDirectory() as tmp:
        scene = probe_scene_with_stiffness(stiffness, damping, Path(tmp))
        session = press_session(scene, mode, seconds, hold, released, window, gains=gains or {}, **changes)
        duration = session.data.duration
        felt = FeltStiffness(_pose_push(duration, hold, window=window)[1]) if mode == "pose" else None
        judged = ContactForce(duration - window)
        let_go = release_time(duration, hold, window) if released else None
        grip = GripTravel(duration - window, let_go)
        own = (judged, grip, felt) if felt else (judged,)
        summary = run_session(session, out_dir=None, plots=False, observers=(*own, *observers)).summary
        force_limit = session.scene.spec.slave.force_limit
    mean, ripple = judged.mean_and_ripple()
    settled = bool(math.isfinite(ripple) and mean >= SETTLE_MIN_FORCE and ripple < SETTLE_RIPPLE * mean)
    stiffness, saturated = (felt.stiffness(), felt.saturated) if felt else (math.nan, False)
    if released and felt is not None:
        stiffness, settled = math.nan, bool(ripple < SETTLE_RIPPLE * felt.plateau_force(0))
        saturated = released_saturated(mean, judged.saturated_share())
    pushed_through = mean >= 0.95 * force_limit
    drift = grip.drift() if felt else math.nan
    return PressResult(
        mean,
        ripple,
        settled,
        stiffness,
        saturated,
        pushed_through,
        summary,
        judged.saturated_share(),
        drift,
        grip.since_release(),
    )


class GripTravel:
    """Tick observer: the grip's true height (m, ``T_0_G``'s z in the base {0}, the probe
    surface's normal) on every tick from ``start`` (s) on, and at ``release`` (s, the first tick
    from then; None: not recorded), for :attr:`PressResult.grip_drift` and
    :attr:`PressResult.release_drift`."""

    def __init__(self, start: float, release: float | None = None) -> None:
        self._start = start
        self._release = release
        self._heights: list[float] = []
        self.at_release = math.nan

    def on_tick(self, tick: TickRecord) -> None:
        z = float(tick.reading.T_0_G[2, 3])
        if self._release is not None and math.isnan(self.at_release) and tick.time >= self._release:
            self.at_release = z
        if tick.time >= self._start:
            self._heights.append(z)

    def _ends(self) -> tuple[float, float]:
        """Mean height (m) over the first and the last tenth of the window (NaN without a tick):
        an oscillation's phase at the window's edges does not read as travel."""
        if not self._heights:
            return math.nan, math.nan
        z = np.array(self._heights)
        n = max(1, len(z) // 10)
        return float(z[:n].mean()), float(z[-n:].mean())

    def drift(self) -> float:
        """Travel (m) along +z over the window, last tenth's mean less the first's."""
        first, last = self._ends()
        return last - first

    def since_release(self) -> float:
        """Travel (m) along +z from the release to the window's last tenth (NaN if not recorded)."""
        return self._ends()[1] - self.at_release


class ContactForce:
    """Tick observer: the contact force magnitude at {MRF} (N) on every tick from ``start`` (s) on,
    the quantity the session's settling judges over its last
    :data:`~app.session.metrics.SETTLE_WINDOW` (:class:`~app.session.metrics.SessionMetrics`),
    kept here for a window of any length, and how many of those ticks the motors saturated on."""

    def __init__(self, start: float) -> None:
        self._start = start
        self._forces: list[float] = []
        self._saturated = 0

    def on_tick(self, tick: TickRecord) -> None:
        if tick.time >= self._start:
            self._forces.append(float(np.linalg.norm(tick.contact_wrench_MRF[0:3])))
            self._saturated += tick.out.saturation_scale < 1.0

    def saturated_share(self) -> float:
        """Share (0..1) of the window's ticks with the uniform saturation scale below 1; 0 without a tick."""
        return self._saturated / len(self._forces) if self._forces else 0.0

    def mean_and_ripple(self) -> tuple[float, float]:
        """Mean and peak-to-peak (N) of the force over the window; NaN without a tick."""
        if not self._forces:
            return math.nan, math.nan
        forces = np.array(self._forces)
        return float(forces.mean()), float(np.ptp(forces))


#: The delay of issue 13's bar, each way (ms): 100 ms round trip.
BAR_DELAY_MS = 50.0


def delayed_press(coupling: Coupling, delay_ms: float = BAR_DELAY_MS) -> PressResult:
    """The probe press in pose mode on a 1e5 N/m surface (the device's gains, K_T 1) through a
    master-slave channel of ``delay_ms`` (ms) each way, reflecting with ``coupling``.

    The hand pushes in two steps (:data:`PUSH_DEPTHS`) and, as an operator waits out the echo of a
    delayed line, holds the second six round trips longer than a direct press
    (:data:`HOLD_SECONDS` + 12 ``delay_ms``) before the force is judged over the last
    :data:`~app.session.metrics.SETTLE_WINDOW`; the felt stiffness is the secant between the two
    plateaus (:class:`FeltStiffness`). Direct reflection of the delayed force makes the loop
    oscillate on the surface; wave variables (:mod:`app.teleop.wave`) settle, at the cost of the
    felt stiffness (a wave press overshoots once after each push: the operator meets the wall a
    round trip late).
    """
    hold = HOLD_SECONDS + 12.0 * delay_ms * 1e-3
    return press(1e5, "pose", hold=hold, channel=ChannelSettings(delay_ms=delay_ms, coupling=coupling))
