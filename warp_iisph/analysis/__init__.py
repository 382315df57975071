"""Measurements on simulation results against experiments and analytic solutions."""

import numpy as np

# NumPy's trapezoidal rule: ``trapezoid`` since NumPy 2, ``trapz`` before (the package's floor is 1.24)
trapezoid = getattr(np, "trapezoid", None) or np.trapz
