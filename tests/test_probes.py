"""Probes: their keys checked, their samples the same bits on every path and across a resume
(and the run itself unchanged by them), probes.csv and its chart, and readings that are right
where the answer is known: water at rest, a box's buoyancy, the column on a box, the pressure
of a column at the instant of release."""

import json

import numpy as np
import pytest

import warp_iisph.engine.launch as launch
from warp_iisph import Box, Probe, Scene, Simulation
from warp_iisph.cli import main
from warp_iisph.run.lock import FolderLock
from warp_iisph.run.probe_file import read_probes
from warp_iisph.scene import SceneFileError, load_scene, scene_from_dict, scene_to_dict

SCENE = """
name = "probed"
spacing = 0.04
[tank]
lower = [0.0, 0.0, 0.0]
upper = [0.8, 0.5, 0.2]
[[fluids]]
lower = [0.0, 0.0, 0.0]
upper = [0.24, 0.4, 0.2]
[[obstacles]]
name = "block"
lower = [0.52, 0.0, 0.04]
upper = [0.64, 0.12, 0.16]
sampling = "faces"
[output]
fps = 20
duration = 0.3
{output}
[[probes]]
name = "wall"
kind = "pressure"
position = [0.0, 0.05, 0.1]
normal = [1.0, 0.0, 0.0]
[[probes]]
name = "face"
kind = "pressure"
position = [0.52, 0.04, 0.1]
normal = [-1.0, 0.0, 0.0]
[[probes]]
name = "gauge"
kind = "level"
position = [0.1, 0.1]
[[probes]]
name = "load"
kind = "force"
obstacle = "block"
{probes}
"""


def scene_file(tmp_path, output="", probes="", name="scene.toml"):
    path = tmp_path / name
    path.write_text(SCENE.format(output=output, probes=probes))
    return path


def _probe(*lines):
    return "\n".join(["[[probes]]", 'name = "x"', *lines])


@pytest.mark.parametrize(
    "extra, message",
    [
        (_probe('kind = "velocity"'), r"probes\[4\]\.kind = 'velocity': must be one of pressure, level"),
        (_probe('kind = "pressure"', "position = [0.1, 0.1, 0.1]"), r"probes\[4\]\.normal: required"),
        (
            _probe('kind = "level"', "position = [0.1, 0.1]", "normal = [1, 0, 0]"),
            r"probes\[4\]\.normal: not a key of a level probe",
        ),
        (_probe('kind = "level"', "position = [0.1, 0.1, 0.1]"), r"probes\[4\]\.position = .*two finite numbers"),
        (
            _probe('kind = "level"', "position = [2.0, 0.1]"),
            r"probes\[4\]\.position = \[2\.0, 0\.1\]: \[x, z\] must lie",
        ),
        (
            _probe('kind = "pressure"', "position = [0.1, 0.1, 0.1]", "normal = [0, 0, 0]"),
            r"probes\[4\]\.normal = .*must be non-zero",
        ),
        (
            _probe('kind = "force"', 'obstacle = "post"'),
            r"probes\[4\]\.obstacle = 'post': no obstacle has that name \(named: 'block'\)",
        ),
        (
            _probe('kind = "force"', "obstacle = 3"),
            r"probes\[4\]\.obstacle = 3: must be an obstacle's name or its index in \[0, 0\]",
        ),
        (
            _probe('kind = "force"', 'body = "raft"'),
            r"probes\[4\]\.body = 'raft': no body has that name \(the bodies: none\)",
        ),
        (
            _probe('kind = "force"', 'obstacle = "block"', "body = 0"),
            r"probes\[4\]: a force probe takes exactly one of obstacle and body",
        ),
        (_probe('kind = "force"'), r"probes\[4\]: a force probe takes exactly one of obstacle and body"),
        (
            '[[probes]]\nname = "gauge"\nkind = "level"\nposition = [0.2, 0.1]',
            r"probes\[4\]\.name = 'gauge': another probe has that name",
        ),
        (
            '[[probes]]\nname = "a,b"\nkind = "level"\nposition = [0.2, 0.1]',
            r"probes\[4\]\.name = 'a,b': must be 1-64 letters",
        ),
        (
            '[[probes]]\nname = "P1\\n"\nkind = "level"\nposition = [0.2, 0.1]',  # a line break would split the header
            r"probes\[4\]\.name = 'P1\\n': must be 1-64 letters",
        ),
        (_probe('kind = "level"', "position = [0.2, 0.1]", "colour = 1"), r"probes\[4\]\.colour: unknown key"),
        (
            '[[probes]]\nname = "load.Fp_x"\nkind = "level"\nposition = [0.2, 0.1]',
            r"probes\[4\]\.name = 'load.Fp_x': probe 'load' already writes a column 'load\.Fp_x'",
        ),
        (
            _probe('kind = "level"', "position = [0.2, 0.1]", "bottom = 0.6"),
            r"probes\[4\]\.bottom = 0\.6: must be in \[0, 0\.5\]",
        ),
        (_probe('kind = "level"', "position = [[0.1], [0.2]]"), r"probes\[4\]\.position = .*two finite numbers"),
        (
            '[[probes]]\nname = "t"\nkind = "level"\nposition = [0.2, 0.1]',  # probes.csv's time column
            r"probes\[4\]\.name = 't': the time's column has that name",
        ),
        (  # buried in the block: it would read nothing, ever
            _probe('kind = "pressure"', "position = [0.58, 0.04, 0.1]", "normal = [-1, 0, 0]"),
            r"probes\[4\]\.position = \[0\.58, 0\.04, 0\.1\]: half a spacing along its normal .* inside obstacles\[0\]",
        ),
        (  # on the block's face, its normal turned into the block
            _probe('kind = "pressure"', "position = [0.52, 0.04, 0.1]", "normal = [1, 0, 0]"),
            r"probes\[4\]\.position = \[0\.52, 0\.04, 0\.1\]: .* inside obstacles\[0\]; a sensor sits on a wall's face",
        ),
        (  # on the tank's wall, its normal out of the tank
            _probe('kind = "pressure"', "position = [0.0, 0.05, 0.1]", "normal = [-1, 0, 0]"),
            r"probes\[4\]\.position = \[0\.0, 0\.05, 0\.1\]: .* reads at \[-0\.02, 0\.05, 0\.1\], outside the tank",
        ),
    ],
)
def test_probe_keys_are_checked(tmp_path, extra, message):
    with pytest.raises(SceneFileError, match=r"scene\.toml: " + message):
        load_scene(scene_file(tmp_path, probes=extra))


