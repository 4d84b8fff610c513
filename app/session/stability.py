"""Contact stability of the whole loop: press the probe into a surface and watch the force settle.

Used by ``frhc bench stability`` (a stiffness sweep, compared with the passivity bound
``K < 2 b / T`` for a sampled-data virtual wall), by ``frhc zwidth`` (:mod:`app.session.zwidth`)
and by the tests (the shipped surfaces settle). Every press is an ordinary headless session,
run by :func:`run_point`, so a sweep engine can run the same points anywhere.
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app.session.run import run_session
from app.session.spec import Session, load_session
from app.teleop.channel import ChannelSettings, Coupling
from app.world.scene import SCENES_DIR


@dataclass(frozen=True)
class PressResult:
    """How the contact force behaved while the operator held the tool pressed on the surface.

    Attributes:
        mean_force: Mean contact force magnitude over the settling window (N).
        ripple: Peak-to-peak contact force over that window (N).
        settled: ``ripple`` below 5 % of the mean (and finite), the mean at least 0.1 N
            (:data:`~app.session.metrics.SETTLE_MIN_FORCE`: in contact).
        felt_stiffness: Rendered grip force over grip travel since contact (N/m).
        summary: The whole session summary.
    """

    mean_force: float
    ripple: float
    settled: bool
    felt_stiffness: float
    summary: dict[str, Any]


def probe_scene_with_stiffness(stiffness: float, damping: float, folder: Path) -> Path:
    """A copy of the probe scene with another surface stiffness (N/m) and damping (N s/m)."""
    text = (SCENES_DIR / "probe.toml").read_text()
    text = re.sub(r"(?m)^stiffness = .*$", f"stiffness = {stiffness!r}", text, count=1)
    text = re.sub(r"(?m)^damping = .*$", f"damping = {damping!r}", text, count=1)
    path = folder / f"probe_k{stiffness:g}.toml"
    path.write_text(text)
    return path


def run_point(session: Session) -> dict[str, Any]:
    """Run ``session`` headless (no files) and return its summary: one point of a stability sweep.

    The summary's ``settling`` entry holds the oscillation criterion
    (:class:`~app.session.metrics.SessionMetrics`); everything is JSON-able, so a sweep engine
    can run points in other processes and collect these dicts.
    """
    return run_session(session, out_dir=None, plots=False).summary


def press_session(scene: Path, mode: str = "rate", seconds: float = 2.8, **changes: Any) -> Session:
    """The probe session's push (reflection on, the device's gains and the hand) on ``scene``,
    in ``mode``, for ``seconds`` of simulated time; ``changes`` are further session-file fields."""
    return load_session("probe_rate").with_changes(scene=str(scene), mode=mode, duration=seconds, **changes)


def press(
    stiffness: float,
    mode: str = "rate",
    gains: dict[str, Any] | None = None,
    damping: float = 3.0,
    seconds: float = 2.8,
    **changes: Any,
) -> PressResult:
    """Run the probe session's push on a surface of another stiffness; judge how the force settles.

    Args:
        stiffness: Surface stiffness (N/m). ``damping``: surface damping (N s/m).
        mode: ``"rate"`` or ``"pose"``. ``gains``: overrides of the device's gains.
        seconds: Simulated time; the force is judged over the last 0.6 s, while the hand still
            holds the push. ``changes``: further session fields (``passivity``, ``channel``...).
    """
    with tempfile.TemporaryDirectory() as tmp:
        scene = probe_scene_with_stiffness(stiffness, damping, Path(tmp))
        session = press_session(scene, mode, seconds, gains=gains or {}, **changes)
        summary = run_point(session)
    s = summary["settling"]
    return PressResult(s["mean_force_N"], s["ripple_N"], s["settled"], s["felt_stiffness_N_per_m"], summary)


#: The delay of issue 13's bar, each way (ms): 100 ms round trip.
BAR_DELAY_MS = 50.0


def delayed_press(coupling: Coupling, delay_ms: float = BAR_DELAY_MS, seconds: float = 2.8) -> PressResult:
    """The probe press in pose mode on a 1e5 N/m surface (the device's gains, K_T 1) through a
    master-slave channel of ``delay_ms`` (ms) each way, reflecting with ``coupling``.

    Direct reflection of the delayed force makes the loop oscillate on the surface; wave variables
    (:mod:`app.teleop.wave`) settle, at the cost of the felt stiffness. ``seconds``: as in
    :func:`press` (the hand holds its push until 3.5 s).
    """
    return press(1e5, "pose", seconds=seconds, channel=ChannelSettings(delay_ms=delay_ms, coupling=coupling))
