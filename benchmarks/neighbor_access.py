"""Neighbour access: compact per-step lists against querying the hash grid inside every loop.

The solver builds fluid-fluid lists (index and grad W per entry) once per step and walks them
in every later loop. The alternative keeps only the grid and queries it in each loop, filtering
the candidates (27 cells, about 6 times the neighbours) and recomputing grad W every time. Which
wins depends on the device: lists cost a build pass and 16 bytes per entry streamed per walk;
queries cost compute and scattered candidate reads. This measures both on a dam-break state
with the solver's own Jacobi iteration (``pressure_sum_dij_pj`` and ``pressure_jacobi``, two
walks of the fluid lists) against twins of those two kernels that query the grid instead. Both
give the same pressures (the query visits neighbours in the list's order; checked here).

A step walks the fluid neighbours 4 times outside the Jacobi loop (density, advection velocity,
advection density, pressure acceleration) and twice per iteration; per step the lists cost the
fill plus those walks, the queries only the walks (the grid is built either way). Outside-loop
walks are counted at the cost of an average Jacobi walk, so the per-step figures are a model;
the per-iteration figures are measured. Writes benchmarks/results/neighbor_access.json and .png.

    python benchmarks/neighbor_access.py [--devices cpu,cuda] [--counts 10000,30000] [--repeats 20] [--quick]
    # on a GPU: --devices cuda --counts 100000,300000,1000000
"""

import argparse
import time

import numpy as np
import warp as wp
from common import RESULTS, header, present_devices, pyplot, save, warm_up

from warp_iisph import Simulation, scenes
from warp_iisph.engine.launch import launch_particles
from warp_iisph.sph.grid import CellGrid, cell_first, cell_hash, cell_range
from warp_iisph.sph.kernel import cubic_grad_W
from warp_iisph.sph.neighbors import NeighborList, StridedListBuffer, entry
from warp_iisph.sph.solvers.iisph import (
    IISPHTerms,
    dij_pj_term,
    jacobi_boundary_sigma,
    jacobi_sigma_term,
    jacobi_update,
    pressure_jacobi,
    pressure_sum_dij_pj,
)
from warp_iisph.sph.wall_pressure import walls_of

WALKS_OUTSIDE_JACOBI = 4  # density, advection velocity, advection density, pressure acceleration
WALKS_PER_ITERATION = 2  # pressure_sum_dij_pj, pressure_jacobi


@wp.kernel
def pressure_sum_dij_pj_query(
    offset: int,
    grid: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    radius: float,
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
    mass: float,
    dt_step: wp.array(dtype=float),
    d_ii: wp.array(dtype=wp.vec3),
    sum_dij_pj: wp.array(dtype=wp.vec3),
    displacement: wp.array(dtype=wp.vec3),
):
    i = wp.tid() + offset
    dt = dt_step[0]
    x_i = x[i]
    r2 = radius * radius
    acc = wp.vec3(0.0, 0.0, 0.0)
    j = int(0)
    query = wp.hash_grid_query(grid, x_i, radius)
    while wp.hash_grid_query_next(query, j):
        if j != i:
            x_ij = x_i - x[j]
            if wp.dot(x_ij, x_ij) < r2:
                acc -= dij_pj_term(mass, p[j], rho[j], cubic_grad_W(x_ij, radius))
    sdp = dt * dt * acc
    sum_dij_pj[i] = sdp
    displacement[i] = d_ii[i] * p[i] + sdp


@wp.kernel
def pressure_jacobi_query(
    offset: int,
    grid: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    radius: float,
    rho: wp.array(dtype=float),
    rho_adv: wp.array(dtype=float),
    a_ii: wp.array(dtype=float),
    displacement: wp.array(dtype=wp.vec3),
    sum_dij_pj: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=float),
    psi: wp.array(dtype=float),
    nb: NeighborList,
    mass: float,
    dt_step: wp.array(dtype=float),
    rho0: float,
    omega: float,
    a_least: float,
    p_new: wp.array(dtype=float),
    density_error: wp.array(dtype=wp.float64),
):
    i = wp.tid() + offset
    dt = dt_step[0]
    x_i = x[i]
    r2 = radius * radius
    rho_i = rho[i]
    p_i = p[i]
    sdp_i = sum_dij_pj[i]
    d_ji_scale = dt * dt * mass / (rho_i * rho_i)
    sigma = float(0.0)
    j = int(0)
    query = wp.hash_grid_query(grid, x_i, radius)
    while wp.hash_grid_query_next(query, j):
        if j != i:
            x_ij = x_i - x[j]
            if wp.dot(x_ij, x_ij) < r2:
                g = cubic_grad_W(x_ij, radius)
                sigma += jacobi_sigma_term(mass, sdp_i, displacement[j], (d_ji_scale * g) * p_i, g)
    sigma = jacobi_boundary_sigma(i, psi, nb, sdp_i, sigma)
    jacobi_update(i, sigma, p_i, a_ii[i], a_ii[i], rho_adv[i], rho0, omega, a_least * dt * dt, p_new, density_error)


