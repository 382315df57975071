"""Time-step methods. WCSPH and IISPH share neighbours, density, forces and integration
(:mod:`.base`); each module adds only its pressure computation."""

from .base import STAGES, SPHSolver
from .iisph import IISPHSolver
from .wcsph import WCSPHSolver

SOLVERS = {"iisph": IISPHSolver, "wcsph": WCSPHSolver}


def make_solver(model) -> SPHSolver:
    """The solver of ``model.physics.method`` for ``model``."""
    return SOLVERS[model.physics.method](model)


__all__ = ["STAGES", "SOLVERS", "SPHSolver", "IISPHSolver", "WCSPHSolver", "make_solver"]
