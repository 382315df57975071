"""A built wheel, installed into a fresh virtual environment, runs bundled scenes from another folder."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_wheel_ships_bundled_scenes_and_their_meshes(tmp_path):
    def ok(*args, cwd=tmp_path):
        p = subprocess.run([str(a) for a in args], capture_output=True, text=True, cwd=cwd, timeout=600)
        assert p.returncode == 0, p.stdout + p.stderr
        return p.stdout

    ok(sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", tmp_path / "dist", ROOT)
    (wheel,) = (tmp_path / "dist").glob("warp_iisph-*.whl")
    # the dependencies come from this environment; the package itself only from the wheel
    ok(sys.executable, "-m", "venv", "--system-site-packages", tmp_path / "venv")
    bin_dir = tmp_path / "venv" / "bin"
    ok(bin_dir / "python", "-m", "pip", "install", "--quiet", "--no-deps", "--no-index", wheel)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = ok(bin_dir / "python", "-c", "import warp_iisph; print(warp_iisph.__file__)", cwd=elsewhere)
    assert str(tmp_path / "venv") in where
    listed = ok(bin_dir / "warp-iisph", "scenes", cwd=elsewhere)
    assert {"dam_break", "drop_splash", "fluid_flow", "martin_moyce", "dam_break_cube"} <= {
        line.split()[0] for line in listed.splitlines()
    }
    # dam_break reads its submarine mesh from the installed package
    ok(
        bin_dir / "warp-iisph",
        "run",
        "dam_break",
        "--duration",
        "0.04",
        "--set",
        "spacing=0.06",
        "--no-progress",
        cwd=elsewhere,
    )
    assert len(list((elsewhere / "runs" / "dam_break" / "particles").glob("frame_*.ply"))) == 2
    assert (elsewhere / "runs" / "dam_break" / "obstacles.obj").is_file()


def test_python_dash_m_runs_the_command_line():
    """``python -m warp_iisph`` is the command line, as ``python -m warp_iisph.cli`` is."""
    import subprocess
    import sys

    for module in ("warp_iisph", "warp_iisph.cli"):
        proc = subprocess.run([sys.executable, "-m", module, "scenes"], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0 and "martin_moyce" in proc.stdout, proc.stderr
