"""The documentation: the MkDocs site builds in strict mode (a broken link, a missing anchor or a
page left out of the navigation fails), and the pages name every command and option of
warp-iisph, every key a scene file takes, and every module of the package."""

import argparse
import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

from warp_iisph import cli
from warp_iisph import scene as sc
from warp_iisph.scene import file as scene_file
from warp_iisph.scene.motion import Motion

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def test_site_builds_in_strict_mode(tmp_path):
    site = tmp_path / "site"
    r = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml")]
        + ["--site-dir", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert r.returncode == 0, r.stdout + r.stderr
    # the API pages were rendered from the docstrings, and linked result files were copied in
    assert "frozen_copy" in (site / "api" / "scene" / "index.html").read_text()
    assert (site / "repo" / "benchmarks" / "results" / "thread_scaling.json").is_file()


def _parser() -> argparse.ArgumentParser:
    """warp-iisph's parser, from the function of ``warp_iisph.cli`` that builds it."""
    for name in ("_parser", "build_parser", "parser", "make_parser"):
        make = getattr(cli, name, None)
        if callable(make):
            return make()
    raise AssertionError("warp_iisph.cli: no function building the parser (_parser, build_parser, ...)")


def _commands(parser: argparse.ArgumentParser) -> dict:
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def _documented(text: str, option: str) -> bool:
    """``option`` written as code: `--out`, `--out DIR`, `--graph`, `--no-graph`."""
    return re.search(r"`" + re.escape(option) + r"[` =\]]", text) is not None


def _sections(text: str) -> dict:
    """The page's ``## `warp-iisph NAME``` sections by command name."""
    parts = re.split(r"^## `warp-iisph ([\w-]+)`\s*$", text, flags=re.M)
    return dict(zip(parts[1::2], parts[2::2]))


def test_every_command_and_option_is_documented():
    parser = _parser()
    page = (DOCS / "cli.md").read_text()
    sections = _sections(page)
    commands = _commands(parser)
    missing = []
    for action in parser._actions:  # the program's own options (--debug)
        missing += [f"warp-iisph {o}" for o in action.option_strings if not _documented(page, o)]
    for name, sub in commands.items():
        if name not in sections:
            missing.append(f"the section `warp-iisph {name}`")
            continue
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            if action.option_strings:
                missing += [
                    f"warp-iisph {name} {o}" for o in action.option_strings if not _documented(sections[name], o)
                ]
            else:
                shown = action.metavar or action.dest.upper()
                if f"`{shown}`" not in sections[name]:
                    missing.append(f"warp-iisph {name} {shown}")
    assert not missing, f"docs/cli.md does not document: {', '.join(missing)}"
    assert not set(sections) - set(commands), f"docs/cli.md documents no such command: {set(sections) - set(commands)}"
    readme = (ROOT / "README.md").read_text()
    assert not [n for n in commands if f"`warp-iisph {n}" not in readme], "README's command line at a glance"


def _fields(cls, skip=()) -> list:
    return [f.name for f in dataclasses.fields(cls) if f.name not in skip]


def scene_keys() -> set:
    """Every key a scene file takes, as docs/scenes.md writes it: ``physics.eta``,
    ``emitters[k].speed``, ``obstacles[k].motion.times``, ``bodies[k].density``."""
    keys = set(_fields(sc.Scene)) | set(getattr(scene_file, "TOP_KEYS", ()))
    for table, cls in (("physics", sc.Physics), ("output", sc.Output), ("surface", sc.SurfaceSettings)):
        keys |= {f"{table}.{f}" for f in _fields(cls)}
    keys |= {f"camera.{f}" for f in _fields(sc.Camera)}
    keys |= {f"emitters[k].{f}" for f in _fields(sc.Emitter)}
    keys |= {f"sinks[k].{f}" for f in _fields(sc.Sink)}
    keys |= {f"probes[k].{f}" for f in _fields(sc.Probe)}
    keys |= {"obstacles[k].motion"} | {f"obstacles[k].motion.{f}" for f in _fields(Motion)}
    # the shapes each place takes (``shape`` chooses one); base_dir is the scene file's folder,
    # set by the loader, and only obstacles move
    places = {"tank": (sc.Box, sc.MeshShape), "fluids[k]": (sc.Box, sc.Sphere)}
    places["obstacles[k]"] = (sc.Box, sc.Sphere, sc.MeshShape)
    places["bodies[k]"] = (sc.Box, sc.Sphere, sc.MeshShape)
    keys |= {f"bodies[k].{f}" for f in _fields(sc.Body, skip=("shape",))}
    for where, classes in places.items():
        keys.add(f"{where}.shape")
        only_obstacles = () if where == "obstacles[k]" else ("name", "sampling")  # the file refuses them elsewhere
        for cls in classes:
            keys |= {f"{where}.{f}" for f in _fields(cls, skip=("base_dir", "motion", *only_obstacles))}
    return keys


def test_every_scene_key_is_documented():
    page = (DOCS / "scenes.md").read_text()
    keys = scene_keys()
    missing = sorted(k for k in keys if f"`{k}`" not in page)
    assert not missing, f"docs/scenes.md does not document: {', '.join(missing)}"
    # and documents no key the scene does not take: the first cell of every row of its key tables
    rows = re.findall(r"^\| (`[^|]*`) \|", page, flags=re.M)
    named = {k for cell in rows for k in re.findall(r"`([^`]+)`", cell)}
    assert not named - keys, f"docs/scenes.md documents no such key: {sorted(named - keys)}"


def test_every_module_is_in_the_developers_layout():
    page = (DOCS / "developing.md").read_text()
    package = ROOT / "warp_iisph"
    modules = [
        p.relative_to(package).as_posix()
        for p in package.rglob("*.py")
        if "bundled" not in p.parts and (p.name != "__init__.py" or p.parent in (package, package / "sph" / "solvers"))
    ]
    missing = sorted(m for m in modules if f"`{m}`" not in page and f"`warp_iisph/{m}`" not in page)
    assert not missing, f"docs/developing.md's layout does not name: {', '.join(missing)}"
