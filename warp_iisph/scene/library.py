"""The scenes shipped with the package (``bundled/*.toml``, meshes in ``bundled/meshes/``), by name."""

from __future__ import annotations

from pathlib import Path

from .checks import SceneFileError

BUNDLED = Path(__file__).resolve().parent / "bundled"


def bundled_scenes() -> dict[str, Path]:
    """Scene files shipped with the package, by name."""
    if not BUNDLED.is_dir():
        return {}
    return {p.stem: p for p in sorted(BUNDLED.glob("*.toml"))}


def resolve_scene(name_or_path: str) -> Path:
    """A scene file path, or the name of a bundled scene."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise SceneFileError(f"{name_or_path}: scene file not found")
        return p
    bundled = bundled_scenes()
    if name_or_path in bundled:
        return bundled[name_or_path]
    raise SceneFileError(
        f"scene {name_or_path!r}: not a file and not a bundled scene ({', '.join(bundled) or 'none found'})"
    )


def describe(path: Path) -> str:
    """A scene file's first comment line (what the scene shows)."""
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            return line.lstrip("# ").strip()
    return ""
