"""Walls that complete the fluid's kernel gradient in the pressure force, not only its density.

Akinci et al.'s volumes ``psi_b = rho0 / sum_k W_bk`` make a fluid particle's density right beside
a wall: the walls fill the part of its kernel's support the liquid lacks, for ``W``. They do not
fill it for ``grad W``. In water settled beside a wall (a held bar's faces, a tank's floor) the
walls' sum ``sum_b psi_b grad W_ib`` is 2-4 % longer than the liquid's missing part
``-sum_j m grad W_ij``. In the symmetric pressure force a uniform pressure p
then pushes the layer at a wall away from it (``2 p / rho^2`` times the excess), and the layer
answers with less pressure than the field around it: 4-9 % below the hydrostatic fit at the
faces of a held bar, differently on its top and bottom faces, so that its buoyancy read 3-4 %
high and floating boxes stood 2-4 % high (docs/physics.md 6.2).

Once a step, after the densities, each fluid particle i near a wall gets the factor ``s_i`` on its
walls' gradients in the forces on it with which the walls complete the liquid's gradient sum
along the walls' own direction:

    s_i = 1 - (G_f + G_b) . G_b / (|G_b|^2 + (kappa rho0 / h)^2),
    G_f = sum_j m grad W_ij,  G_b = sum_b psi_b grad W_ib.

It multiplies the walls' terms of the pressure force (:func:`~.solvers.base.integrate`), of IISPH's
``d_ii`` and of the walls' pressures in ``sum_j d_ij p_j``, and the force sums that probes and
free bodies take (:mod:`.wall_forces`), so a wall's load stays the reaction of the force on the
liquid. It does not touch the density's rate of change (the advected density, ``a_ii``'s and
the Jacobi sum's divergence side): the density is summed from ``W``, and its change is what the
unscaled gradient says; scaling that side too left the wall layer compressed and made resting
water's pressure jump by 7 % where the step's length changes. Nor the walls' friction.

The regularisation ``kappa`` leaves particles a wall barely reaches (``|G_b|`` a few per cent of a
flat wall's ``0.5 rho0 / h``) as they are: their sums say more about the liquid's own packing than
about the wall. Where the liquid's side of the support is not full (a free surface within
reach: the particle's density well below rho0), ``G_f`` lacks that side too and says nothing of
the walls: the factor is taken in full from ``1 - FULL_FROM`` of rho0 up, not at all from
``1 - NONE_FROM`` down, linearly between. ``s_i`` is kept within ``1 -+ S_RANGE``.
"""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

KAPPA = 0.03  # regularisation, in units of rho0 / h (a flat wall's first layer has |G_b| = 0.5 rho0 / h)
FULL_FROM = wp.constant(0.02)  # density deficit (fraction of rho0) down to which the factor is taken in full
NONE_FROM = wp.constant(0.05)  # and from which not at all
S_RANGE = wp.constant(0.25)  # the factor stays within 1 -+ this


@wp.func
def gradient_factor(g_f: wp.vec3, g_b: wp.vec3, rho_i: float, rho0: float, regularisation: float) -> float:
    """``s_i`` from fluid particle i's sums ``G_f = sum_j m grad W_ij`` and ``G_b = sum_b psi_b
    grad W_ib`` and its density (see the module); summed where the walls' heads are
    (:func:`~.wall_pressure.wall_heads`), which walks the same lists once a step."""
    s = 1.0 - wp.dot(g_f + g_b, g_b) / (wp.dot(g_b, g_b) + regularisation * regularisation)
    s = wp.clamp(s, 1.0 - S_RANGE, 1.0 + S_RANGE)
    full = wp.clamp((rho_i / rho0 - 1.0 + NONE_FROM) / (NONE_FROM - FULL_FROM), 0.0, 1.0)
    return 1.0 + full * (s - 1.0)


def regularisation(model) -> float:
    """``kappa rho0 / h`` for ``model``'s liquid."""
    return KAPPA * model.physics.rho0 / model.spacing
