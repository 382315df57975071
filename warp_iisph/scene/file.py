"""Scene files: TOML in, a validated :class:`~warp_iisph.scene.Scene` out.

Every key is checked: an unknown key, a wrong type or an out-of-range value raises
:class:`SceneFileError` whose one-line message names the file and the key. The format is
documented in ``docs/scenes.md``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import sys
from pathlib import Path

from .bodies import Body
from .checks import SceneFileError, folder_name
from .description import Scene
from .flows import Emitter, Sink
from .library import resolve_scene
from .probes import Probe
from .settings import Camera, Output, Physics, SurfaceSettings
from .shapes import Box, MeshShape, Sphere

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

TOP_KEYS = {
    "name",
    "spacing",
    "tank",
    "fluids",
    "obstacles",
    "physics",
    "output",
    "surface",
    "camera",
    "emitters",
    "sinks",
    "probes",
    "max_particles",
    "bodies",
}
SHAPE_KEYS = {
    "box": {"lower", "upper"},
    "sphere": {"center", "radius"},
    "mesh": {"path", "translate", "rotate", "scale", "shell"},
}
# keys only an obstacle takes: its name (probes refer to it), and a box's sampling
OBSTACLE_KEYS = {"name"}
BOX_OBSTACLE_KEYS = {"sampling"}


def parse_value(text: str):
    """A --set value as TOML (numbers, booleans, arrays, quoted strings), else a bare string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_override(data: dict, assignment: str) -> None:
    """Apply ``key.path=value`` to the raw scene table; list items by index (``fluids.0.radius``)."""
    if "=" not in assignment:
        raise SceneFileError(f"--set {assignment!r}: must be KEY=VALUE, e.g. spacing=0.01 or physics.eta=0.0005")
    key, _, text = assignment.partition("=")
    parts = key.strip().split(".")
    node = data
    if not all(parts):
        raise SceneFileError(f"--set {key.strip()!r}: must be a dotted key, e.g. physics.eta or fluids.0.radius")
    for depth, part in enumerate(parts[:-1]):
        where = ".".join(parts[: depth + 1])
        if isinstance(node, list):
            if not re.fullmatch(r"[0-9]+", part) or int(part) >= len(node):
                raise SceneFileError(f"--set {key}: {where} must index one of the {len(node)} items (0, 1, ...)")
            node = node[int(part)]
        elif part not in node and re.fullmatch(r"[0-9]+", parts[depth + 1]):
            raise SceneFileError(f"--set {key.strip()}: the scene has no {where} to index; add them to the file")
        else:
            node = node.setdefault(part, {})
        if not isinstance(node, (dict, list)):  # e.g. spacing.x: spacing is a number
            raise SceneFileError(f"--set {key.strip()}: {where} is a value ({node!r}), not a table")
    last = parts[-1]
    if isinstance(node, list):
        raise SceneFileError(f"--set {key.strip()}: cannot replace a whole list item")
    node[last] = parse_value(text.strip())


def _check_keys(table, allowed: set, where: str) -> dict:
    if not isinstance(table, dict):
        raise ValueError(f"{where}: must be a table")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ValueError(
            f"{where}{'.' if where else ''}{unknown[0]}: unknown key; allowed: {', '.join(sorted(allowed))}"
        )
    return table


def _shape(table, where: str, allowed: tuple, base_dir: Path, movable: bool = False):
    extra = {"shape", "motion"} | OBSTACLE_KEYS if movable else {"shape"}
    boxed = BOX_OBSTACLE_KEYS if movable else set()
    _check_keys(table, extra | boxed | set().union(*(SHAPE_KEYS[s] for s in allowed)), where)
    kind = table.get("shape", "box")
    if kind not in allowed:
        raise ValueError(f"{where}.shape = {kind!r}: must be one of {', '.join(allowed)}")
    own = extra | SHAPE_KEYS[kind] | (boxed if kind == "box" else set())
    others = sorted(set(table) - own)
    if others:  # a key of another shape (the first check passed it)
        shapes = [s for s in allowed if others[0] in SHAPE_KEYS[s] or (s == "box" and others[0] in boxed)]
        raise ValueError(f"{where}.{others[0]}: a key of shape = {' or '.join(map(repr, shapes))}, not of {kind!r}")
    missing = [
        k for k in sorted(SHAPE_KEYS[kind]) if k not in table and k in ("lower", "upper", "center", "radius", "path")
    ]
    if missing:
        raise ValueError(f"{where}.{missing[0]}: required for shape = {kind!r}")
    args = {k: v for k, v in table.items() if k != "shape"}
    if kind == "box":
        return Box(**args)
    if kind == "sphere":
        return Sphere(**args)
    return MeshShape(**args, base_dir=str(base_dir))


BODY_KEYS = {f.name for f in dataclasses.fields(Body)} - {"shape"}


