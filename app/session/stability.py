"""Contact stability of the whole loop: press the probe into a surface and watch the force settle.

Used by ``frhc bench stability`` (a stiffness sweep, compared with the passivity bound
``K < 2 b / T`` for a sampled-data virtual wall) and by the tests (the shipped surfaces settle).
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.session.run import play
from app.session.spec import load_session
from app.world.scene import SCENES_DIR


@dataclass(frozen=True)
class PressResult:
    """How the contact force behaved while the operator held the tool pressed on the surface.

    Attributes:
        mean_force: Mean normal contact force over the last ``window`` seconds (N).
        ripple: Peak-to-peak contact force over that window (N).
        settled: ``ripple`` below 5 % of the mean (and finite).
    """

    mean_force: float
    ripple: float
    settled: bool


def probe_scene_with_stiffness(stiffness: float, damping: float, folder: Path) -> Path:
    """A copy of the probe scene with another surface stiffness (N/m) and damping (N s/m)."""
    text = (SCENES_DIR / "probe.toml").read_text()
    text = re.sub(r"(?m)^stiffness = .*$", f"stiffness = {stiffness!r}", text, count=1)
    text = re.sub(r"(?m)^damping = .*$", f"damping = {damping!r}", text, count=1)
    path = folder / f"probe_k{stiffness:g}.toml"
    path.write_text(text)
    return path


def press(
    stiffness: float,
    mode: str = "rate",
    gains: dict[str, Any] | None = None,
    damping: float = 3.0,
    seconds: float = 2.8,
    window: float = 0.6,
) -> PressResult:
    """Run the probe session's push (reflection on, the device's gains and the hand) on a surface.

    Args:
        stiffness: Surface stiffness (N/m). ``damping``: surface damping (N s/m).
        mode: ``"rate"`` or ``"pose"``. ``gains``: overrides of the device's gains.
        seconds: Simulated time; the normal force is read over the last ``window`` seconds,
            while the hand still holds the push.
    """
    with tempfile.TemporaryDirectory() as tmp:
        scene = probe_scene_with_stiffness(stiffness, damping, Path(tmp))
        session = load_session("probe_rate").with_changes(
            scene=str(scene), mode=mode, duration=seconds, gains=gains or {}
        )
    forces = np.array([tick.contact_wrench_MRF[2] for tick in play(session)])
    tail = forces[-round(window * session.data.servo_rate) :]
    mean = float(np.mean(tail))
    ripple = float(np.ptp(tail))
    return PressResult(mean, ripple, bool(np.isfinite(ripple) and ripple < 0.05 * max(abs(mean), 1e-9)))
