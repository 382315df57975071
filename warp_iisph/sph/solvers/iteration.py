"""The one owner of an iterative pressure solve: the loop on the device, its convergence test,
its iteration count and its error statistic.

A method hands :meth:`IterativeSolve.run` two callables: ``iterate`` computes one iteration's
update (kept aside, not yet applied) and each particle's error into :attr:`IterativeSolve.error`;
``advance(blend)`` applies the update. The loop sums the errors (float64), counts the iteration,
decides on the device whether another follows (``wp.capture_while``: a captured graph holds the
whole loop) and then advances. Nothing in it allocates, so it may sit in a conditional graph body.

A density solve ends where its error reaches eta: in the iteration that takes the mean error
below eta, ``blend`` is the share of the way from the last iterate to this one at which the error,
taken as linear between them, reaches eta; the update is affine in the unknowns (but for the
clamp at zero), so applying that share of this iteration's update gives the update of the iterate
at eta. The result then does not jump with the integer iteration count from step to step, which
moved resting water's pressure by percents (docs/physics.md 4.12). ``blend`` is negative where the
whole update applies.

Relaxed Jacobi on IISPH's system with extrapolated wall pressures has a slowly growing long-wave
mode where every particle is near a wall (a column four spacings deep between two walls: 2.3 % an
iteration, ahead of the decaying ones from about 150 iterations on; docs/pressure_solve.md). A
density solve therefore also stops where its mean error, above eta, has grown to ``GROWTH`` times
the least it reached (never before ``min_iterations``), and keeps that iteration's input
pressures (``blend`` 0), as a solve stopped by ``max_iterations`` keeps its last: the step goes on
with the error it logs, instead of pressures that run away to 1e30 Pa.
"""

from __future__ import annotations

from collections.abc import Callable

import warp as wp

from ...engine.launch import launch
from ...engine.reduce import sum_into

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

GROWTH = wp.constant(2.0)  # a density solve whose error grows to this many times its least stops (module docstring)


@wp.kernel
def convergence_test(
    error_sum: wp.array(dtype=wp.float64),
    n: int,
    eta: wp.float64,
    min_iterations: int,
    max_iterations: int,
    ends_at_eta: int,
    iterations: wp.array(dtype=wp.int32),
    keep_going: wp.array(dtype=wp.int32),
    last_error_sum: wp.array(dtype=wp.float64),
    least_error_sum: wp.array(dtype=wp.float64),
    blend: wp.array(dtype=float),
):
    """Count the iteration; stop once the mean error is at most eta (after ``min_iterations``) or at
    ``max_iterations``. With ``ends_at_eta``, where the error crossed eta in this iteration,
    ``blend`` is the share of the way from the last iterate to this one at which it reaches eta
    and the error sum reported is eta's; otherwise (and always without ``ends_at_eta``) ``blend``
    is negative. With ``ends_at_eta`` it also stops (after ``min_iterations``) where the error,
    above eta, has grown to ``GROWTH`` times the least of this solve (``least_error_sum``), with
    ``blend`` 0: the input pressures kept."""
    it = iterations[0] + 1
    iterations[0] = it
    mean = error_sum[0] / wp.float64(n)
    converged = it >= min_iterations and mean <= eta
    least = wp.min(least_error_sum[0], error_sum[0])
    least_error_sum[0] = least
    growing = ends_at_eta != 0 and it >= min_iterations and mean > eta and error_sum[0] > wp.float64(GROWTH) * least
    keep_going[0] = wp.where(converged or growing or it >= max_iterations, 0, 1)
    b = float(-1.0)
    if growing:
        b = float(0.0)
    elif ends_at_eta != 0:
        last = last_error_sum[0] / wp.float64(n)
        if converged and it > 1 and last > eta and last > mean:
            b = float((last - eta) / (last - mean))
            # reported as eta: a hair under it, so that the logged mean (sum / n) never rounds above eta
            error_sum[0] = eta * wp.float64(n) * (wp.float64(1.0) - wp.float64(1.0e-15))
        last_error_sum[0] = error_sum[0]
    blend[0] = b


class IterativeSolve:
    """The device state of one iterative solve over up to ``capacity`` particles: each
    particle's error (:attr:`error`, float64), their sum (:attr:`error_sum`, the step's logged
    error is its mean), the iteration count (:attr:`iterations`) and where it ends (``blend``).
    ``ends_at_eta``: the density solves' ending (module docstring); off, the last iteration's
    update applies whole."""

    def __init__(self, capacity: int, device, ends_at_eta: bool = True):
        self.ends_at_eta = bool(ends_at_eta)
        self.error = wp.zeros(max(capacity, 1), dtype=wp.float64, device=device)
        self.error_sum = wp.zeros(1, dtype=wp.float64, device=device)
        self.iterations = wp.zeros(1, dtype=wp.int32, device=device)
        self.keep_going = wp.zeros(1, dtype=wp.int32, device=device)
        self._last_error_sum = wp.zeros(1, dtype=wp.float64, device=device)
        self._least_error_sum = wp.zeros(1, dtype=wp.float64, device=device)
        self.blend = wp.zeros(1, dtype=float, device=device)

    def run(
        self,
        n: int,
        eta: float,
        min_iterations: int,
        max_iterations: int,
        iterate: Callable[[], None],
        advance: Callable[[wp.array], None],
    ) -> None:
        """Iterate until converged (see the class and module docstrings); on the device."""
        self.iterations.zero_()
        self._last_error_sum.zero_()
        self._least_error_sum.fill_(1.0e300)
        self.keep_going.fill_(1)
        test = [
            self.error_sum,
            max(n, 1),
            wp.float64(eta),
            int(min_iterations),
            int(max_iterations),
            int(self.ends_at_eta),
        ]
        state = [self.iterations, self.keep_going, self._last_error_sum, self._least_error_sum, self.blend]

        def body():
            iterate()
            sum_into(self.error, n, self.error_sum)
            launch(convergence_test, dim=1, inputs=test + state, device=self.error.device)
            advance(self.blend)

        wp.capture_while(self.keep_going, body)

    def stats(self) -> tuple[wp.array, wp.array]:
        """The device sum of the final errors and the iteration count, for the step's record."""
        return self.error_sum, self.iterations
