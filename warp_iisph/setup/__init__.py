"""A scene turned into particles on a device: fluid lattice, tank walls, rasterised meshes,
boundary psi, Model and State."""

from .build import build_model
from .model import Model, State

__all__ = ["Model", "State", "build_model"]
