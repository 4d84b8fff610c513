"""Sweeps: many independent headless sessions on the point engine (serially or on Ray).

``load_sweep`` checks a sweep file, ``run_sweep`` runs its points and writes the results table;
``app.sweep.engine.run_points`` is the engine, also used by the experiment and ``frhc zwidth``.
"""

from app.sweep.run import SweepReport, run_sweep
from app.sweep.spec import SweepPlan, load_sweep

__all__ = ["SweepPlan", "SweepReport", "load_sweep", "run_sweep"]