def _body(table, where: str, base_dir: Path) -> Body:
    """A ``[[bodies]]`` table: a shape's keys (as an obstacle's, without motion) and the body's."""
    _check_keys(table, {"shape"} | set().union(*SHAPE_KEYS.values()) | BODY_KEYS, where)
    shape = _shape({k: v for k, v in table.items() if k not in BODY_KEYS}, where, ("box", "sphere", "mesh"), base_dir)
    return Body(shape, **{k: v for k, v in table.items() if k in BODY_KEYS})


def _record(cls, table, where: str):
    """A table as a ``cls`` record: unknown keys and missing required ones name the key."""
    _check_keys(table, _fields(cls), where)
    for field_ in dataclasses.fields(cls):
        if (
            field_.default is dataclasses.MISSING
            and field_.default_factory is dataclasses.MISSING
            and field_.name not in table
        ):
            raise ValueError(f"{where}.{field_.name}: required")
    return cls(**table)


def _fields(cls) -> set:
    return {f.name for f in dataclasses.fields(cls)}


def scene_from_dict(data: dict, base_dir: Path = Path("."), default_name: str = "scene") -> Scene:
    """Build and validate a scene from a parsed TOML table (raises ValueError)."""
    _check_keys(data, TOP_KEYS, "")
    if "spacing" not in data:
        raise ValueError("spacing: required (metres, the particle diameter)")
    if "tank" not in data:
        raise ValueError("tank: required (a box with lower/upper, or shape = 'mesh')")
    fluids = data.get("fluids", [])
    obstacles = data.get("obstacles", [])
    emitters = data.get("emitters", [])
    sinks = data.get("sinks", [])
    probes = data.get("probes", [])
    bodies = data.get("bodies", [])
    for key, value in (
        ("fluids", fluids),
        ("obstacles", obstacles),
        ("emitters", emitters),
        ("sinks", sinks),
        ("probes", probes),
        ("bodies", bodies),
    ):
        if not isinstance(value, list):
            raise ValueError(f"{key}: must be an array of tables ([[{key}]])")
    physics = _check_keys(data.get("physics", {}), _fields(Physics), "physics")
    output = _check_keys(data.get("output", {}), _fields(Output), "output")
    surface = _check_keys(data.get("surface", {}), _fields(SurfaceSettings), "surface")
    camera = _check_keys(data.get("camera", {}), _fields(Camera), "camera")
    name = folder_name(
        data.get("name", default_name), "name" if "name" in data else "name (the file's, as it gives none)"
    )
    scene = Scene(
        spacing=data["spacing"],
        tank=_shape(data["tank"], "tank", ("box", "mesh"), base_dir),
        fluids=[_shape(f, f"fluids[{k}]", ("box", "sphere"), base_dir) for k, f in enumerate(fluids)],
        obstacles=[
            _shape(o, f"obstacles[{k}]", ("box", "sphere", "mesh"), base_dir, movable=True)
            for k, o in enumerate(obstacles)
        ],
        physics=Physics(**physics),
        output=Output(**output),
        surface=SurfaceSettings(**surface),
        name=name,
        camera=Camera(**camera),
        emitters=[_record(Emitter, e, f"emitters[{k}]") for k, e in enumerate(emitters)],
        sinks=[_record(Sink, s, f"sinks[{k}]") for k, s in enumerate(sinks)],
        probes=[_record(Probe, p, f"probes[{k}]") for k, p in enumerate(probes)],
        max_particles=data.get("max_particles"),
        bodies=[_body(b, f"bodies[{k}]", base_dir) for k, b in enumerate(bodies)],
    )
    return scene.validate()


def _shape_table(shape) -> dict:
    if isinstance(shape, Box):
        table = {"shape": "box", "lower": list(shape.lower), "upper": list(shape.upper)}
    elif isinstance(shape, Sphere):
        table = {"shape": "sphere", "center": list(shape.center), "radius": shape.radius}
    else:
        table = {
            "shape": "mesh",
            "path": str((Path(shape.base_dir) / shape.path).resolve()),
            "translate": list(shape.translate),
            "rotate": list(shape.rotate),
            "scale": list(shape.scale) if isinstance(shape.scale, tuple) else shape.scale,
        }
        if shape.shell:
            table["shell"] = True
    if getattr(shape, "name", None) is not None:
        table["name"] = shape.name
    if getattr(shape, "sampling", "faces") != "faces":
        table["sampling"] = shape.sampling
    if shape.motion is not None:
        table["motion"] = _settings_table(shape.motion)
    return table


def _settings_table(settings) -> dict:
    # TOML has no null: a setting left at None (e.g. physics.dt, the CFL rule) is left out
    return {
        k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(settings).items() if v is not None
    }


