"""Resume: a run continued from its last checkpoint is bitwise the run that never stopped."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import finish, terminal_signals

from warp_iisph.cli import main
from warp_iisph.run.formats import read_particles, read_stats

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["--set", "spacing=0.04", "--no-progress"]


def frames(run: Path) -> list[Path]:
    return sorted((run / "particles").glob("frame_*.ply"))


def same_run(a: Path, b: Path) -> None:
    fa, fb = frames(a), frames(b)
    assert [f.name for f in fa] == [f.name for f in fb] and fa
    for x, y in zip(fa, fb):
        pa, pb = read_particles(x), read_particles(y)
        for k in ("x", "v", "density", "pressure", "id"):
            assert np.array_equal(pa[k], pb[k]), (x.name, k)
    strip = lambda r: {k: v for k, v in r.items() if k != "ms"}  # noqa: E731
    assert [strip(r) for r in read_stats(a / "stats.jsonl")] == [strip(r) for r in read_stats(b / "stats.jsonl")]


@pytest.fixture(scope="module")
def whole(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("resume") / "whole"
    assert main(["run", "martin_moyce", "--duration", "0.4", "--out", str(out), *SMALL]) == 0
    return out


def test_an_interrupted_run_resumes_bitwise(whole, tmp_path):
    out = tmp_path / "cut"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "warp_iisph.cli",
            "run",
            "martin_moyce",
            "--duration",
            "0.4",
            "--out",
            str(out),
            "--set",
            "spacing=0.04",
            "--set",
            "physics.dt=0.0005",
            "--no-progress",
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=terminal_signals,
    )
    t0 = time.time()
    while not (out / "particles" / "frame_00003.ply").exists():
        assert proc.poll() is None and time.time() - t0 < 120, proc.communicate()
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    finish(proc)
    record = json.loads((out / "run.json").read_text())
    assert record["ended"] == "interrupted" and record["totals"]["frames"] < 12
    # the interrupted run used a fixed dt; so does the run it must equal
    reference = tmp_path / "reference"
    assert (
        main(
            ["run", "martin_moyce", "--duration", "0.4", "--out", str(reference), "--set", "physics.dt=0.0005", *SMALL]
        )
        == 0
    )
    assert main(["run", "--resume", str(out), "--no-progress"]) == 0
    same_run(out, reference)
    record = json.loads((out / "run.json").read_text())
    assert record["ended"] == "completed" and record["resumed"][0]["frame"] >= 3
    assert record["run_id"] == json.loads(json.dumps(record))["run_id"]


def test_a_finished_run_extends_bitwise(whole, tmp_path):
    out = tmp_path / "short"
    assert main(["run", "martin_moyce", "--duration", "0.1", "--out", str(out), *SMALL]) == 0
    # a checkpoint staged by a run killed mid-frame (written beside its place, never renamed in)
    stale = out / ".checkpoint.npz.k1ll3d.tmp.npz"
    stale.write_bytes(b"half a checkpoint")
    assert main(["run", "--resume", str(out), "--duration", "0.4", "--no-progress"]) == 0
    same_run(out, whole)
    assert not stale.exists()


def test_a_diverged_run_resumes_once_fixed(whole, tmp_path):
    """A run stopped as diverged by a speed limit set too low resumes, with the limit fixed, from
    its last checkpoint: the steps after it go, and the run equals one that had the right limit."""
    out = tmp_path / "strict"
    assert (
        main(
            ["run", "martin_moyce", "--duration", "0.4", "--out", str(out), "--set", "physics.max_velocity=1.0", *SMALL]
        )
        == 1
    )
    record = json.loads((out / "run.json").read_text())
    assert record["ended"] == "diverged" and "exceeds the limit 1 m/s" in record["message"]
    last = record["totals"]["frames"] - 1
    assert main(["run", "--resume", str(out), "--set", "physics.max_velocity=50", "--no-progress"]) == 0
    record = json.loads((out / "run.json").read_text())
    assert record["ended"] == "completed" and record["resumed"][0]["frame"] == last
    assert record["scene"]["physics"]["max_velocity"] == 50
    same_run(out, whole)


def test_resume_refuses_what_it_cannot_do(whole, tmp_path, capsys):
    assert main(["run", "--resume", str(whole), "--set", "spacing=0.02", "--no-progress"]) == 2
    assert "--set spacing: a resumed run keeps its particles" in capsys.readouterr().err
    assert main(["run", "--resume", str(whole), "--fps", "60", "--no-progress"]) == 2
    assert "keeps its 30 frames/s" in capsys.readouterr().err
    assert main(["run", "martin_moyce", "--resume", str(whole), "--no-progress"]) == 2
    capsys.readouterr()
    nock = tmp_path / "nock"
    assert (
        main(
            [
                "run",
                "martin_moyce",
                "--duration",
                "0.1",
                "--out",
                str(nock),
                "--set",
                "output.checkpoint_every=0",
                *SMALL,
            ]
        )
        == 0
    )
    assert main(["run", "--resume", str(nock), "--no-progress"]) == 2
    assert "no checkpoint to resume from" in capsys.readouterr().err