def test_bad_probe_settings_stop_the_command_with_one_line(tmp_path, capsys):
    path = scene_file(tmp_path, output="probe_interval = -1")
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "scene.toml: output.probe_interval = -1: must be in [0, 1e+06]" in err
    path = scene_file(tmp_path, output="probe_interval = 5e-324")  # no step is that short: one row in all
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--no-progress"]) == 2
    assert "output.probe_interval = 5e-324: must be 0 (every step) or at least 1e-07 s" in capsys.readouterr().err
    bad = SCENE.format(output="", probes="").replace('sampling = "faces"', 'sampling = "layers"')
    (tmp_path / "bad.toml").write_text(bad)
    assert main(["run", str(tmp_path / "bad.toml"), "--no-progress"]) == 2
    assert "obstacles[0].sampling = 'layers': must be one of cells, faces" in capsys.readouterr().err


def test_a_scene_with_probes_round_trips(tmp_path):
    scene = load_scene(scene_file(tmp_path, output="probe_interval = 0.01"))
    again = scene_from_dict(scene_to_dict(scene))
    assert again.probes == scene.probes and again.obstacles[0].name == "block"
    assert again.obstacles[0].sampling == "faces" and again.output.probe_interval == 0.01
    assert scene.probes[3].point == pytest.approx((0.58, 0.06, 0.1))  # the obstacle's centre by default
    assert scene.probes[2].bottom == 0.0  # the tank's floor


def _run(scene, graph=False, threads=None, duration=0.35):
    if threads:
        launch.set_threads(threads)
    try:
        sim = Simulation(scene, "cpu", graph=graph)
        sim.advance(duration)
    finally:
        launch.set_threads(launch.available_cores())
    return sim


def test_probes_are_the_same_bits_on_every_path_and_leave_the_run_unchanged(tmp_path, monkeypatch):
    """Pressure, level and force probes (with wall friction) sampled every step: a plain run on one
    thread, split over three and replayed as a graph give the same samples, and the same particles
    as the run without probes."""
    scene = lambda probes=True: load_scene(  # noqa: E731
        scene_file(tmp_path),
        ["physics.boundary_viscosity=0.01"] + ([] if probes else ["probes=[]"]),
    )
    bare = _run(scene(False))
    plain = _run(scene(), threads=1)
    assert np.array_equal(plain.positions, bare.positions) and np.array_equal(plain.pressures, bare.pressures)
    monkeypatch.setattr(launch, "MIN_CHUNK", 50)
    monkeypatch.setattr(launch, "SPLIT_WORTH", 0.0)  # split every launch, however light
    split = _run(scene(), threads=3)
    graph = _run(scene(), graph=True)
    reference = plain.probes.array()
    assert len(reference) == plain.step_count and plain.probes.names[:3] == ["wall", "face", "gauge"]
    for other in (split, graph):
        assert np.array_equal(other.probes.array(), reference)
        assert np.array_equal(other.positions, bare.positions)
    assert np.all(plain.probes["wall"] > 0.0) and plain.probes["gauge"][-1] > 0.2
    assert np.any(plain.probes["load.Fv_x"] != 0.0) and np.any(plain.probes["load.Fp_x"] > 1.0)  # the water hit it
    assert np.all(plain.probes["face"][: plain.probes.time.searchsorted(0.1)] == 0.0)  # dry until the water comes
    load = plain.probes["load"]  # a force probe by its name: its twelve columns
    assert load.shape == (len(reference), 12) and np.array_equal(load[:, 3], plain.probes["load.Fv_x"])
    with pytest.raises(KeyError, match="no such probe"):
        plain.probes["loa"]
    assert "load" in plain.probes and "load.Mp_z" in plain.probes
    assert "loa" not in plain.probes and 0 not in plain.probes
    assert list(plain.probes) == plain.probes.keys() == plain.probes.names and len(plain.probes) == len(reference)