def scene_to_dict(scene: Scene) -> dict:
    """A validated scene as the table of a scene file (mesh paths absolute): what
    :func:`scene_from_dict` reads back into the same scene. A run records it, to be resumed."""
    return {
        "name": scene.name,
        "spacing": scene.spacing,
        "tank": _shape_table(scene.tank),
        "fluids": [_shape_table(f) for f in scene.fluids],
        "obstacles": [_shape_table(o) for o in scene.obstacles],
        "physics": _settings_table(scene.physics),
        "output": _settings_table(scene.output),
        "surface": _settings_table(scene.surface),
        "camera": _settings_table(scene.camera),
        "emitters": [_settings_table(e) for e in scene.emitters],
        "sinks": [_settings_table(s) for s in scene.sinks],
        **({"probes": [_settings_table(p) for p in scene.probes]} if scene.probes else {}),
        **({"max_particles": scene.max_particles} if scene.max_particles is not None else {}),
        **({"bodies": [_body_table(b) for b in scene.bodies]} if scene.bodies else {}),
    }


def _body_table(body: Body) -> dict:
    table = _shape_table(body.shape)
    for key in sorted(BODY_KEYS):
        value = getattr(body, key)
        if key == "release_time" and value == 0.0:
            continue  # free from the start: the table (and so the geometry's hash) as before the key existed
        if value is not None:
            table[key] = list(value) if isinstance(value, (tuple, list)) else value
    return table


# what a resumed run keeps: its particles (--set may change physics, output, surface and camera)
GEOMETRY_KEYS = ("spacing", "tank", "fluids", "obstacles", "emitters", "sinks", "max_particles", "bodies")


def scene_fingerprint(scene: Scene) -> dict:
    """What a checkpoint was taken of: a hash of the scene's geometry (its table, mesh paths
    included), of each mesh file's contents, by key (``tank``, ``obstacles[0]``), and of its probes,
    with their sampling interval, so that a resume can say what changed."""
    table = scene_to_dict(scene)
    # a scene without bodies hashes as it did before they existed
    parts = {k: table.get(k) for k in GEOMETRY_KEYS if k in table or k != "bodies"}
    geometry = json.dumps(parts, sort_keys=True, separators=(",", ":"))
    meshes = {}
    shapes = [("tank", scene.tank), *((f"obstacles[{k}]", o) for k, o in enumerate(scene.obstacles))]
    shapes += [(f"bodies[{k}]", b.shape) for k, b in enumerate(scene.bodies)]
    for key, shape in shapes:
        if isinstance(shape, MeshShape):
            path = Path(shape.base_dir) / shape.path
            try:
                meshes[key] = hashlib.sha256(path.read_bytes()).hexdigest()
            except OSError as e:
                raise ValueError(f"{key}.path = {shape.path!r}: cannot be read ({e.strerror})") from None
    # the sensors probes.csv's columns were read at: a resume must read the same ones
    probes = json.dumps(table.get("probes") or [], sort_keys=True, separators=(",", ":"))
    return {
        "geometry": hashlib.sha256(geometry.encode()).hexdigest(),
        "meshes": meshes,
        "probes": hashlib.sha256(probes.encode()).hexdigest(),
        # and how often they were read: probes.csv's rows keep one interval
        "probe_interval": float(scene.output.probe_interval) if scene.probes else None,
    }


def load_scene(path, overrides=()) -> Scene:
    """Read a scene file (a path or a bundled name), apply ``--set`` overrides (``KEY=VALUE``
    strings; one string is one override), validate. Every problem raises
    :class:`SceneFileError` with a one-line message naming the file."""
    if isinstance(overrides, str):
        overrides = [overrides]
    if overrides is None or not all(isinstance(a, str) for a in overrides):
        raise TypeError(f"overrides = {overrides!r}: must be KEY=VALUE strings, e.g. ['spacing=0.02']")
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path = {path!r}: must be a scene file's path or a bundled scene's name")
    path = resolve_scene(str(path))
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise SceneFileError(f"{path}: not valid TOML: {e}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise SceneFileError(f"{path}: cannot read: {e}") from None
    for assignment in overrides:
        try:
            apply_override(data, assignment)
        except SceneFileError as e:  # the override's own fault, said with the file it changes
            raise SceneFileError(f"{path}, {e}") from None
    try:
        return scene_from_dict(data, path.parent, default_name=path.stem)
    except SceneFileError:
        raise
    except (ValueError, TypeError) as e:
        given = _override_named(str(e), overrides)
        raise SceneFileError(f"{path}{f', --set {given}' if given else ''}: {e}") from None


def _override_named(message: str, overrides) -> str | None:
    """The ``--set`` assignment whose key, or the list entry holding it, a validation message names
    first (``obstacles.1.name`` is shown as ``obstacles[1].name``, its entry as ``obstacles[1]``),
    so that the message says where the value came from."""
    shown = {a: re.sub(r"\.(\d+)(?=\.|$)", r"[\1]", a.split("=", 1)[0].strip()) for a in overrides}
    entries = {a: [k[: m.end()] for m in reversed(list(re.finditer(r"\[\d+\]", k)))] for a, k in shown.items()}
    for candidates in ({a: [k] for a, k in shown.items()}, entries):  # the key itself first, then its entry
        for assignment, names in candidates.items():
            if any(re.match(re.escape(n) + r"(\s|:|\.|\[|$)", message) for n in names):
                return assignment
    return None