@wp.kernel
def pressure_sum_dij_pj_index(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    radius: float,
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
    nf: NeighborList,
    mass: float,
    dt_step: wp.array(dtype=float),
    d_ii: wp.array(dtype=wp.vec3),
    sum_dij_pj: wp.array(dtype=wp.vec3),
    displacement: wp.array(dtype=wp.vec3),
):
    """The list twin that reads only the lists' indices and recomputes grad W from positions
    (a quarter of the list bytes streamed, a position gathered per entry)."""
    i = wp.tid() + offset
    dt = dt_step[0]
    x_i = x[i]
    acc = wp.vec3(0.0, 0.0, 0.0)
    for m in range(nf.count[i]):
        j = nf.index[entry(nf, i, m)]
        acc -= dij_pj_term(mass, p[j], rho[j], cubic_grad_W(x_i - x[j], radius))
    sdp = dt * dt * acc
    sum_dij_pj[i] = sdp
    displacement[i] = d_ii[i] * p[i] + sdp


@wp.kernel
def pressure_jacobi_index(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    radius: float,
    rho: wp.array(dtype=float),
    rho_adv: wp.array(dtype=float),
    a_ii: wp.array(dtype=float),
    displacement: wp.array(dtype=wp.vec3),
    sum_dij_pj: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=float),
    psi: wp.array(dtype=float),
    nf: NeighborList,
    nb: NeighborList,
    mass: float,
    dt_step: wp.array(dtype=float),
    rho0: float,
    omega: float,
    a_least: float,
    p_new: wp.array(dtype=float),
    density_error: wp.array(dtype=wp.float64),
):
    i = wp.tid() + offset
    dt = dt_step[0]
    x_i = x[i]
    rho_i = rho[i]
    p_i = p[i]
    sdp_i = sum_dij_pj[i]
    d_ji_scale = dt * dt * mass / (rho_i * rho_i)
    sigma = float(0.0)
    for m in range(nf.count[i]):
        j = nf.index[entry(nf, i, m)]
        g = cubic_grad_W(x_i - x[j], radius)
        sigma += jacobi_sigma_term(mass, sdp_i, displacement[j], (d_ji_scale * g) * p_i, g)
    sigma = jacobi_boundary_sigma(i, psi, nb, sdp_i, sigma)
    jacobi_update(i, sigma, p_i, a_ii[i], a_ii[i], rho_adv[i], rho0, omega, a_least * dt * dt, p_new, density_error)


@wp.kernel
def count_neighbors_strided(
    offset: int, grid: CellGrid, points: wp.array(dtype=wp.vec3), radius: float, wanted: wp.array(dtype=wp.int32)
):
    """The fill's twin that only counts: the same candidate loop without the list's stores, so
    the difference to the fill is what writing the lists costs."""
    i = wp.tid() + offset
    x_i = points[i]
    r2 = radius * radius
    k = int(0)
    cx = cell_range(grid, x_i, radius, 0)
    cy = cell_range(grid, x_i, radius, 1)
    cz = cell_range(grid, x_i, radius, 2)
    for z in range(cz[0], cz[1] + 1):
        for y in range(cy[0], cy[1] + 1):
            for x in range(cx[0], cx[1] + 1):
                c = cell_hash(x, y, z)
                s = cell_first(grid, c)
                while s < grid.n and grid.keys[s] == c:
                    x_ij = x_i - grid.points[s]
                    s += 1
                    if wp.dot(x_ij, x_ij) < r2:
                        k += 1
    wanted[i] = k - 1  # itself


