"""The IISPH pressure solve's linear operator, built explicitly: where relaxed Jacobi cannot converge.

The solve predicts each particle's density from the pressures, ``rho_pred = rho_adv + A p``, and
relaxed Jacobi converges only if every eigenvalue of ``D^-1 A`` (``D``: the diagonal it divides by)
has a positive real part. Here ``A`` is built column by column in the first step of a column of
water at rest from the hydrostatic start, from the solver's own kernels (the pressures of a set of
particles more than 8 spacings apart raised by 100 Pa at a time, each one's response read within
its reach of 4 spacings), for the default extrapolated wall pressures and, in the same state, Akinci's
walls. Reported for each case:

- the eigenvalue of ``D^-1 A`` with the least real part (ARPACK), and the factor ``|1 - omega
  lambda|`` by which relaxed Jacobi multiplies that mode each iteration (above 1: it grows);
- the uniform pressure's Rayleigh quotient ``1 . D^-1 A 1 / n`` and ``D^-1 A 1`` averaged over the
  particles in the wall layers and the others (negative: a uniform pressure compresses them);
- the wall layer's kernel-gradient sum ``sum_j m grad W_ij + sum_b psi_b grad W_ib`` along the
  wall's normal, as a fraction of ``rho0 / h``: what a uniform pressure pushes the wall layer with.

The cases: the release column of ``validation.py`` (0.1 m wide, 0.2 m high, between two side walls
4 spacings apart) at nx 10, 16 and 20, the same 8 spacings deep, and an open 3D block. docs/
pressure_solve.md ("Where every particle is near a wall") reads the results.

Writes benchmarks/results/pressure_operator.json and pressure_operator.png.

    python benchmarks/pressure_operator.py [--quick]
"""

import argparse
import time

import numpy as np
import warp as wp
from common import RESULTS, header, pyplot, save

import warp_iisph.sph.solvers.iisph as iisph
from warp_iisph.sph.kernel import cubic_grad_W_np

REACH = 4  # spacings: how far a pressure reaches in one prediction (two support radii of 2 spacings)
DELTA = 100.0  # Pa: the raise that measures a column (the operator is linear but for the walls' clip at 0)
COLOUR = 9  # spacings between particles raised together: more than twice the reach
CASES = [  # (name, spacing, tank size, fluid size): the fluid box sits in the tank's corner at the origin
    ("column nx 10, 4 deep", 0.01, (0.4, 0.3, 0.04), (0.1, 0.2, 0.04)),
    ("column nx 16, 4 deep", 0.00625, (0.4, 0.3, 0.025), (0.1, 0.2, 0.025)),
    ("column nx 20, 4 deep", 0.005, (0.4, 0.3, 0.02), (0.1, 0.2, 0.02)),
    ("column nx 10, 8 deep", 0.01, (0.4, 0.3, 0.08), (0.1, 0.2, 0.08)),
    ("column nx 20, 8 deep", 0.005, (0.4, 0.3, 0.04), (0.1, 0.2, 0.04)),
    ("tank 16 x 24 x 16", 0.0125, (0.2, 0.4, 0.2), (0.2, 0.3, 0.2)),
    ("tank 16 x 24 x 16, settled 1 s", 0.0125, (0.2, 0.4, 0.2), (0.2, 0.3, 0.2), 1.0),
    ("column nx 20, 4 deep, held 1 s", 0.005, (0.1, 0.3, 0.02), (0.1, 0.2, 0.02), 1.0),
]
QUICK = CASES[:1]


@wp.kernel
def predicted_density(
    fluid: iisph.Fluid,
    nf: iisph.NeighborList,
    nb: iisph.NeighborList,
    walls: iisph.Walls,
    terms: iisph.IISPHTerms,
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
    out: wp.array(dtype=float),
):
    """``a_ii p + s_i``: the density change the pressures ``p`` predict (the solve's own
    ``jacobi_sigma``; the predicted density less ``rho_adv``, so that float32 keeps the small
    differences the operator's columns are)."""
    i = wp.tid()
    sigma = iisph.jacobi_sigma(i, fluid, nf, nb, walls, terms, rho, p)
    out[i] = terms.a_ii[i] * p[i] + sigma


