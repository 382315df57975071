"""The SPH method: the smoothing kernel, neighbour search and the pressure solvers (one step of time)."""
