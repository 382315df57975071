"""How long a step is: a requested one, the scene's fixed dt (cut into substeps where it is longer
than the flow allows), or the CFL rule; the steps up to a landing time (a frame, the end) made
equal. All on the device (:func:`choose_dt`), so a graph replays it without the host."""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

SQRT2 = wp.constant(wp.float64(1.4142135623730951))


@wp.func
def fixed_step_limit(h: wp.float64, speed: wp.float64, longest: wp.float64) -> wp.float64:
    """The longest step a fixed dt may be cut into: ``h / speed`` (``longest``, the fixed dt, when
    nothing moves)."""
    if speed > wp.float64(0.0):
        return wp.min(longest, h / speed)
    return longest


# steps fitted to a landing time are equal from this many steps before it on
LANDING_STEPS = wp.constant(wp.float64(64.0))


@wp.func
def fit_to_landing(step: wp.float64, to_end: wp.float64) -> wp.float64:
    """A step fitted to land on a time ``to_end`` ahead: the steps up to it are equal, as few as
    fit at ``step`` (together up to a twentieth of a step longer, rather than one sliver more); a
    landing further than :data:`LANDING_STEPS` steps away leaves the step as it is. A step
    shortened alone would change the pressure the next one starts from (half of this step's, the
    warm start) and the IISPH pressure's response to the state's compression, which grows as
    1/dt^2: resting water's pressure kicked by percents at every frame."""
    if to_end > LANDING_STEPS * step:
        return step
    n = wp.max(wp.ceil(to_end / step - wp.float64(0.05) - wp.float64(1.0e-9)), wp.float64(1.0))
    return to_end / n


@wp.struct
class StepRule:
    """What chooses a step: the run's constants (s, m, m/s)."""

    fixed_dt: wp.float64  # the scene's fixed dt; not positive for the CFL rule
    cfl: wp.float64
    h: wp.float64  # the particle spacing
    velocity_scale: wp.float64  # the speed the CFL rule assumes at least, sqrt(2 g y_top)
    signal_speed: wp.float64  # WCSPH's speed of sound, 0 for the incompressible methods
    dt_min: wp.float64
    dt_max: wp.float64
    split: int  # whether a fixed dt longer than a step may be is cut into substeps


@wp.struct
class Clock:
    """The loop's clock on the device, and where it must stop."""

    time: wp.array(dtype=wp.float64)
    end: wp.array(dtype=wp.float64)  # the landing time of this loop
    dt_request: wp.array(dtype=wp.float64)  # a step asked for; not positive: the rules choose
    dt: wp.array(dtype=wp.float64)  # this step's
    steps: wp.array(dtype=wp.int32)  # steps taken in the run
    slot: wp.array(dtype=wp.int32)  # the next log row
    step_limit: wp.array(dtype=wp.int32)  # the most steps this loop may take
    keep_going: wp.array(dtype=wp.int32)


@wp.struct
class Substeps:
    """A fixed dt being cut into substeps."""

    left: wp.array(dtype=wp.float64)  # what is left of the fixed step being cut
    done: wp.array(dtype=wp.int32)  # substeps taken of it
    pieces: wp.array(dtype=wp.int32)  # how many it is cut into (logged)


@wp.kernel
def choose_dt(
    rule: StepRule,
    clock: Clock,
    sub: Substeps,
    max_speed2: wp.array(dtype=float),
    dt32: wp.array(dtype=float),
):
    """The step: a requested one, the scene's fixed dt, or the CFL rule
    ``cfl h / (max(max|v|, sqrt(2 g y_top)) + c)`` clamped to [dt_min, dt_max] (the viscosity
    takes sub-steps of its own where a step exceeds its limit, ``sph.solvers.forces``); then
    fitted to land on the end time: the steps up to it are equal (:func:`fit_to_landing`; for a
    fixed dt cut into substeps, equal fixed steps, each cut).

    With ``split``, a fixed dt longer than a step may be is cut into equal substeps (``pieces``:
    how many its step is cut into): no longer than ``h / (max(max|v|, 2 sqrt(g y_top)) + c)``, so
    that no particle crosses more than a spacing in a step and, from rest,
    ``dt^2 g y_top / h^2 <= 1/4`` (resting IISPH water bounces at 0.49 and its pressure alternates
    from step to step at 0.37). ``sub_left`` is what is left of the fixed step being cut
    (recounted every substep, as speeds change); a landing time inside it ends it there."""
    fixed_dt, cfl, h, split = rule.fixed_dt, rule.cfl, rule.h, rule.split
    velocity_scale, signal_speed, dt_min, dt_max = rule.velocity_scale, rule.signal_speed, rule.dt_min, rule.dt_max
    time, end, sub_left, sub_done = clock.time, clock.end, sub.left, sub.done
    dt = clock.dt_request[0]
    n = wp.int32(1)
    splitting = False
    if dt <= wp.float64(0.0):
        dt = fixed_dt
        if dt > wp.float64(0.0) and split != 0:
            splitting = True
            left = sub_left[0]
            to_end = end[0] - time[0]
            if left <= wp.float64(0.0):
                # a new fixed step, fitted to the landing time (a frame, the end) as the CFL step is
                left = fit_to_landing(dt, to_end)
                sub_done[0] = 0
            elif to_end < left:
                left = to_end  # a landing inside the fixed step being cut (a new end time) ends it there
            # from rest sqrt(2) times the free-fall speed: dt^2 g y_top / h^2 <= 1/4, where IISPH
            # water still rests with a steady pressure (about 0.3; docs/physics.md 4.12)
            speed = wp.max(wp.float64(wp.sqrt(max_speed2[0])), SQRT2 * velocity_scale) + signal_speed
            pieces_left = wp.max(wp.ceil(left / fixed_step_limit(h, speed, dt) - wp.float64(1.0e-6)), wp.float64(1.0))
            dt = left / pieces_left
            sub_left[0] = left
            n = sub_done[0] + wp.int32(pieces_left)
    if dt <= wp.float64(0.0):
        speed = wp.max(wp.float64(wp.sqrt(max_speed2[0])), velocity_scale) + signal_speed
        dt = dt_max
        if speed > wp.float64(0.0):
            dt = cfl * h / speed
        dt = wp.min(wp.max(dt, dt_min), dt_max)
    left = end[0] - time[0]
    if splitting:
        if left - dt < wp.float64(1.0e-9) + wp.float64(0.05) * dt:
            dt = left
    else:
        dt = fit_to_landing(dt, left)
    if splitting:
        rest = sub_left[0] - dt
        if rest <= wp.float64(1.0e-9) * fixed_dt:
            sub_left[0] = wp.float64(0.0)
        else:
            sub_left[0] = rest
            sub_done[0] = sub_done[0] + 1
    sub.pieces[0] = n
    clock.dt[0] = dt
    dt32[0] = float(dt)