def colour_classes(x: np.ndarray, cell: np.ndarray, spacing: float) -> list[np.ndarray]:
    """The particles in sets whose members lie more than twice the reach apart, so that raising a
    set's pressures together gives each member's column of ``A`` apart: the cells modulo
    :data:`COLOUR`, each set split further where particles moved off the lattice came closer."""
    colour = (cell[:, 0] % COLOUR) * COLOUR * COLOUR + (cell[:, 1] % COLOUR) * COLOUR + cell[:, 2] % COLOUR
    apart = (2.0 * REACH * spacing) ** 2
    sets = []
    for c in np.unique(colour):
        left = list(np.flatnonzero(colour == c))
        while left:
            chosen, rest = [], []
            for i in left:
                far = all(((x[i] - x[j]) ** 2).sum() > apart for j in chosen)
                (chosen if far else rest).append(i)
            sets.append(np.asarray(chosen))
            left = rest
    return sets


def step_operators(spacing: float, tank: tuple, fluid: tuple, settle: float = 0.0) -> dict:
    """``A`` and ``D`` of a step's solve (the first after ``settle`` seconds at the defaults), for
    extrapolated and Akinci's walls, the particles' positions and the kernel-gradient sums,
    caught where the solve would start."""
    from warp_iisph import Box, Scene, Simulation

    scene = Scene(spacing=spacing, tank=Box((0, 0, 0), tank), name="pressure_operator")
    scene.add_fluid_box((0, 0, 0), fluid)
    sim = Simulation(scene, "cpu")
    if settle:
        sim.advance(settle)
    solver, model, state = sim.solver, sim.model, sim.state
    caught = {}

    def catch(*args, **kwargs):
        n = state.n
        nf, nb = solver.search.fluid.lists, solver.search.boundary.lists
        walls = solver.walls.walls
        out = wp.zeros(n, dtype=float, device=model.device)
        p_all = state.p.numpy().copy()
        p0 = p_all[:n].astype(np.float64)

        def predict(p, pressure_factor):
            walls.pressure_factor = pressure_factor
            p_all[:n] = p
            state.p.assign(p_all)
            common = [solver.fluid, nf, nb, walls, solver.terms, state.rho, state.p]
            wp.launch(iisph.pressure_sum_dij_pj, n, [0, *common], device=model.device)
            wp.launch(predicted_density, n, [*common, out], device=model.device)
            return out.numpy().astype(np.float64)

        x = state.x.numpy()[:n].astype(np.float64)
        cell = np.floor((x - x.min(0)) / spacing + 0.5).astype(int)
        factor = walls.pressure_factor
        for name, f in (("extrapolated", factor), ("akinci", 0.0)):
            base = predict(p0, f)
            rows, cols, vals = [], [], []
            for raised in colour_classes(x, cell, spacing):
                q = p0.copy()
                q[raised] += DELTA
                response = (predict(q, f) - base) / DELTA
                near = np.flatnonzero(response != 0.0)
                # each responding particle answers to the one raised particle within its reach
                d2 = ((x[near, None, :] - x[None, raised, :]) ** 2).sum(-1)
                assert np.all(d2.min(axis=1) <= (1.001 * REACH * spacing) ** 2), "a response beyond the reach"
                owner = raised[np.argmin(d2, axis=1)]
                rows.append(near), cols.append(owner), vals.append(response[near])
            caught[name] = (np.concatenate(rows), np.concatenate(cols), np.concatenate(vals))
        walls.pressure_factor = factor
        caught["a_diag"] = solver.terms.a_diag.numpy()[:n].astype(np.float64)
        caught["a_ii"] = solver.terms.a_ii.numpy()[:n].astype(np.float64)
        caught["x"], caught["cell"], caught["omega"] = x, cell, float(solver.physics.omega)
        caught["gradient_sum"] = _gradient_sums(model, state, n)
        p_all[:n] = p0
        state.p.assign(p_all)
        caught["rho0"] = float(solver.physics.rho0)
        return None

    solver.solve.run = catch  # the step then integrates with the start's pressures; nothing else is read
    sim.step()
    return caught


