"""PNG plots of a session log: wrench, Delta X and commands against time, contact events shaded."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: never needs a display
import matplotlib.pyplot as plt
import numpy as np

from app.controller.layout import DELTA_X_AXES, TWIST_AXES, WRENCH_AXES
from app.session.log import read_log


def _shade_contacts(ax: plt.Axes, t: np.ndarray, contacts: np.ndarray) -> None:
    on = contacts > 0
    edges = np.flatnonzero(np.diff(on.astype(int)))
    starts = list(t[edges + 1][~on[edges]]) if len(edges) else []
    ends = list(t[edges + 1][on[edges]]) if len(edges) else []
    if on[0]:
        starts.insert(0, t[0])
    if on[-1]:
        ends.append(t[-1])
    for a, b in zip(starts, ends, strict=False):
        ax.axvspan(a, b, color="tab:red", alpha=0.08, lw=0)


def plot_session(log_dir: Path, out_dir: Path) -> list[Path]:
    """Write ``session.png`` (4 panels) into ``out_dir``; returns the files written."""
    table = read_log(log_dir)
    col = {name: table.column(name).to_numpy() for name in table.column_names}
    t = col["t"]
    fig, axes = plt.subplots(4, 1, figsize=(10, 11), sharex=True)
    panels = [
        ("contact force at {MRF} (N)", [f"contact_MRF_{s}" for s in WRENCH_AXES[0:3]]),
        ("reflected wrench at {G}: force (N)", [f"G_F_T_{s}" for s in WRENCH_AXES[0:3]]),
        ("Delta X: translation (m), angles (rad)", [f"delta_x_{s}" for s in DELTA_X_AXES]),
        ("slave rate command (m/s, rad/s)", [f"cmd_{s}" for s in TWIST_AXES]),
    ]
    for ax, (title, names) in zip(axes, panels, strict=True):
        for name in names:
            ax.plot(t, col[name], lw=1, label=name.rsplit("_", 1)[-1])
        _shade_contacts(ax, t, col["contacts"])
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, ncol=6, loc="upper right")
    axes[-1].set_xlabel("time (s); shaded: tool in contact")
    fig.tight_layout()
    path = out_dir / "session.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return [path]
