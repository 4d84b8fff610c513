"""The plot of a sweep: one metric over one field (lines) or two fields (a heatmap).

With more fields the metric is averaged over the others; points that failed are left out.
Random samples (too many distinct values to grid) are drawn as a scatter coloured by the metric.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pyarrow as pa

#: Most distinct values of a field drawn as heatmap cells; beyond, the sweep is drawn as a scatter.
MAX_CELLS = 40


def _numeric(values: list[Any]) -> bool:
    return all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)


def plot_sweep(table: pa.Table, fields: tuple[str, ...], metric: str, path: Path) -> Path | None:
    """Draw ``metric`` over the first one or two ``fields`` of ``table`` into ``path``; None if no
    point succeeded."""
    ok = table.filter(pa.compute.equal(table.column("status"), "ok"))
    y = np.array([np.nan if v is None else float(v) for v in ok.column(metric).to_pylist()])
    if ok.num_rows == 0:
        return None
    xs = [ok.column(f).to_pylist() for f in fields[:2]]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    if len(xs) == 1:
        _lines(ax, xs[0], y)
        ax.set_xlabel(fields[0])
        ax.set_ylabel(metric)
    else:
        keys = [sorted(set(x), key=str) if not _numeric(x) else sorted(set(x)) for x in xs]
        if max(len(k) for k in keys) <= MAX_CELLS:
            _heatmap(fig, ax, xs, keys, y, metric)
        else:
            sc = ax.scatter(xs[0], xs[1], c=y, cmap="viridis", s=16)
            fig.colorbar(sc, ax=ax, label=metric)
        ax.set_xlabel(fields[0])
        ax.set_ylabel(fields[1])
    rest = f" (mean over {', '.join(fields[2:])})" if len(fields) > 2 else ""
    ax.set_title(f"{metric}{rest}: {ok.num_rows} of {table.num_rows} points ok")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _lines(ax: Any, x: list[Any], y: np.ndarray) -> None:
    keys = sorted(set(x)) if _numeric(x) else sorted(set(x), key=str)
    means = [float(np.nanmean(y[[i for i, v in enumerate(x) if v == k]])) for k in keys]
    pos = keys if _numeric(x) else list(range(len(keys)))
    ax.plot(pos, means, "o-")
    if not _numeric(x):
        ax.set_xticks(pos, [str(k) for k in keys])
    ax.grid(alpha=0.3)


def _heatmap(fig: Any, ax: Any, xs: list[list[Any]], keys: list[list[Any]], y: np.ndarray, metric: str) -> None:
    grid = np.full((len(keys[1]), len(keys[0])), np.nan)
    for c, a in enumerate(keys[0]):
        for r, b in enumerate(keys[1]):
            sel = [i for i, (u, v) in enumerate(zip(xs[0], xs[1], strict=True)) if u == a and v == b]
            if sel:
                grid[r, c] = float(np.nanmean(y[sel]))
    im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
    ax.set_xticks(range(len(keys[0])), [f"{k:g}" if isinstance(k, float) else str(k) for k in keys[0]], rotation=45)
    ax.set_yticks(range(len(keys[1])), [f"{k:g}" if isinstance(k, float) else str(k) for k in keys[1]])
    fig.colorbar(im, ax=ax, label=metric)
