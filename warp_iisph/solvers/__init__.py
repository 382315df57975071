"""Time-step methods. WCSPH and IISPH share neighbours, density, forces and integration
(:mod:`.common`); each module adds only its pressure computation."""

from .common import STAGES, SPHSolver
from .iisph import IISPHSolver
from .wcsph import WCSPHSolver

SOLVERS = {"iisph": IISPHSolver, "wcsph": WCSPHSolver}


def make_solver(model, physics) -> SPHSolver:
    return SOLVERS[physics.method](model, physics)


__all__ = ["STAGES", "SOLVERS", "SPHSolver", "IISPHSolver", "WCSPHSolver", "make_solver"]
