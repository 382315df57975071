"""Make the obstacle meshes of the bundled scenes from trimesh primitives.

    python warp_iisph/scene/bundled/meshes/make_meshes.py      # rewrites the .obj files beside this script

Each mesh is built around its own origin (metres, y up); the scene files place it with
``translate``. Every part is a closed solid, so the fluid-clearing inside test applies.
"""

from pathlib import Path

import numpy as np
import trimesh
from trimesh.creation import annulus, box, capsule, cylinder
from trimesh.transformations import rotation_matrix, translation_matrix

HERE = Path(__file__).resolve().parent


def moved(mesh, offset=(0.0, 0.0, 0.0), angle=0.0, axis=(0.0, 1.0, 0.0)):
    mesh.apply_transform(translation_matrix(offset) @ rotation_matrix(angle, axis))
    return mesh


def submarine() -> trimesh.Trimesh:
    """A 0.6 m submarine along x: capsule hull, a sail on top, a cross of tail fins."""
    hull = moved(capsule(height=0.44, radius=0.08, count=[24, 24]), angle=np.pi / 2)
    sail = moved(box(extents=[0.14, 0.1, 0.04]), offset=(0.05, 0.11, 0.0))
    fin_h = moved(box(extents=[0.08, 0.02, 0.24]), offset=(-0.27, 0.0, 0.0))
    fin_v = moved(box(extents=[0.08, 0.2, 0.02]), offset=(-0.27, 0.0, 0.0))
    return trimesh.util.concatenate([hull, sail, fin_h, fin_v])


def upper_tray() -> trimesh.Trimesh:
    """An open-top tray, inner 0.4 x 0.25 x 0.3 m with 4 cm walls, its floor open over the last
    0.1 m in x: liquid drains through that slot."""
    t = 0.04
    parts = [
        moved(box(extents=[0.3 + t, t, 0.3 + 2 * t]), offset=(-0.07, -t / 2, 0.0)),  # x -0.24 .. 0.1
        moved(box(extents=[t, 0.25 + t, 0.3 + 2 * t]), offset=(-0.2 - t / 2, 0.25 / 2 - t / 2, 0.0)),
        moved(box(extents=[t, 0.25 + t, 0.3 + 2 * t]), offset=(0.2 + t / 2, 0.25 / 2 - t / 2, 0.0)),
        moved(box(extents=[0.4, 0.25 + t, t]), offset=(0.0, 0.25 / 2 - t / 2, -0.15 - t / 2)),
        moved(box(extents=[0.4, 0.25 + t, t]), offset=(0.0, 0.25 / 2 - t / 2, 0.15 + t / 2)),
    ]
    return trimesh.util.concatenate(parts)


def lower_cup() -> trimesh.Trimesh:
    """A round cup, inner radius 0.18 m, 0.25 m deep, 4 cm wall and floor."""
    wall = moved(
        annulus(r_min=0.18, r_max=0.22, height=0.29, sections=48),
        offset=(0, 0.145, 0),
        angle=-np.pi / 2,
        axis=(1, 0, 0),
    )
    floor = moved(
        cylinder(radius=0.22, height=0.04, sections=48), offset=(0, 0.02, 0), angle=-np.pi / 2, axis=(1, 0, 0)
    )
    return trimesh.util.concatenate([wall, floor])


def wine_glass() -> trimesh.Trimesh:
    """A wine glass standing on y = 0, its axis along y: a foot of radius 4 cm, a stem, a bowl 5 cm
    wide inside at the rim and 9 cm deep (about 0.2 l), glass 4 mm thick: one closed solid, the
    profile (radius, height) revolved about the axis."""
    outer = [
        (0.0, 0.0),
        (0.04, 0.0),
        (0.04, 0.004),
        (0.008, 0.008),
        (0.005, 0.02),
        (0.005, 0.07),
        (0.02, 0.078),
        (0.035, 0.095),
        (0.043, 0.12),
        (0.045, 0.145),
        (0.044, 0.17),
    ]
    inner = [(0.040, 0.17), (0.041, 0.145), (0.039, 0.122), (0.031, 0.099), (0.017, 0.084), (0.0, 0.081)]
    profile = np.array(outer + inner)
    mesh = trimesh.creation.revolve(profile, sections=64)  # about z, from the profile's (x, z)
    mesh.apply_transform(rotation_matrix(-np.pi / 2, (1, 0, 0)))  # z up -> y up
    mesh.fix_normals()
    return mesh


def main() -> None:
    for name, make in (
        ("submarine", submarine),
        ("upper_tray", upper_tray),
        ("lower_cup", lower_cup),
        ("wine_glass", wine_glass),
    ):
        mesh = make()
        mesh.export(HERE / f"{name}.obj")
        print(
            f"{name}.obj: {len(mesh.faces)} triangles, "
            f"bounds {np.round(mesh.bounds, 3).tolist()}, watertight {mesh.is_watertight}"
        )


if __name__ == "__main__":
    main()
