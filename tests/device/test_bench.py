"""The plant benchmark runs and reports every device (timings themselves are not asserted)."""

from __future__ import annotations

from app.device.bench import run
from app.device.spec import available_devices


def test_bench_quick_reports_every_device() -> None:
    table = run(quick=True)
    rows = {line.split()[0]: line.split()[1:] for line in table.splitlines()[2:]}
    assert set(rows) == set(available_devices())
    for values in rows.values():
        assert all(float(v) > 0 for v in values)
