"""Settings of a scene besides its shapes: physics, output, surface reconstruction, camera."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from .checks import Record, flag, floats, in_range, position, positive, vec3

METHODS = ("iisph", "wcsph", "dfsph")

WALL_PRESSURES = ("extrapolated", "fluid")  # physics.wall_pressure: see Physics
WALL_GRADIENTS = ("completed", "akinci")  # physics.wall_gradient: see Physics
WARM_STARTS = ("hydrostatic", "half", "half_hydrostatic")  # physics.warm_start: see Physics
MAX_GRAVITY = 1000.0  # m/s^2, a hundred g: a centrifuge's liquid, not a typo's
HYDROSTATIC_STARTS = ("hydrostatic", "half_hydrostatic")  # the starts that need gravity along an axis

SMOOTHING = ("laplacian", "taubin", "none")
MESH_FORMATS = ("obj", "ply")

PARTICLE_FORMATS = ("ply", "vtu")  # output.format: binary PLY (splashsurf reads it) or VTU (ParaView)

# The shortest time step (s) a scene (physics.dt, dt_min, dt_max) or Simulation.step may ask for:
# a step of 1e-300 s would need 1e300 steps to reach a frame, and below about 1e-10 s a step no
# longer moves a float64 clock at long times.
MIN_STEP = 1.0e-7
MAX_DURATION = 1.0e6  # simulated seconds: output.duration and a Simulation's until


@dataclass
class SurfaceSettings(Record):
    """Surface reconstruction settings, in particle spacings ``h``: ``cell`` the distance-field
    grid's cell (h/2), ``r0`` the particle radius of Zhu & Bridson's distance (h/2), ``radius``
    their kernel radius R (2h); ``smoothing`` ``laplacian`` (the report's), ``taubin`` (keeps
    droplets' volume) or ``none``, over ``passes`` passes with factors ``lam`` and ``mu``;
    ``feature_weights``: scale each vertex's smoothing step by the particles near it (1 on the
    bulk surface, less towards lone droplets, which then keep their volume), as splashsurf's
    feature weights do; ``format`` the mesh files a run writes: ``obj`` (text, with normals) or
    ``ply`` (binary)."""

    cell: float = 0.5
    r0: float = 0.5
    radius: float = 2.0
    smoothing: str = "laplacian"
    passes: int = 3
    lam: float = 0.5
    mu: float = -0.53
    feature_weights: bool = True
    format: str = "obj"

    def validate(self) -> "SurfaceSettings":
        self.cell = in_range(self.cell, "surface.cell", 0.05, 4.0, "particle spacings")
        self.r0 = in_range(self.r0, "surface.r0", 0.0, 4.0, "particle spacings")
        self.radius = in_range(self.radius, "surface.radius", 0.5, 8.0, "particle spacings")
        if self.smoothing not in SMOOTHING:
            raise ValueError(f"surface.smoothing = {self.smoothing!r}: must be one of {', '.join(SMOOTHING)}")
        if (
            isinstance(self.passes, bool)
            or not isinstance(self.passes, (int, np.integer))
            or not 0 <= self.passes <= 100
        ):
            raise ValueError(f"surface.passes = {self.passes!r}: must be an integer in [0, 100]")
        self.lam = in_range(self.lam, "surface.lam", 0.0, 1.0, "smoothing factor", lo_open=True)
        self.mu = in_range(self.mu, "surface.mu", -1.0, 0.0, "Taubin's inflation factor", hi_open=True)
        if not isinstance(self.feature_weights, (bool, np.bool_)):
            raise ValueError(f"surface.feature_weights = {self.feature_weights!r}: must be true or false")
        self.feature_weights = bool(self.feature_weights)
        if self.format not in MESH_FORMATS:
            raise ValueError(f"surface.format = {self.format!r}: must be one of {', '.join(MESH_FORMATS)}")
        return self


@dataclass
class Output(Record):
    """What a run writes: ``fps`` frames per simulated second over ``duration`` seconds,
    particle files (``particles``, in ``format``: ``ply`` or ``vtu``), surface meshes (``mesh``),
    and the full state every ``checkpoint_every`` frames (0: never) for ``warp-iisph run --resume``;
    the probes (``[[probes]]``) are sampled at the end of the first step at or after every
    multiple of ``probe_interval`` seconds (0: every step)."""

    fps: float = 30.0
    duration: float = 2.0
    particles: bool = True
    mesh: bool = False
    checkpoint_every: int = 1
    format: str = "ply"
    probe_interval: float = 0.0

    def validate(self) -> None:
        self.fps = in_range(self.fps, "output.fps", 0.0, 10_000.0, "frames per simulated second", lo_open=True)
        self.duration = in_range(self.duration, "output.duration", 0.0, MAX_DURATION, "simulated seconds", lo_open=True)
        self.particles = flag(self.particles, "output.particles")
        self.mesh = flag(self.mesh, "output.mesh")
        c = self.checkpoint_every
        if isinstance(c, bool) or not isinstance(c, (int, np.integer)) or not 0 <= c <= 1_000_000:
            raise ValueError(
                f"output.checkpoint_every = {c!r}: must be a whole number of frames in [0, 1000000] (0: never)"
            )
        if self.format not in PARTICLE_FORMATS:
            raise ValueError(f"output.format = {self.format!r}: must be one of {', '.join(PARTICLE_FORMATS)}")
        self.probe_interval = in_range(
            self.probe_interval, "output.probe_interval", 0.0, 1.0e6, "seconds between probe samples, 0: every step"
        )
        if 0.0 < self.probe_interval < MIN_STEP:  # no step is that short: ask for every step
            raise ValueError(
                f"output.probe_interval = {self.probe_interval!r}: must be 0 (every step) or at least "
                f"{MIN_STEP:g} s, the shortest step"
            )


@dataclass
class Camera(Record):
    """Where `warp-iisph render` looks from: ``position`` and ``target`` (m) and a horizontal
    field of view ``fov`` (degrees). Without a position the camera frames the liquid itself."""

    position: Optional[tuple] = None
    target: Optional[tuple] = None
    fov: float = 40.0

    def validate(self) -> None:
        if self.position is not None:
            self.position = tuple(float(c) for c in position(self.position, "camera.position"))
        if self.target is not None:
            self.target = tuple(float(c) for c in position(self.target, "camera.target"))
        if self.target is not None and self.position is None:
            raise ValueError("camera.target: needs camera.position too")
        if self.position is not None and self.target is not None and np.allclose(self.position, self.target):
            raise ValueError("camera.target: must differ from camera.position")
        self.fov = in_range(self.fov, "camera.fov", 1.0, 170.0, "degrees", lo_open=False)


@dataclass
class Physics(Record):
    """Physical and numerical parameters.

    - ``method``: ``"iisph"``, ``"wcsph"`` or ``"dfsph"`` (divergence-free SPH, Bender & Koschier
      2017: a divergence solve and a constant-density solve per step).
    - ``rho0``: rest density (kg/m^3).
    - ``viscosity``: the report's viscosity coefficient mu (m^2/s); 0 switches viscosity off.
      The default 0.05 is SPlisHSPlasH's water-scene viscosity (its "Standard" model, 0.01 with
      the SPH Laplacian's factor 2(d + 2) = 10 where the report's sum has 2: a kinematic viscosity
      of 0.01 m^2/s). It removes what the pressure solver's start-up leaves moving (water started at
      rest would bounce for ever without it); being a fixed kinematic viscosity it damps small
      scenes more than large ones. Its explicit step is stable up to 0.4 h^2 / mu; a longer step
      applies it in equal sub-steps within that limit (one pass over the neighbour lists each),
      so the step follows the flow, not the viscosity.
    - ``boundary_viscosity``: the same coefficient against the walls (wall friction, m^2/s);
      0 leaves the walls free-slip.
    - ``wall_pressure``: the pressure the boundary particles push with. ``"extrapolated"`` (the
      default): the fluid's pressure around the particle pushed, continued into the wall with the
      hydrostatic (and, for a moving obstacle, inertial) gradient, ``p_b = max(p~_i + rho_i
      (g - a_b).(x_b - x~_i), 0)`` (``p~_i``, ``x~_i``: the pressure and position averaged over
      i's neighbourhood with weights W_ij; after Adami et al. 2012), in the symmetric force
      ``psi_b (p_i/rho_i^2 + p_b/rho0^2) grad W_ib`` and in IISPH's ``sum_j d_ij p_j``.
      ``"fluid"``: Akinci et al.'s ``psi_b p_i/rho_i^2 grad W_ib`` (the fluid particle's own
      pressure, in one term), with which the fluid layer touching a wall carries about twice its
      hydrostatic pressure. IISPH and WCSPH read it; DFSPH's solves keep Akinci's walls.
    - ``wall_gradient``: with extrapolated wall pressures, how the boundary particles' volumes
      enter the pressure force. ``"completed"``: each fluid particle's walls scaled once a step
      so that they complete its liquid's kernel-gradient sum along the walls' direction, as
      Akinci's volumes complete its density (``warp_iisph/sph/wall_gradient.py``; without it a
      uniform pressure pushes the layer at a wall off it, and that layer carries 4-9 % less than
      the pressure around it: loads on bodies and floating drafts 2-4 % off). ``"akinci"``:
      Akinci's volumes as they are. Unset (the default): ``"completed"`` in scenes with free
      bodies (their loads are what moves them), ``"akinci"`` otherwise (resting water stays
      stiller there: see :meth:`wall_gradient_for`). Set ``"completed"`` to measure loads on
      obstacles with force probes.
    - ``gravity``: (m/s^2).
    - ``eta``: IISPH's and DFSPH's target average density error, a fraction (0.001 = 0.1 %).
    - ``eta_divergence``: DFSPH's target average divergence error, the density that the
      compression rate ``max(D rho/Dt, 0)`` would add in one step, a fraction of rho0.
    - ``max_iterations``: cap on IISPH's relaxed Jacobi iterations and on each of DFSPH's two
      solves; ``min_iterations`` the floor of the pressure (constant-density) solve, unset: 4
      for IISPH from the hydrostatic start (from 2, a narrow resting column's slope rose 3 % above
      rho0 g, 1 % above the converged solve's), 2 otherwise (see :meth:`iteration_floor`).
    - ``omega``: IISPH's Jacobi relaxation factor.
    - ``warm_start``: the pressure IISPH's solve starts each step from. Unset (the default):
      ``"hydrostatic"`` where gravity points along an axis, ``"half"`` otherwise (no gravity, or
      gravity at an angle; see :meth:`pressure_start`). ``"hydrostatic"``: the hydrostatic pressure
      under the particle's column, ``rho0 |g| d`` with ``d`` the depth below the highest liquid in it
      (columns one spacing wide across gravity), taken in full where the particle's advected density
      is at least rho0 and not at all where it is 1 % or more below (a particle being pulled
      apart: the solution leaves it free), linearly between; nothing of the last step's, so
      resting water keeps no memory that could make it bounce (4 iterations a step at rest, its
      slope within 0.2 % from step to step; docs/pressure_solve.md); beside a free body (blind to
      the body's weight on the liquid under it) at least half the last step's. ``"half"``: half the last
      step's, ``0.5 p(t - dt)``; resting water's pressure holds still too, at about 22 iterations a
      step in a 0.6 m column. ``"half_hydrostatic"``: ``0.5 p(t - dt)`` plus half the hydrostatic
      pressure (ungated): the fewest iterations at tight tolerances in flows, but resting water's
      pressure wanders by a few per cent. A full warm start, ``p(t - dt)``, makes resting water
      bounce and is not offered. DFSPH and WCSPH ignore it (DFSPH starts from its own stiffness).
    - ``stiffness``: WCSPH's k in p = k((rho/rho0)^7 - 1) (Pa).
    - ``substeps``: with a fixed ``dt``, cut a step longer than the method can take into equal
      substeps (each step record's ``substeps`` says into how many): no longer than
      ``h / (max(max|v|, 2 sqrt(g y_top)) + c)`` (no particle crosses
      more than one spacing in a step; from rest, ``dt^2 g y_top / h^2 <= 1/4``: resting IISPH
      water alternates its pressure at 0.37 and bounces at 0.49, and at 1/2 IISPH's linearised
      density prediction fails at the walls). ``False`` takes the fixed dt as
      it is.
    - ``dt``: fixed time step (s); ``None`` selects the CFL rule
      ``dt = cfl * h / (max|v| + c)`` clamped to ``[dt_min, dt_max]`` (``c`` is WCSPH's speed of
      sound sqrt(7 k / rho0), 0 for IISPH and DFSPH); the last steps before a time the run must
      land on (a frame, the end) are fitted to it.
    - ``max_velocity``: a speed (m/s) beyond which the run counts as diverged; ``None`` derives
      one from the domain height (10 x the free-fall speed over it, at least 10 m/s, and at least
      3 x the fastest point of a free body at its start).
    """

    method: str = "iisph"
    rho0: float = 1000.0
    viscosity: float = 0.05
    boundary_viscosity: float = 0.0
    wall_pressure: str = "extrapolated"
    wall_gradient: Optional[str] = None
    gravity: tuple = (0.0, -9.81, 0.0)
    eta: float = 1.0e-3
    eta_divergence: float = 1.0e-3
    max_iterations: int = 100
    min_iterations: Optional[int] = None
    omega: float = 0.5
    warm_start: Optional[str] = None
    stiffness: float = 50_000.0
    dt: Optional[float] = None
    substeps: bool = True
    cfl: float = 0.5
    dt_min: float = 1.0e-5
    dt_max: float = 5.0e-3
    max_velocity: Optional[float] = None

    def pressure_start(self) -> str:
        """The warm start IISPH's solve uses: ``warm_start`` where set, else ``"hydrostatic"`` where
        gravity points along an axis (the columns it is estimated over) and ``"half"`` otherwise.
        With free bodies as without since 2026-12-06: with the completed walls the bodies float at
        their drafts from it as from the half start, heave alike, and cost about half as much
        (docs/physics.md 4.14)."""
        if self.warm_start is not None:
            return self.warm_start
        return "hydrostatic" if self.gravity_along_an_axis() else "half"

    def wall_gradient_for(self, free_bodies: bool = False) -> str:
        """The walls' gradient the pressure force uses: ``wall_gradient`` where set, else
        ``"completed"`` with free bodies and ``"akinci"`` without. Completed walls hold a body's
        load and a floating draft within 1-2 % (docs/physics.md 6.2), but leave resting water less
        still: in a 2 cm tank its mean speed 6.3 mm/s at most against 2.4, its fastest particle
        12.0 cm/s against 7.4, and from the hydrostatic start a step cut from 3.6 to 2 ms kicks its
        pressure by 6.5 % against 2.7 % (the water holds 0.07 % compression at rest against 0.03 %)."""
        if self.wall_gradient is not None:
            return self.wall_gradient
        return "completed" if free_bodies else "akinci"

    def resolved(self, free_bodies: bool = False) -> dict:
        """What the run takes for the choices a scene may leave unset: IISPH's ``warm_start``
        (:meth:`pressure_start`; None for other methods) and the walls' gradient the pressure force
        uses (:meth:`wall_gradient_for` with extrapolated wall pressures in IISPH and WCSPH;
        DFSPH's and the ``"fluid"`` wall pressure's walls are Akinci's)."""
        completes = self.method != "dfsph" and self.wall_pressure == "extrapolated"
        return {
            "warm_start": self.pressure_start() if self.method == "iisph" else None,
            "wall_gradient": self.wall_gradient_for(free_bodies) if completes else "akinci",
        }

    def gravity_along_an_axis(self) -> bool:
        """Whether gravity has exactly one non-zero component (the hydrostatic starts' columns)."""
        return sum(1 for g in self.gravity if g != 0.0) == 1

    def iteration_floor(self) -> int:
        """The fewest iterations of the pressure solve: ``min_iterations`` where set, else 4 for
        IISPH from the hydrostatic start and 2 otherwise (never above ``max_iterations``)."""
        if self.min_iterations is not None:
            return int(self.min_iterations)
        hydrostatic = self.method == "iisph" and self.pressure_start() == "hydrostatic"
        return min(4 if hydrostatic else 2, int(self.max_iterations))

    def validate(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"physics.method = {self.method!r}: must be one of {', '.join(METHODS)}")
        self.rho0 = in_range(self.rho0, "physics.rho0", 1.0, 1.0e5, "kg/m^3")
        self.viscosity = in_range(self.viscosity, "physics.viscosity", 0.0, 1.0, "m^2/s")
        self.boundary_viscosity = in_range(self.boundary_viscosity, "physics.boundary_viscosity", 0.0, 1.0, "m^2/s")
        if self.wall_pressure not in WALL_PRESSURES:
            raise ValueError(
                f"physics.wall_pressure = {self.wall_pressure!r}: must be one of {', '.join(WALL_PRESSURES)}"
            )
        if self.wall_gradient is not None and self.wall_gradient not in WALL_GRADIENTS:
            raise ValueError(
                f"physics.wall_gradient = {self.wall_gradient!r}: must be one of {', '.join(WALL_GRADIENTS)}"
            )
        self.gravity = floats(vec3(self.gravity, "physics.gravity"))
        if math.hypot(*self.gravity) > MAX_GRAVITY:  # hypot: no overflow for huge components
            raise ValueError(
                f"physics.gravity = {list(self.gravity)}: its magnitude must be at most {MAX_GRAVITY:g} m/s^2"
            )
        self.eta = in_range(self.eta, "physics.eta", 0.0, 0.5, "fraction of rho0, e.g. 0.001", lo_open=True)
        self.eta_divergence = in_range(
            self.eta_divergence,
            "physics.eta_divergence",
            0.0,
            0.5,
            "fraction of rho0 per step, e.g. 0.001",
            lo_open=True,
        )
        for key in ("max_iterations", "min_iterations"):
            v = getattr(self, key)
            if v is None and key == "min_iterations":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 100_000:
                raise ValueError(f"physics.{key} = {v!r}: must be an integer in [1, 100000]")
        if self.min_iterations is not None and self.min_iterations > self.max_iterations:
            raise ValueError(
                f"physics.min_iterations = {self.min_iterations}: must be <= "
                f"physics.max_iterations = {self.max_iterations}"
            )
        self.omega = in_range(self.omega, "physics.omega", 0.0, 1.0, "Jacobi relaxation", lo_open=True)
        if self.warm_start is not None and self.warm_start not in WARM_STARTS:
            raise ValueError(f"physics.warm_start = {self.warm_start!r}: must be one of {', '.join(WARM_STARTS)}")
        if self.warm_start in HYDROSTATIC_STARTS:
            if self.method != "iisph":
                raise ValueError(
                    f"physics.warm_start = {self.warm_start!r}: IISPH's only (physics.method = {self.method!r} "
                    "starts its solves from its own stiffness)"
                )
            if not self.gravity_along_an_axis():
                raise ValueError(
                    f"physics.warm_start = {self.warm_start!r}: needs physics.gravity along an axis, not {self.gravity}"
                )
        self.stiffness = positive(self.stiffness, "physics.stiffness", "Pa")
        if self.dt is not None:
            self.dt = in_range(self.dt, "physics.dt", MIN_STEP, 1.0, "seconds")
        self.substeps = flag(self.substeps, "physics.substeps")
        self.cfl = in_range(self.cfl, "physics.cfl", 0.0, 2.0, "Courant number", lo_open=True)
        self.dt_min = in_range(self.dt_min, "physics.dt_min", MIN_STEP, 1.0, "seconds")
        self.dt_max = in_range(self.dt_max, "physics.dt_max", self.dt_min, 1.0, "seconds, >= dt_min")
        if self.max_velocity is not None:
            self.max_velocity = positive(self.max_velocity, "physics.max_velocity", "m/s")
