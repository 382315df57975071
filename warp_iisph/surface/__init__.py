"""The liquid's surface from its particles: sparse distance field, marching cubes, smoothing."""

from .reconstructor import SurfaceMesh, SurfaceReconstructor

__all__ = ["SurfaceMesh", "SurfaceReconstructor"]
