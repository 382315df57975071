"""Advancing a scene in time: Simulation (time steps, dt, divergence checks) and replays of captured graphs."""

from .flows import LiquidFullWarning
from .simulation import DivergenceError, Simulation

__all__ = ["DivergenceError", "LiquidFullWarning", "Simulation"]
