"""The heave of a floating box by linear potential flow: the reference bodies.py's heave is set
against, computed for the box's own shape rather than taken from a table.

The box's heave added mass ``A(w)`` and radiation damping ``B(w)`` come from Capytaine (a
boundary-element solver of the linear radiation problem, after Nemoh; the ``bench`` extra), on
the box's wetted hull with a lid on its waterplane (which removes the irregular frequencies), in
water as deep as the pool, at frequencies up to ``W_MAX`` and at infinite frequency. The free decay
from rest where the simulated box is released follows from Cummins' equation, the time-domain
form of the same linear problem, for a body in water without walls:

    (M + A_inf) z'' + int_0^t K(t - s) z'(s) ds + k z = 0,   K(t) = (2 / pi) int_W_MIN^W_MAX B(w) cos(w t) dw,

with ``k`` the hydrostatic stiffness (the caller's: that of the simulated pool, whose level rises
as the box sinks). It is fitted with the same damped cosine as the simulation's record, so that
the two periods and damping ratios compare like with like. Linear theory holds for small motions
from still water: the simulated box is released about 2 cm below rest (half of its draft), after
a 0.5 s hold in water that has not quite settled, and the theory has no viscosity.
"""

from __future__ import annotations

import logging

import numpy as np

from warp_iisph.analysis import trapezoid

# rad/s: B(w) is 0.2 kg/s at 25 rad/s, and beyond it the 1 cm panels grow too coarse for the
# shorter waves (B rises spuriously to 0.9 at 30); the fitted decay moves by 0.1 % between a cut at
# 20 and one at 30 rad/s
W_MAX = 25.0
W_STEP = 0.25  # rad/s
# rad/s: below, the finite-depth Green function is out of range (kh < 0.1); B(1 rad/s) is 0.8 kg/s
# against 4.4 at its peak near 8, and the band below adds under 1 % to the integral of B
W_MIN = 1.0
PANEL = 0.01  # m, the hull's panel size (16 across the box's 0.16 m)


def radiation(side: float, draft: float, depth: float, rho: float = 1000.0, g: float = 9.81) -> dict:
    """Heave added mass and radiation damping of a square box ``side`` wide at ``draft`` in water
    ``depth`` deep, every ``W_STEP`` from ``W_MIN`` to ``W_MAX`` rad/s and at infinite frequency (Capytaine)."""
    import capytaine as cpt

    logging.getLogger("capytaine").setLevel(logging.ERROR)
    n_side, n_draft = round(side / PANEL), max(2, round(draft / PANEL))
    height = 2.0 * draft  # only the wetted part is kept
    mesh = cpt.mesh_parallelepiped(
        size=(side, side, height), center=(0.0, 0.0, 0.5 * height - draft), resolution=(n_side, n_side, 2 * n_draft)
    )
    hull = mesh.immersed_part()
    body = cpt.FloatingBody(
        mesh=hull, lid_mesh=hull.generate_lid(), dofs=cpt.rigid_body_dofs(only=["Heave"]), center_of_mass=(0, 0, 0)
    )
    solver = cpt.BEMSolver()
    omegas = np.arange(W_MIN, W_MAX + 0.5 * W_STEP, W_STEP)
    added, damping = [], []
    for w in [*omegas, np.inf]:
        problem = cpt.RadiationProblem(body=body, radiating_dof="Heave", omega=w, water_depth=depth, rho=rho, g=g)
        result = solver.solve(problem)
        added.append(float(result.added_masses["Heave"]))
        damping.append(float(result.radiation_dampings["Heave"]) if np.isfinite(w) else 0.0)
    return {
        "omega": omegas.tolist(),
        "added_mass": added[:-1],
        "damping": damping[:-1],
        "added_mass_infinite": added[-1],
        "panels": int(hull.nb_faces),
        "capytaine": cpt.__version__,
    }


def free_decay(mass: float, stiffness: float, rad: dict, z0: float, t_end: float, dt: float = 5e-4) -> tuple:
    """Cummins' equation from ``z = z0`` at rest: times and heave every ``dt`` up to ``t_end``."""
    w = np.asarray(rad["omega"])
    b = np.clip(np.asarray(rad["damping"]), 0.0, None)  # a panel's small negative value at the top frequencies
    t = np.arange(0.0, t_end + 0.5 * dt, dt)
    kernel = (2.0 / np.pi) * trapezoid(b[None, :] * np.cos(np.outer(t, w)), w, axis=1)
    inertia = mass + rad["added_mass_infinite"]
    z, v = np.zeros_like(t), np.zeros_like(t)
    z[0] = z0
    for n in range(len(t) - 1):
        memory = dt * np.dot(kernel[n::-1][: n + 1], v[: n + 1])  # int_0^t K(t - s) v(s) ds
        a = -(memory + stiffness * z[n]) / inertia
        v[n + 1] = v[n] + dt * a  # semi-implicit Euler: stable, no energy gained
        z[n + 1] = z[n] + dt * v[n + 1]
    return t, z


def natural_frequency(mass: float, stiffness: float, rad: dict) -> float:
    """The frequency where ``w^2 (M + A(w)) = k`` (the frequency-domain undamped resonance)."""
    w, a = np.asarray(rad["omega"]), np.asarray(rad["added_mass"])
    f = w**2 * (mass + a) - stiffness
    k = int(np.nonzero(np.diff(np.sign(f)))[0][0])
    return float(w[k] - f[k] * (w[k + 1] - w[k]) / (f[k + 1] - f[k]))