def _gradient_sums(model, state, n: int) -> np.ndarray:
    """``sum_j m grad W_ij + sum_b psi_b grad W_ib`` of each fluid particle (a KD-tree: set-up code)."""
    from scipy.spatial import cKDTree

    H = model.support_radius
    x = state.x.numpy()[:n].astype(np.float64)
    xb = model.boundary_x.numpy().astype(np.float64)
    psi = model.boundary_psi.numpy().astype(np.float64)

    def grad_sum(points, weights, pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        g = cubic_grad_W_np(x[i] - points[j], H) * weights[j][:, None]
        out = np.zeros((n, 3))
        np.add.at(out, i, g)
        return out

    fluid_pairs = cKDTree(x).query_ball_tree(cKDTree(x), H)
    wall_pairs = cKDTree(x).query_ball_tree(cKDTree(xb), H)

    def as_pairs(lists):
        return np.array([(i, j) for i, js in enumerate(lists) for j in js], dtype=int).reshape(-1, 2)

    mass = np.full(n, model.mass)
    return grad_sum(x, mass, as_pairs(fluid_pairs)) + grad_sum(xb, psi, as_pairs(wall_pairs))


def analyse(name: str, spacing: float, tank: tuple, fluid: tuple, settle: float = 0.0) -> dict:
    from scipy.sparse import csr_matrix, diags
    from scipy.sparse.linalg import eigs

    t0 = time.perf_counter()
    op = step_operators(spacing, tank, fluid, settle)
    n, omega, cell = len(op["x"]), op["omega"], op["cell"]
    one = np.ones(n)
    # away from the floor, the back wall and the free faces (3 spacings): the side walls' layers and those between
    top = cell.max(0)
    inner = (cell[:, 0] > 3) & (cell[:, 1] > 3) & (cell[:, 0] < top[0] - 3) & (cell[:, 1] < top[1] - 3)
    side = inner & ((cell[:, 2] == 0) | (cell[:, 2] == top[2]))
    between = inner & ~side
    row = {"case": name, "spacing": spacing, "particles": n, "settled_s": settle}
    for walls, diagonal in (("extrapolated", op["a_diag"]), ("akinci", op["a_ii"])):
        r, c, v = op[walls]
        J = diags(1.0 / diagonal) @ csr_matrix((v, (r, c)), shape=(n, n))
        lam = eigs(J, k=3, which="SR", return_eigenvectors=False, tol=1e-8, maxiter=20 * n)
        least = lam[np.argmin(lam.real)]
        u = J @ one
        row[walls] = {
            "least_eigenvalue": [float(least.real), float(least.imag)],
            "jacobi_factor": float(abs(1.0 - omega * least)),
            "uniform_rayleigh": float(one @ u / n),
            "uniform_side_layers": float(u[side].mean()),
            "uniform_between": float(u[between].mean()),
        }
    side_sum = op["gradient_sum"][inner & (cell[:, 2] == 0), 2].mean()
    row["side_wall_gradient_sum"] = float(side_sum * spacing / op["rho0"])  # a fraction of rho0 / h
    row["seconds"] = round(time.perf_counter() - t0, 1)
    print(
        f"{name}: {n} particles, least eigenvalue {row['extrapolated']['least_eigenvalue'][0]:+.4f} "
        f"(Akinci {row['akinci']['least_eigenvalue'][0]:+.4f}), Jacobi factor "
        f"{row['extrapolated']['jacobi_factor']:.4f}, D^-1 A 1 between the side layers "
        f"{row['extrapolated']['uniform_between']:+.3f} (Akinci {row['akinci']['uniform_between']:+.3f}), "
        f"side wall layer's gradient sum "
        f"{row['side_wall_gradient_sum']:+.4f} rho0/h ({row['seconds']} s)",
        flush=True,
    )
    return row


def chart(rows: list, path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 5))
    names = [r["case"] for r in rows]
    y = np.arange(len(rows))
    least = [r["extrapolated"]["least_eigenvalue"][0] for r in rows]
    ax.barh(y + 0.2, least, 0.4, label="extrapolated walls (default)")
    ax.barh(y - 0.2, [r["akinci"]["least_eigenvalue"][0] for r in rows], 0.4, label="Akinci's walls")
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_yticks(y, names)
    ax.invert_yaxis()
    ax.set_xlabel("least real part of an eigenvalue of D^-1 A\n(below 0: relaxed Jacobi grows that mode)")
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.2), ncol=2)
    ax.set_title("The pressure solve's operator at the start of a step (hydrostatic start)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="the smallest case only (a few seconds)")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    rows = [analyse(*case) for case in (QUICK if args.quick else CASES)]
    record = header("pressure_operator", reach_spacings=REACH, colour_spacings=COLOUR, cases=rows)
    chart(rows, save(record, args.out, "pressure_operator", args.quick))


if __name__ == "__main__":
    main()
