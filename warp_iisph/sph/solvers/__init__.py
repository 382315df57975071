"""Time-step methods. WCSPH and IISPH share neighbours, density, forces and integration
(:mod:`.base`); each module adds only its pressure computation. DFSPH shares the neighbours,
density and forces and runs its own step (two pressure solves, its own integration)."""

from .base import STAGES, SPHSolver
from .dfsph import DFSPHSolver
from .iisph import IISPHSolver
from .wcsph import WCSPHSolver

SOLVERS = {"iisph": IISPHSolver, "wcsph": WCSPHSolver, "dfsph": DFSPHSolver}


def make_solver(model) -> SPHSolver:
    """The solver of ``model.physics.method`` for ``model``."""
    return SOLVERS[model.physics.method](model)


__all__ = ["STAGES", "SOLVERS", "SPHSolver", "DFSPHSolver", "IISPHSolver", "WCSPHSolver", "make_solver"]
