"""The benchmark scripts' --quick modes run and write their table, JSON and chart."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("script,stem", [("thread_scaling.py", "thread_scaling_quick"), ("surface.py", "surface_quick")])
def test_benchmark_quick_mode(script, stem, tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / script), "--quick", "--threads", "1,2", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    record = json.loads((tmp_path / f"{stem}.json").read_text())
    assert [r["threads"] for r in record["results"]][:2] == [1, 2]
    assert record["versions"]["warp"] and record["date"]
    assert (tmp_path / f"{stem}.png").stat().st_size > 10_000


@pytest.mark.parametrize("script,stem", [("validation.py", "validation_quick"), ("stability.py", "stability_quick")])
def test_accuracy_benchmark_quick_mode(script, stem, tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / script), "--quick", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    record = json.loads((tmp_path / f"{stem}.json").read_text())
    rows = record.get("runs") or record.get("results")
    assert rows and (tmp_path / f"{stem}.png").stat().st_size > 10_000
    if script == "stability.py":  # the point of the chart: IISPH takes far larger steps than WCSPH
        dt = {r["method"]: r["dt_max"] for r in rows}
        assert dt["iisph"] > 2 * dt["wcsph"], dt
    else:
        assert all(r["mean_abs_error"] < 0.1 for r in rows if r["wall_friction"] > 0)