def timed(fn, device, repeats: int) -> float:
    """Median wall seconds of ``fn`` over ``repeats`` synchronised calls (after one untimed)."""
    fn()
    wp.synchronize_device(device)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        wp.synchronize_device(device)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def run(device: str, count: int, settle: float, repeats: int) -> dict:
    sim = Simulation(scenes.dam_break_cube(particles=count, eta=1e-3, cfl=0.5, dt_max=5e-3), device)
    steps0 = sim.step_count
    sim.advance(settle)  # a moving, compressed state with a converged pressure field
    iterations = float(np.mean([s["iterations"] for s in sim.stats[steps0:]]))
    model, state, solver = sim.model, sim.state, sim.solver
    search, n, H, ph = solver.search, model.n_fluid, model.support_radius, solver.physics
    search.build(state.x)  # lists of the current positions, as the next step would have them
    nf, nb = search.fluid.lists, search.boundary.lists

    def grid_build():
        search.grid.build(state.x, search.radius)

    def list_fill():
        search.fluid.build(search.grid, state.x, n, search.radius)

    sum_list, sum_query = wp.zeros_like(solver.terms.sum_dij_pj), wp.zeros_like(solver.terms.sum_dij_pj)
    p_list, p_query = wp.zeros_like(solver.p_next), wp.zeros_like(solver.p_next)
    disp = wp.zeros_like(solver.terms.sum_dij_pj)  # each iteration writes it before it reads it

    walls = walls_of(model, 0.0, n)  # the walls' pressures off (Akinci's term), as the query twins compute

    def terms_with(sums):
        # the solver's terms with the iteration's own sums, and a_ii as the diagonal
        t = IISPHTerms()
        for name in ("v_adv", "d_ii", "a_ii", "rho_adv", "wall_push"):
            setattr(t, name, getattr(solver.terms, name))
        t.a_diag, t.sum_dij_pj, t.displacement = solver.terms.a_ii, sums, disp
        return t

    def iteration_lists(lists=nf, sums=sum_list, p_out=p_list):
        # the fluid part of an iteration, as the query twins compute it
        common = [solver.fluid, lists, nb, walls, terms_with(sums), state.rho, state.p]
        launch_particles(pressure_sum_dij_pj, n, common, device)
        launch_particles(
            pressure_jacobi, n, [*common, float(ph.omega), solver.a_least, p_out, solver.solve.error], device
        )

    # the same lists in the other layout: slot-major (slot m of particle i at m * n + i, what a
    # GPU warp reads coalesced) against particle-major (i * stride + m, one cache line per list)
    slot_major = nf.step != 1
    other = StridedListBuffer(n, device, stride=search.fluid.stride, slot_major=not slot_major)
    other.build(search.grid, state.x, n, search.radius)
    sum_other, p_other = wp.zeros_like(solver.terms.sum_dij_pj), wp.zeros_like(solver.p_next)

    # the query twins walk a wp.HashGrid over the same points: the same candidates in the same
    # order as the solver's own grid (warp_iisph.sph.grid), so the sums are bitwise the lists'
    query_grid = wp.HashGrid(128, 128, 128, device=device)
    query_grid.build(state.x, H)

    def iteration_query():
        grid = query_grid.id
        launch_particles(
            pressure_sum_dij_pj_query,
            n,
            [grid, state.x, H, state.rho, state.p, model.mass, solver.dt, solver.terms.d_ii, sum_query, disp],
            device,
        )
        launch_particles(
            pressure_jacobi_query,
            n,
            [
                grid,
                state.x,
                H,
                state.rho,
                solver.terms.rho_adv,
                solver.terms.a_ii,
                disp,
                sum_query,
                state.p,
                model.boundary_psi,
                nb,
                model.mass,
                solver.dt,
                ph.rho0,
                float(ph.omega),
                solver.a_least,
                p_query,
                solver.solve.error,
            ],
            device,
        )

    t_grid = timed(grid_build, device, repeats)
    t_fill = timed(list_fill, device, repeats)
    t_lists = timed(iteration_lists, device, repeats)
    t_query = timed(iteration_query, device, repeats)
    t_other = timed(lambda: iteration_lists(other.lists, sum_other, p_other), device, repeats)
    sum_index, p_index = wp.zeros_like(solver.terms.sum_dij_pj), wp.zeros_like(solver.p_next)

    def iteration_index():
        launch_particles(
            pressure_sum_dij_pj_index,
            n,
            [state.x, H, state.rho, state.p, nf, model.mass, solver.dt, solver.terms.d_ii, sum_index, disp],
            device,
        )
        launch_particles(
            pressure_jacobi_index,
            n,
            [
                state.x,
                H,
                state.rho,
                solver.terms.rho_adv,
                solver.terms.a_ii,
                disp,
                sum_index,
                state.p,
                model.boundary_psi,
                nf,
                nb,
                model.mass,
                solver.dt,
                ph.rho0,
                float(ph.omega),
                solver.a_least,
                p_index,
                solver.solve.error,
            ],
            device,
        )

    t_index = timed(iteration_index, device, repeats)
    index_difference = float(np.abs(p_list.numpy()[:n] - p_index.numpy()[:n]).max())
    counted = wp.zeros(n, dtype=wp.int32, device=device)
    t_count = timed(
        lambda: launch_particles(
            count_neighbors_strided, n, [search.grid.grid, state.x, search.radius, counted], device
        ),
        device,
        repeats,
    )
    assert np.array_equal(counted.numpy(), nf.count.numpy()[:n])
    layout_difference = float(np.abs(p_list.numpy()[:n] - p_other.numpy()[:n]).max())
    t_slot, t_particle = (t_lists, t_other) if slot_major else (t_other, t_lists)
    # 32 particles (a GPU warp's) interleaved slot by slot: reads coalesce as slot-major's do,
    # while a warp's fill writes stay within its own few kilobytes
    warp = StridedListBuffer(n, device, stride=search.fluid.stride, block=32)
    t_warp_fill = timed(lambda: warp.build(search.grid, state.x, n, search.radius, sync=False), device, repeats)
    sum_warp, p_warp = wp.zeros_like(solver.terms.sum_dij_pj), wp.zeros_like(solver.p_next)
    t_warp = timed(lambda: iteration_lists(warp.lists, sum_warp, p_warp), device, repeats)
    warp_difference = float(np.abs(p_list.numpy()[:n] - p_warp.numpy()[:n]).max())
    # both give the same iteration (same neighbours in the same order, same grad W)
    scale = max(float(np.abs(p_list.numpy()[:n]).max()), 1.0)
    p_difference = float(np.abs(p_list.numpy()[:n] - p_query.numpy()[:n]).max()) / scale
    s_l, s_q = sum_list.numpy()[:n], sum_query.numpy()[:n]
    sum_difference = float(np.abs(s_l - s_q).max() / max(np.abs(s_l).max(), 1e-30))
    walks = WALKS_OUTSIDE_JACOBI + WALKS_PER_ITERATION * iterations
    per_walk_lists, per_walk_query = t_lists / WALKS_PER_ITERATION, t_query / WALKS_PER_ITERATION
    step_lists = t_fill + walks * per_walk_lists
    step_query = walks * per_walk_query
    extra = per_walk_query - per_walk_lists
    return {
        "device": device,
        "particles": n,
        "spacing": model.spacing,
        "settled_seconds": settle,
        "mean_iterations": iterations,
        "fluid_entries": int(nf.count.numpy()[:n].sum()),
        "list_stride": search.fluid.stride,
        "list_bytes": search.fluid.capacity * 16,
        "grid_build_ms": 1e3 * t_grid,
        "list_fill_ms": 1e3 * t_fill,
        "jacobi_iteration_ms": {"lists": 1e3 * t_lists, "query": 1e3 * t_query},
        "solver_layout": "slot-major" if slot_major else "particle-major",
        # the same iteration on the same lists in each layout (bitwise the same pressures)
        "layout_iteration_ms": {
            "slot-major": 1e3 * t_slot,
            "particle-major": 1e3 * t_particle,
            "warp-blocked": 1e3 * t_warp,
        },
        "warp_blocked_fill_ms": 1e3 * t_warp_fill,
        "warp_blocked_max_difference": warp_difference,
        "particle_major_over_slot_major": t_particle / t_slot,
        "layout_max_difference": layout_difference,
        # the same iteration reading only the lists' indices, grad W recomputed from positions
        "index_only_iteration_ms": 1e3 * t_index,
        "index_only_max_difference": index_difference,
        # the fill's candidate loop alone (no list stores): the rest of the fill is its writes
        "count_only_ms": 1e3 * t_count,
        "query_over_lists_per_iteration": t_query / t_lists,
        "walks_per_step": walks,
        "modelled_step_ms": {"lists": 1e3 * step_lists, "query": 1e3 * step_query},
        # walks per step above which building the lists pays (never when a query walk is cheaper)
        "break_even_walks": t_fill / extra if extra > 0 else None,
        "faster": "lists" if step_lists <= step_query else "query",
        "max_relative_difference": {"pressure": p_difference, "sum_dij_pj": sum_difference},
    }