def test_a_normal_too_long_for_a_float_is_still_a_direction_and_probes_edited_in_a_run_are_not_resumed(
    tmp_path, capsys
):
    """A normal whose length overflows float64 is scaled before it is normalised (it was stored as
    [0, 0, 0], with NumPy's overflow warnings on stderr, and the run could not be resumed), and a
    checkpoint remembers the probes it was taken with: a run.json whose probes were edited since
    is not resumed into the same probes.csv."""
    import json

    path = scene_file(tmp_path)
    out = tmp_path / "run"
    args = ["run", str(path), "--out", str(out), "--duration", "0.1", "--no-progress"]
    assert main([*args, "--set", "probes.0.normal=[1e308,1e308,0]"]) == 0
    assert capsys.readouterr().err == ""
    record = json.loads((out / "run.json").read_text())
    np.testing.assert_allclose(record["scene"]["probes"][0]["normal"], [0.5**0.5, 0.5**0.5, 0.0])
    # a direction normalised once is kept as it is when run.json is read back (normalising it again
    # moved a last bit of [0.81, 0.82, 0]'s, and the resume saw other probes than the run's)
    assert main([*args, "--overwrite", "--set", "probes.0.normal=[0.81,0.82,0]"]) == 0
    assert main(["run", "--resume", str(out), "--duration", "0.15", "--no-progress"]) == 0
    kept = (out / "run.json").read_bytes()
    record = json.loads(kept)
    record["scene"]["probes"][1]["position"][1] += 0.01
    (out / "run.json").write_text(json.dumps(record))
    assert main(["run", "--resume", str(out), "--duration", "0.2", "--no-progress"]) == 2
    assert "other probes than" in capsys.readouterr().err
    (out / "run.json").write_bytes(kept)  # nor at another interval: probes.csv's rows keep one
    assert (
        main(["run", "--resume", str(out), "--duration", "0.2", "--no-progress", "--set", "output.probe_interval=0.02"])
        == 2
    )
    assert (
        "probes were read every 0 s (0: every step), this resume would read them every 0.02 s"
        in capsys.readouterr().err
    )
    assert main(["run", "--resume", str(out), "--duration", "0.2", "--no-progress"]) == 0


def test_probe_interval_samples_the_first_step_at_or_after_each_multiple(tmp_path):
    sim = _run(load_scene(scene_file(tmp_path, output="probe_interval = 0.02")), duration=0.2)
    t = sim.probes.time
    steps = np.cumsum([s["dt"] for s in sim.stats])
    expected = [steps[np.searchsorted(steps, m - 1e-9)] for m in np.arange(0.02, 0.2 + 1e-9, 0.02)]
    assert np.allclose(t, expected, rtol=0, atol=1e-12) and len(t) == 10


def test_probes_csv_is_written_kept_across_a_resume_and_charted(tmp_path, capsys, monkeypatch):
    path = scene_file(tmp_path)
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main(["run", str(path), "--out", str(whole), "--no-progress"]) == 0
    assert main(["run", str(path), "--out", str(cut), "--duration", "0.15", "--no-progress"]) == 0
    assert main(["plot", str(cut)]) == 0  # its chart of the first 0.15 s: a resume makes it stale
    with open(cut / "probes.csv", "a") as f:  # what a run killed after its last checkpoint had written
        f.write("0.2," + ",".join(["1"] * 15) + "\n0.21,1,2")
    capsys.readouterr()
    assert main(["run", "--resume", str(cut), "--duration", "0.3", "--no-progress"]) == 0
    assert (cut / "probes.csv").read_text() == (whole / "probes.csv").read_text()
    assert not (cut / "probes.png").exists()  # gone with the other views made of the whole run
    names, units, rows = read_probes(whole / "probes.csv")
    assert names[:4] == ["wall", "face", "gauge", "load.Fp_x"] and units[:4] == ["Pa", "Pa", "m", "N"]
    assert units[-1] == "N m" and len(names) == 3 + 12 and rows.shape[1] == 16
    assert (whole / "probes.csv").read_text().startswith("t [s],wall [Pa],face [Pa],gauge [m],load.Fp_x [N],")
    assert main(["plot", str(whole)]) == 0
    assert (whole / "probes.png").stat().st_size > 10_000
    assert main(["plot", str(tmp_path / "nowhere")]) == 2
    assert "no such run folder" in capsys.readouterr().err
    assert main(["plot", str(path)]) == 2  # the scene file, not its run
    assert "a file, not a run folder" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["plot", str(tmp_path / "empty")]) == 2
    assert "empty: not a run folder (it holds no run.json)" in capsys.readouterr().err
    (tmp_path / "folder").mkdir()
    for out, message in [("folder", "is a folder"), ("chart", "must end in .png"), ("chart.txt", "must end in .png")]:
        assert main(["plot", str(whole), "--out", str(tmp_path / out)]) == 2
        assert f"--out {tmp_path / out}: {message}" in capsys.readouterr().err
    chart = (whole / "probes.png").read_bytes()
    with FolderLock(whole):  # a run still writing into it: one writer per folder
        assert main(["plot", str(whole)]) == 2
        assert "in use by" in capsys.readouterr().err and (whole / "probes.png").read_bytes() == chart
        assert main(["plot", str(whole), "--out", str(tmp_path / "new" / "elsewhere.png")]) == 0  # reads it as it is
    assert (tmp_path / "new" / "elsewhere.png").stat().st_size > 10_000
    assert main(["plot", str(whole), "--out", str(cut / "probes.png")]) == 2  # not over another run's own chart
    assert f"--out {cut / 'probes.png'}: one of the run in {cut}'s own files or views" in capsys.readouterr().err
    for other in ("particles/x.png", "frames/f.png", "stats.jsonl.png"):
        code = main(["plot", str(whole), "--out", str(cut / other)])
        assert code == (0 if other == "stats.jsonl.png" else 2), other  # a name of no run's file is free
    (cut / "stats.jsonl.png").unlink()
    with FolderLock(cut):  # into another run's folder while its writer holds it: refused the same way
        assert main(["plot", str(whole), "--out", str(cut / "charts" / "whole.png")]) == 2
        assert "in use by" in capsys.readouterr().err and not (cut / "charts").exists()
    assert not [p for p in whole.iterdir() if p.name.endswith(".tmp.png")]  # written beside and renamed in
    import matplotlib.figure

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full)
    capsys.readouterr()
    assert main(["plot", str(whole)]) == 1  # a failure at run time, not bad input
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot write: No space left on device" in err[0]
    assert (whole / "probes.png").read_bytes() == chart  # the last chart kept