def chart(rows, path):
    plt = pyplot()
    devices = sorted({r["device"] for r in rows})
    fig, axes = plt.subplots(1, len(devices), figsize=(5 * len(devices) + 1, 4), squeeze=False)
    for ax, dev in zip(axes[0], devices):
        r = [x for x in rows if x["device"] == dev]
        pos = np.arange(len(r))
        fill = [x["list_fill_ms"] for x in r]
        walks_lists = [x["modelled_step_ms"]["lists"] - x["list_fill_ms"] for x in r]
        ax.bar(pos - 0.2, fill, 0.4, color="tab:blue", alpha=0.5, label="list fill")
        ax.bar(pos - 0.2, walks_lists, 0.4, bottom=fill, color="tab:blue", label="walks over lists")
        ax.bar(
            pos + 0.2,
            [x["modelled_step_ms"]["query"] for x in r],
            0.4,
            color="tab:orange",
            label="walks querying the grid",
        )
        ax.set_xticks(pos, [f"{x['particles']:,}" for x in r])
        ax.set_xlabel("fluid particles")
        ax.set_ylabel("ms per step (neighbour access)")
        ax.set_title(f"{dev}: lists against grid queries")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--devices", default="cpu,cuda")
    ap.add_argument("--counts", default="10000,30000")
    ap.add_argument("--settle", type=float, default=0.1, help="simulated seconds before measuring")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.quick:
        args.counts, args.settle, args.repeats = "4000", 0.02, 5
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    devices, missing = present_devices(args.devices)
    rows = []
    for dev in devices:
        warm_up(dev)
        rows += [run(dev, int(c), args.settle, args.repeats) for c in args.counts.split(",")]
    print(
        f"{'device':>6} {'particles':>9} {'iters':>5} {'grid ms':>7} {'fill ms':>7} {'it lists':>8} {'it query':>8}"
        f" {'step lists':>10} {'step query':>10} {'faster':>6} {'max diff':>8} {'slot-major':>10} {'part-major':>10}"
        f" {'index-only':>10} {'count-only':>10} {'warp it':>8} {'warp fill':>9}"
    )
    for r in rows:
        it, st = r["jacobi_iteration_ms"], r["modelled_step_ms"]
        print(
            f"{r['device']:>6} {r['particles']:>9} {r['mean_iterations']:>5.2f}"
            f" {r['grid_build_ms']:>7.2f} {r['list_fill_ms']:>7.2f}"
            f" {it['lists']:>8.2f} {it['query']:>8.2f} {st['lists']:>10.2f} {st['query']:>10.2f} {r['faster']:>6}"
            f" {r['max_relative_difference']['pressure']:>8.1e} {r['layout_iteration_ms']['slot-major']:>10.2f}"
            f" {r['layout_iteration_ms']['particle-major']:>10.2f} {r['index_only_iteration_ms']:>10.2f}"
            f" {r['count_only_ms']:>10.2f}"
            f" {r['layout_iteration_ms']['warp-blocked']:>8.2f} {r['warp_blocked_fill_ms']:>9.2f}"
        )
    record = header(
        "neighbor_access",
        devices[0],
        scene="dam_break_cube",
        settle=args.settle,
        repeats=args.repeats,
        devices_missing=missing,
        walks_outside_jacobi=WALKS_OUTSIDE_JACOBI,
        results=rows,
    )
    if "cuda" in devices:
        record["cuda_device_name"] = wp.get_device("cuda:0").name
    chart(rows, save(record, args.out, "neighbor_access", args.quick))


if __name__ == "__main__":
    main()