def test_water_at_rest_reads_its_depth_and_its_pressure_as_the_numpy_sensors_do():
    """A tank settled for 2 s (the water takes that long to come to rest from its lattice): the
    gauge reads the water's depth, the wall and floor sensors its
    hydrostatic pressure at their points, a sensor above the water 0; and every reading is what
    the NumPy twins (warp_iisph.analysis.sensors, float64) read from the same particles."""
    from warp_iisph.analysis.sensors import level_readings, pressure_readings

    h, depth = 0.02, 0.32
    scene = Scene(spacing=h, tank=Box((0.0, 0.0, 0.0), (0.3, 0.42, 0.12)), name="rest")
    scene.add_fluid_box((0.0, 0.0, 0.0), (0.3, depth, 0.12))
    sensors = [("side", (0.0, 0.1, 0.06), (1, 0, 0)), ("floor", (0.15, 0.0, 0.06), (0, 1, 0))]
    sensors.append(("dry", (0.0, 0.38, 0.06), (1, 0, 0)))
    for name, at, normal in sensors:
        scene.add_probe(Probe(name, "pressure", position=at, normal=normal))
    scene.add_probe(Probe("gauge", "level", position=(0.15, 0.06)))
    sim = Simulation(scene, "cpu")
    sim.advance(2.0)
    got = {n: float(sim.probes[n][-1]) for n in sim.probes.names}
    x, p, rho = (a.astype(np.float64) for a in (sim.positions, sim.pressures, sim.densities))
    twin = pressure_readings(x, p, rho, [s[1] for s in sensors], [s[2] for s in sensors], h)
    assert np.allclose([got[s[0]] for s in sensors], twin, rtol=1e-4, atol=1e-2)
    (level,) = level_readings(x, [(0.15, 0.06)], 0.0, 0.42 + h, h)
    assert got["gauge"] == pytest.approx(level, abs=1e-5)
    top = np.sort(x[:, 1])[-len(x) // 16 :].mean() + 0.5 * h  # the top layer's face
    assert got["gauge"] == pytest.approx(top, abs=0.25 * h) and abs(got["gauge"] - depth) < 0.5 * h
    rho_g = 1000.0 * 9.81
    assert got["side"] == pytest.approx(rho_g * (got["gauge"] - 0.1), rel=0.03)
    assert got["floor"] == pytest.approx(rho_g * (got["gauge"] - 0.5 * h), rel=0.03)  # settled: -0.4 and -0.9 %
    assert got["dry"] == 0.0


def test_a_level_gauge_ignores_spray_and_bridges_a_short_gap():
    """The NumPy twin of the gauge (the device's is checked against it above): a droplet cloud
    above the water does not count, an air pocket thinner than 2h inside it is bridged."""
    from warp_iisph.analysis.sensors import level_readings

    h = 0.02
    g = np.arange(0.5, 10) * h
    water = np.stack(np.meshgrid(g, np.arange(0.5, 15) * h, g, indexing="ij"), -1).reshape(-1, 3)  # 0.3 m deep
    spray = np.array([[0.1, 0.45, 0.1], [0.11, 0.5, 0.1], [0.1, 0.55, 0.09]])
    depth = level_readings(water, [(0.1, 0.1)], 0.0, 0.8, h)[0]
    assert depth == pytest.approx(0.3, abs=0.01)
    assert level_readings(np.concatenate([water, spray]), [(0.1, 0.1)], 0.0, 0.8, h)[0] == depth
    pocket = water[np.abs(water[:, 1] - 0.15) > 0.5 * h]  # one layer missing, mid-column
    assert level_readings(pocket, [(0.1, 0.1)], 0.0, 0.8, h)[0] == pytest.approx(depth, abs=0.01)
    assert level_readings(water[water[:, 1] > 0.1], [(0.1, 0.1)], 0.0, 0.8, h)[0] == 0.0  # not standing on the floor


def test_the_release_pressure_is_harmonic_and_meets_its_conditions():
    """The exact pressure at the instant of release (analysis.release): Laplace's equation inside,
    p = 0 on the free surfaces, dp/dx = 0 at the back wall, dp/dy = -rho g at the floor, and the
    hydrostatic column for a very wide one; 0.3697 rho g H at the foot for the Martin & Moyce
    column (a = H/2)."""
    from warp_iisph.analysis.release import release_pressure

    a, H, e = 0.1, 0.2, 1e-4
    p = lambda x, y: release_pressure(x, y, a, H)  # noqa: E731
    for x, y in ((0.03, 0.05), (0.07, 0.15), (0.05, 0.1)):
        lap = (p(x + e, y) + p(x - e, y) + p(x, y + e) + p(x, y - e) - 4 * p(x, y)) / e**2
        assert abs(lap) < 1e-3 * 9810 / H
    assert np.allclose(p(np.linspace(0, a, 7), H), 0.0, atol=1e-6) and np.allclose(
        p(a, np.linspace(0, H, 7)), 0.0, atol=0.1
    )
    assert np.allclose((p(e, np.linspace(0.02, 0.18, 5)) - p(0.0, np.linspace(0.02, 0.18, 5))) / e, 0.0, atol=10.0)
    assert np.allclose((p(np.linspace(0.0, 0.08, 5), e) - p(np.linspace(0.0, 0.08, 5), 0.0)) / e, -9810.0, rtol=2e-3)
    assert release_pressure(0.0, 0.05, 50.0, H) == pytest.approx(9810 * 0.15, rel=1e-9)
    assert p(0.0, 0.0) / (9810 * H) == pytest.approx(0.36972, abs=1e-4)


@pytest.mark.parametrize(
    "submerged,h,wall_gradient", [(True, 0.015, None), (False, 0.015, None), (True, 0.01, "completed")]
)
def test_a_bar_at_rest_feels_its_buoyancy_or_the_water_above_it(submerged, h, wall_gradient):
    """A bar through a tank (its ends in the side walls), sampled as the walls are, settled 1.5 s
    and read over the next 0.5 s: held clear of the floor its force probe reads rho0 g V upward,
    standing on the floor the weight of the water above its top, each within 2 %. At 8 spacings
    square and the defaults +1.9 % and -1.0 % (over 2.5-3.0 s +1.8 % and -1.3 %; at 6 spacings
    +3.7 % and -2.5 %, at 12 +3.2 % and -0.1 %: benchmarks/validation.py loads); at 12 spacings
    with the walls completing the kernel gradient (physics.wall_gradient = "completed") +1.1 %
    (+1.0 % over 2.5-3.0 s), where Akinci's walls read +3.2 % (docs/physics.md 6.2)."""
    L, X, depth, W = 0.12, 0.30, 0.32, 0.12
    y0 = round(0.1 / h) * h if submerged else 0.0
    scene = Scene(spacing=h, tank=Box((0.0, 0.0, 0.0), (X, depth + 0.1, W)), name="bar")
    scene.physics.wall_gradient = wall_gradient
    scene.add_fluid_box((0.0, 0.0, 0.0), (X, depth, W))
    lo, hi = (X / 2 - L / 2, y0, -5 * h), (X / 2 + L / 2, y0 + L, W + 5 * h)
    scene.add_obstacle(Box(lo, hi, name="bar", sampling="faces"))
    scene.add_probe(Probe("bar", "force", obstacle="bar"))
    scene.add_probe(Probe("level", "level", position=(0.03, W / 2)))
    sim = Simulation(scene, "cpu", history=1)
    sim.advance(2.0)
    late = sim.probes.time > 1.5
    force, level = sim.probes["bar.Fp_y"][late].mean(), sim.probes["level"][late].mean()
    expected = 9810.0 * L * L * W if submerged else -9810.0 * (level - hi[1]) * L * W
    assert force == pytest.approx(expected, rel=0.02)
    assert abs(sim.probes["bar.Fp_x"][late].mean()) < 0.01 * abs(expected)  # nothing sideways
    assert np.all(sim.probes["bar.Fv_y"] == 0.0)  # free-slip walls: no viscous load


@pytest.mark.parametrize("method", ["iisph", "dfsph", "wcsph", "iisph completed"])
def test_the_force_on_an_obstacle_is_the_reaction_of_what_the_fluid_felt(method):
    """Without gravity and viscosity, a block of water thrown at a box (touching nothing else)
    changes its momentum by exactly what the box pushed it with, wall friction included: the
    force probe's pressure and viscous parts are minus that change, step by step (but in the few
    steps where the last line put particles back)."""
    scene = Scene(spacing=0.05, tank=Box((0.0, 0.0, 0.0), (1.6, 1.0, 1.0)), name="throw")
    scene.add_fluid_box((0.3, 0.3, 0.3), (0.6, 0.6, 0.6))
    scene.add_obstacle(Box((0.75, 0.25, 0.25), (1.0, 0.65, 0.75), name="box", sampling="faces"))
    scene.add_probe(Probe("F", "force", obstacle="box"))
    ph = scene.physics
    ph.method, ph.gravity, ph.viscosity, ph.boundary_viscosity = method.split()[0], (0.0, 0.0, 0.0), 0.0, 0.02
    ph.wall_gradient = "completed" if "completed" in method else None
    sim = Simulation(scene, "cpu")
    sim.state.v.assign(np.tile(np.float32([2.0, 0.0, 0.0]), (sim.state.capacity, 1)))
    m, h = sim.model.mass, scene.spacing
    hits, scaled = 0, 0.0  # scaled: the largest departure of a wall-gradient factor s_i from 1
    while True:
        x = sim.positions
        if np.any(x < 2 * h) or np.any(x > np.array([1.6, 1.0, 1.0]) - 2 * h):
            break  # the splash reaches the tank's walls, which push too
        before = m * sim.velocities.astype(np.float64).sum(axis=0)
        rec = sim.step()
        change = (m * sim.velocities.astype(np.float64).sum(axis=0) - before) / rec["dt"]
        if rec["wall_corrections"] or rec["obstacle_corrections"]:
            continue  # the last line moved particles: what it took is not a force
        s = sim.probes.array()[-1]
        push = s[1:4] + s[4:7]  # pressure and viscous parts on the box
        assert np.allclose(change, -push, rtol=1e-3, atol=1e-3 * max(1.0, np.abs(push).max())), (rec["t"], change, push)
        hits += np.abs(s[1]) > 1.0 and np.abs(s[4]) > 0.0
        if method != "dfsph":
            scaled = max(scaled, float(np.abs(sim.solver.walls.walls.gradient_scale.numpy()[: sim.state.n] - 1).max()))
    assert (scaled > 0.01) if "completed" in method else (scaled == 0.0), scaled  # Akinci's walls keep s_i = 1
    assert hits > 10 and sim.time > 0.15  # the block struck the box, its pressure and friction both measured
    assert sum(bool(s["obstacle_corrections"]) for s in sim.stats) < 0.1 * len(sim.stats)


def test_sampling_inside_a_graph_allocates_nothing(tmp_path, conditional_body_allocations):
    """The probes' launches sit in the loop over steps and in a capture_if of their own: on CUDA a
    conditional body may not allocate, so (as tests/test_graph.py does for the step) any
    allocation while one is being recorded fails here, on the CPU."""
    calls = conditional_body_allocations
    sim = Simulation(load_scene(scene_file(tmp_path), ["physics.boundary_viscosity=0.01"]), "cpu", graph=True)
    sim.advance(0.1)
    assert sim.graph.captures == 1 and sim.graph.replays >= 1 and not calls
    assert len(sim.probes) == sim.step_count


def test_spheric_scores_locate_a_delay_between_the_release_and_the_run_out():
    """SPHERIC Test 2's scores of the experiment against itself are zero; a run whose every series is
    the experiment's 50 ms late is scored 50 ms late at every sensor and gauge front, at every depth
    of the front and in the column's fall, and on time from the front's passage at the gauge
    nearest the column."""
    from warp_iisph.analysis import spheric

    ref = spheric.load_marin()
    names = spheric.PRESSURES + spheric.GAUGES
    same = spheric.score({n: (ref["t"], ref[n]) for n in names})
    late = spheric.score({n: (ref["t"] + 0.05, ref[n]) for n in names})
    for name in ("P1", "P2", "P3", "P4"):
        assert abs(same[name]["arrival_error"]) < 1e-9 and abs(same[name]["transit_error"]) < 1e-9
        assert late[name]["arrival_error"] == pytest.approx(0.05, abs=1e-9)
        assert abs(late[name]["transit_error"]) < 1e-9
        assert not late[name]["arrival_ok"] and same[name]["arrival_ok"]
    for name in spheric.DOWNSTREAM:
        assert same[name]["rms"] == pytest.approx(0.0, abs=1e-12)
        assert late[name]["front_error"] == pytest.approx(0.05, abs=1e-9)
    assert 0.18 < same["H_x1.488"]["front"]["experiment"] < 0.2  # the front passes x = 1.488 m at 0.19 s
    for name in spheric.DOWNSTREAM:  # the front's depths and the column's fall: the same 50 ms
        assert list(late[name]["front_depths"]) == ["1", "3", "5"]
        assert all(v["error"] == pytest.approx(0.05, abs=1e-9) for v in late[name]["front_depths"].values())
    drops = late[spheric.COLUMN]["drops"]
    assert all(v["error"] == pytest.approx(0.05, abs=1e-9) for v in drops.values())
    assert all(abs(v["error"]) < 1e-9 for v in same[spheric.COLUMN]["drops"].values())
    # the experiment's column falls 1 cm at 0.066 s, 3 cm at 0.166 s: ahead of the exact release's
    # fall there by about 20 ms; a fall of the exact release's shape reads the lead it was given
    assert 0.06 < drops["1"]["experiment"] < 0.07 and 0.16 < drops["3"]["experiment"] < 0.17
    assert 0.015 < late[spheric.COLUMN]["lead"]["experiment"] < 0.03
    t = np.arange(0.0, 0.3, 0.001)
    exact = 0.55 - 0.5 * 2.0269 * t**2  # the exact release's top there, 2.03 m/s^2 down
    assert abs(spheric.column_lead(t, exact)) <= 1e-4 and abs(spheric.column_lead(t - 0.02, exact) - 0.02) <= 1e-4


def test_probes_outside_a_mesh_tank_are_refused(tmp_path):
    """A mesh tank's box holds corners beside its walls: a sensor reading there, or a gauge whose
    column misses the mesh, would read nothing, ever (they were accepted, read 0 throughout)."""
    import trimesh

    trimesh.creation.icosphere(subdivisions=3, radius=0.3).export(tmp_path / "ball.obj")
    base = {
        "spacing": 0.04,
        "tank": {"shape": "mesh", "path": "ball.obj", "translate": [0.3, 0.3, 0.3]},
        "fluids": [{"lower": [0.2, 0.05, 0.2], "upper": [0.4, 0.2, 0.4]}],
    }
    inside = [
        {"name": "floor", "kind": "pressure", "position": [0.3, 0.0, 0.3], "normal": [0, 1, 0]},
        {"name": "middle", "kind": "level", "position": [0.3, 0.3]},
    ]
    assert len(scene_from_dict({**base, "probes": inside}, tmp_path).probes) == 2
    corner = {"name": "c", "kind": "pressure", "position": [0.01, 0.01, 0.01], "normal": [1, 0, 0]}
    with pytest.raises(ValueError, match=r"probes\[0\]\.position = \[0\.01, 0\.01, 0\.01\]: .* outside the tank"):
        scene_from_dict({**base, "probes": [corner]}, tmp_path)
    with pytest.raises(ValueError, match=r"probes\[0\]\.position = \[0\.01, 0\.01\]: the column at \[x, z\] misses"):
        scene_from_dict({**base, "probes": [{"name": "g", "kind": "level", "position": [0.01, 0.01]}]}, tmp_path)


def test_a_level_gauge_reads_the_level_at_a_wall_in_a_corner_and_over_a_still_obstacle():
    """Still water 0.1 m deep (2 cm): a gauge on a side wall, a quarter and half a spacing from
    it, in a corner, standing on a block and over a bar held above the floor reads the level the
    gauge in the open water reads, within 2 % (without the walls' share of the kernel's support
    the one on the wall read 0, a quarter spacing from it 7 % low, the one on the block 0 and the
    one over the bar the water under it); the NumPy twin reads the same."""
    from warp_iisph.analysis.sensors import level_readings

    h = 0.02
    scene = Scene(spacing=h, tank=Box((0.0, 0.0, 0.0), (0.5, 0.3, 0.1)), name="walls")
    scene.add_fluid_box((0.0, 0.0, 0.0), (0.5, 0.12, 0.1))
    scene.add_obstacle(Box((0.14, 0.0, 0.0), (0.22, 0.06, 0.1), name="block"))
    scene.add_obstacle(Box((0.28, 0.04, -0.1), (0.34, 0.08, 0.2), name="bar"))
    gauges = {
        "open": (0.42, 0.05),
        "wall": (0.0, 0.05),
        "quarter": (0.005, 0.05),
        "half": (0.01, 0.05),
        "corner": (0.5, 0.1),
        "block": (0.18, 0.05),
        "bar": (0.31, 0.05),
    }
    for name, at in gauges.items():
        scene.add_probe(Probe(name, "level", position=at))
    sim = Simulation(scene, "cpu")
    sim.advance(0.4)
    late = sim.probes.time > 0.2
    level = {n: float(sim.probes[n][late].mean()) for n in gauges}
    assert 0.105 < level["open"] < 0.125
    for name in gauges:
        assert level[name] == pytest.approx(level["open"], rel=0.02), name
    x = sim.positions.astype(np.float64)
    twin = level_readings(x, list(gauges.values()), 0.0, 0.3 + h, h, tank=scene.tank, obstacles=scene.obstacles)
    assert np.allclose([sim.probes[n][-1] for n in gauges], twin, atol=1e-5)


def test_plot_draws_a_probe_by_its_unit_not_its_name_and_refuses_columns_of_no_probe(tmp_path, capsys, monkeypatch):
    """A pressure sensor may be named like a force probe's viscous column (``air.Fv_x``, dry, all
    zeros; ``wet.Mv_1``): it is drawn, solid, in the pressure panel (it was left off or dashed), as
    is a force probe's pressure part when the probe is named so (``f.Fv_q.Fp_x``); a
    probes.csv with no column in a probe's unit is refused in one line naming it (matplotlib's own
    message came out), a missing one as missing (not as a scene without probes). A force probe's
    obstacle given as a NumPy integer is stored as the file's integer (run.json could not be
    written)."""
    import matplotlib.axes

    extra = (
        '[[probes]]\nname = "air.Fv_x"\nkind = "pressure"\nposition = [0.0, 0.45, 0.1]\nnormal = [1.0, 0.0, 0.0]\n'
        '[[probes]]\nname = "wet.Mv_1"\nkind = "pressure"\nposition = [0.0, 0.02, 0.1]\nnormal = [1.0, 0.0, 0.0]\n'
        '[[probes]]\nname = "f.Fv_q"\nkind = "force"\nobstacle = "block"\n'
    )
    out = tmp_path / "run"
    assert main(["run", str(scene_file(tmp_path, probes=extra)), "--out", str(out), "--duration", "0.05"]) == 0
    drawn = {}
    plot = matplotlib.axes.Axes.plot

    def record(self, *args, **kwargs):
        drawn[kwargs.get("label")] = (self.get_ylabel(), args[2] if len(args) > 2 else None)
        return plot(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", record)
    assert main(["plot", str(out)]) == 0
    assert drawn["air.Fv_x"][1] == "-" and drawn["wet.Mv_1"][1] == "-"
    assert drawn["load.Fp_x"][1] == "-" and "load.Fv_x" not in drawn  # free-slip walls: no viscous load
    assert drawn["f.Fv_q.Fp_x"][1] == "-" and "f.Fv_q.Fv_x" not in drawn  # a force probe named like a part
    capsys.readouterr()
    (out / "probes.csv").write_text("t [s],x [furlong]\n0.1,1\n0.2,2\n")
    assert main(["plot", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "probes.csv: no column in a probe's unit" in err[0]
    (out / "probes.csv").unlink()
    assert main(["plot", str(out)]) == 2
    assert "probes.csv: missing (or not a file), though the run's scene has probes" in capsys.readouterr().err
    scene = load_scene(scene_file(tmp_path))
    scene.add_probe(Probe("by_index", "force", obstacle=np.int64(0)))
    scene.validate()
    assert type(scene.probes[-1].obstacle) is int and json.dumps(scene_to_dict(scene))


def test_a_level_gauge_steps_over_any_solid_and_reads_in_a_mesh_tank(tmp_path):
    """The NumPy twin on lattice water 0.16 m deep (2 cm): a gauge on the face two boxes share, on
    a tank wall over a block flush with it, over three stacked boxes and in a corner over a block
    reads the level (each read 0 when only a box's inside was solid, not its faces); in a bowl (a
    mesh tank) a gauge whose column enters the bowl 0.13 m up reads the water standing in it (it
    read 0), its column's crossings found once (a winding number a point took seconds on a fine
    mesh) and agreeing with the winding number."""
    from warp_iisph.analysis.sensors import level_readings
    from warp_iisph.scene.shapes import MeshShape, contains
    from warp_iisph.sph.probes import gauge_support

    h, level = 0.02, 0.16

    def box(lo, hi):
        b = Box(lo, hi)
        b.validate("b")
        return b

    tank = box((0.0, 0.0, 0.0), (0.5, 0.3, 0.2))
    cases = [
        ([box((0.1, 0, 0.05), (0.2, 0.08, 0.15)), box((0.2, 0, 0.05), (0.3, 0.08, 0.15))], (0.2, 0.1)),
        ([box((0.0, 0, 0.05), (0.1, 0.08, 0.15))], (0.0, 0.1)),
        ([box((0.1, y0, 0.05), (0.3, y1, 0.15)) for y0, y1 in ((0, 0.04), (0.04, 0.08), (0.08, 0.1))], (0.2, 0.1)),
        ([box((0.4, 0, 0.1), (0.5, 0.08, 0.2))], (0.5, 0.2)),
    ]
    g = [np.arange(h / 2, top, h) for top in (0.5, level, 0.2)]
    water = np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3)
    for obstacles, at in cases:
        x = water[~np.any([np.all((water > o.bounds[0]) & (water < o.bounds[1]), axis=1) for o in obstacles], axis=0)]
        reads = level_readings(x, [(0.42, 0.1), at], 0.0, 0.3 + h, h, tank=tank, obstacles=obstacles)
        assert reads == pytest.approx(level, abs=0.002), at
    import trimesh

    trimesh.creation.icosphere(subdivisions=3, radius=0.3).export(str(tmp_path / "ball.obj"))
    bowl = MeshShape(path=str(tmp_path / "ball.obj"), translate=(0.3, 0.3, 0.3))
    bowl.validate("tank")
    g = np.arange(0.02, 0.6, h)  # the top layer at 0.24: its face at 0.25
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    x = x[(np.linalg.norm(x - 0.3, axis=1) < 0.29) & (x[:, 1] < 0.25)]
    assert level_readings(x, [(0.3, 0.3), (0.55, 0.3)], 0.0, 0.64, h, tank=bowl) == pytest.approx(0.25, abs=0.004)
    ys = (np.arange(64) + 0.5) * 0.01
    column = np.column_stack([np.full(64, 0.55), ys, np.full(64, 0.3)])
    assert np.array_equal(gauge_support(bowl, [], 0.55, 0.3, ys, 2 * h) == 0.0, ~contains(bowl, column))
