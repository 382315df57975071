"""Per-step neighbour lists against brute force."""

import numpy as np
import pytest
import warp as wp

from warp_iisph.sph.neighbors import NeighborSearch


def _brute(points, queries, H, same):
    out = []
    p32, q32 = points.astype(np.float32), queries.astype(np.float32)
    for i, q in enumerate(q32):
        d = q - p32
        d2 = np.einsum("ij,ij->i", d, d)  # float32, as in the kernel
        idx = set(np.nonzero(d2 < np.float32(H) * np.float32(H))[0].tolist())
        if same:
            idx.discard(i)
        out.append(idx)
    return out


def test_neighbor_lists_identical_to_brute_force():
    rng = np.random.default_rng(3)
    H = 0.04
    x = rng.uniform(0, 0.3, size=(3000, 3))
    xb = rng.uniform(-0.05, 0.35, size=(1500, 3))
    search = NeighborSearch(len(x), wp.array(xb.astype(np.float32), dtype=wp.vec3, device="cpu"), H, "cpu")
    search.build(wp.array(x.astype(np.float32), dtype=wp.vec3, device="cpu"))
    assert search.fluid.to_sets(len(x)) == _brute(x, x, H, same=True)
    assert search.boundary.to_sets(len(x)) == _brute(xb, x, H, same=False)
    # lists grow when the particles crowd together: the fluid lists' stride, the boundary's storage
    x2 = (x - 0.15) * 0.5 + 0.15
    stride, capacity, generation = search.fluid.stride, search.boundary.capacity, search.fluid.generation
    search.build(wp.array(x2.astype(np.float32), dtype=wp.vec3, device="cpu"))
    assert search.fluid.to_sets(len(x)) == _brute(x2, x2, H, same=True)
    assert search.boundary.to_sets(len(x)) == _brute(xb, x2, H, same=False)
    longest = max(len(s) for s in _brute(x2, x2, H, same=True))
    assert stride < longest <= search.fluid.stride and search.fluid.generation == generation + 1
    assert int(search.fluid.needed.numpy()[0]) == len(x) * longest
    assert search.boundary.capacity >= capacity


def test_lists_exact_where_cells_wrap_round_the_hash_table_and_alias():
    """A row of cells is scanned as one run of sorted points where its hashes are consecutive, cell
    by cell where it wraps round the 128-cell table (negative coordinates, a domain wider than the
    table, cells of several places sharing a hash): every neighbour once, no other."""
    rng = np.random.default_rng(5)
    H = 0.01
    # 1.7 m along x at 1 cm cells spans the table, from below zero; thin in y and z, so dense enough
    x = np.column_stack([rng.uniform(-0.4, 1.3, 6000), rng.uniform(-0.02, 0.03, 6000), rng.uniform(0, 0.03, 6000)])
    search = NeighborSearch(len(x), None, H, "cpu")
    search.build(wp.array(x.astype(np.float32), dtype=wp.vec3, device="cpu"))
    sets, count = search.fluid.to_sets(len(x)), search.fluid.lists.count.numpy()[: len(x)]
    assert sets == _brute(x, x, H, same=True)
    assert np.array_equal(count, [len(s) for s in sets])  # nobody listed twice
    assert count.sum() > 5 * len(x)


@wp.kernel
def _hash_grid_order(
    grid: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    queries: wp.array(dtype=wp.vec3),
    radius: float,
    slots: int,
    out: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    x_i = queries[i]
    m = int(0)
    j = int(0)
    query = wp.hash_grid_query(grid, x_i, radius)
    while wp.hash_grid_query_next(query, j):
        d = x_i - points[j]
        if wp.dot(d, d) < radius * radius:
            if m < slots:
                out[i * slots + m] = j
            m += 1
    count[i] = m


def test_wall_lists_in_the_order_a_warp_hash_grid_visits_them():
    """The walls' grid is the project's own (sph/grid.py): each list holds the walls' particles in
    the very order ``wp.hash_grid_query`` gives, so every sum over them adds in the same order as
    with a ``wp.HashGrid`` (cells that wrap round the table and alias included)."""
    rng = np.random.default_rng(11)
    H, slots = 0.02, 64
    xb = np.column_stack([rng.uniform(-0.5, 2.2, 8000), rng.uniform(-0.03, 0.05, 8000), rng.uniform(0, 0.04, 8000)])
    x = np.column_stack([rng.uniform(-0.5, 2.2, 3000), rng.uniform(-0.03, 0.05, 3000), rng.uniform(0, 0.04, 3000)])
    walls = wp.array(xb.astype(np.float32), dtype=wp.vec3, device="cpu")
    fluid = wp.array(x.astype(np.float32), dtype=wp.vec3, device="cpu")
    search = NeighborSearch(len(x), walls, H, "cpu")
    search.build(fluid)
    grid = wp.HashGrid(128, 128, 128, device="cpu")
    grid.build(walls, H)
    out = wp.full(len(x) * slots, -1, dtype=wp.int32, device="cpu")
    count = wp.zeros(len(x), dtype=wp.int32, device="cpu")
    wp.launch(_hash_grid_order, dim=len(x), inputs=[grid.id, walls, fluid, H, slots, out, count], device="cpu")
    expected, count = out.numpy().reshape(len(x), slots), count.numpy()
    lists = search.boundary.lists
    start, got, index = lists.start.numpy(), lists.count.numpy(), lists.index.numpy()
    assert count.max() <= slots and count.sum() > 2 * len(x)
    assert np.array_equal(got[: len(x)], count)
    for i in range(len(x)):
        assert np.array_equal(index[start[i] : start[i] + got[i]], expected[i, : count[i]]), i


def test_strided_lists_cut_at_the_stride_without_sync_and_say_what_they_needed():
    """Inside a captured graph nothing is read back: a list longer than the stride is cut (no
    write past the storage) and ``needed`` tells the host afterwards."""
    rng = np.random.default_rng(5)
    x = rng.uniform(0, 0.2, size=(2000, 3)).astype(np.float32)
    search = NeighborSearch(len(x), None, 0.04, "cpu")
    search.fluid.grow(4 * len(x))  # a stride of about 5 slots
    stride = search.fluid.stride
    search.build(wp.array(x, dtype=wp.vec3, device="cpu"), sync=False)
    full = _brute(x, x, 0.04, same=True)
    got = search.fluid.to_sets(len(x))
    assert all(len(g) == min(len(f), stride) and g <= f for g, f in zip(got, full))
    assert int(search.fluid.needed.numpy()[0]) == len(x) * max(len(f) for f in full) > search.fluid.capacity


def test_cell_order_is_a_permutation_grouping_cells():
    rng = np.random.default_rng(4)
    x = rng.uniform(0, 0.5, size=(2000, 3)).astype(np.float32)
    search = NeighborSearch(len(x), None, 0.04, "cpu")
    order = search.cell_order(wp.array(x, dtype=wp.vec3, device="cpu")).numpy()
    assert sorted(order.tolist()) == list(range(len(x)))
    cells = np.floor(x[order] / 0.04).astype(int)
    changes = np.count_nonzero(np.any(np.diff(cells, axis=0) != 0, axis=1))
    assert changes < len(np.unique(cells, axis=0)) + 1  # each cell is one contiguous run


def test_wall_mask_skips_far_particles_and_keeps_every_wall_neighbour():
    """Walls on a box's faces; fluid inside, near the walls, and beyond them: the static mask
    clears far particles (they skip the walls' grid) and the lists still equal brute force."""
    from warp_iisph.scene import Box
    from warp_iisph.setup.sampling import sample_tank_walls
    from warp_iisph.sph.wall_mask import near_mask

    H, h = 0.04, 0.02
    walls = sample_tank_walls(Box((0.0, 0.0, 0.0), (0.6, 0.4, 0.4)), h)
    rng = np.random.default_rng(5)
    x = np.concatenate([rng.uniform(-0.1, 0.7, size=(4000, 3)), rng.uniform(0.0, 0.6, size=(1000, 3)) * [1, 0.05, 1]])
    xb = wp.array(walls.astype(np.float32), dtype=wp.vec3, device="cpu")
    search = NeighborSearch(len(x), xb, H, "cpu")
    search.build(wp.array(x.astype(np.float32), dtype=wp.vec3, device="cpu"))
    assert search.boundary.to_sets(len(x)) == _brute(walls, x, H, same=False)
    # the mask: no wall within H of a cleared cell; most of the box's inside is cleared
    m = near_mask(xb, H, "cpu")
    dims, lower, cell = np.array([m.dims[0], m.dims[1], m.dims[2]]), np.array(m.lower), m.cell
    c = np.floor((x - lower) / cell).astype(int)
    inside = np.all((c >= 0) & (c < dims), axis=1)
    near = np.zeros(len(x), bool)
    near[inside] = m.near.numpy().reshape(dims)[tuple(c[inside].T)] != 0
    has_wall = np.array([len(s) > 0 for s in _brute(walls, x, H, same=False)])
    assert np.all(near[has_wall]) and has_wall.sum() > 500
    assert (~near).mean() > 0.3


def test_moving_walls_mask_follows_them_and_keeps_every_neighbour():
    """Still walls and a moving body's samples (the last ones): the moving mask is marked again at
    every build, so lists equal brute force where the body has gone, and particles far from it
    skip its grid; a body that leaves the mask's box makes every particle query (still exact)."""
    from warp_iisph.scene import Box
    from warp_iisph.setup.sampling import sample_tank_walls

    H, h = 0.04, 0.02
    walls = sample_tank_walls(Box((0.0, 0.0, 0.0), (0.6, 0.4, 0.4)), h)
    g = np.arange(0.0, 0.1, h)
    body = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    rng = np.random.default_rng(6)
    x = rng.uniform(-0.05, 0.65, size=(4000, 3))
    xb = np.concatenate([walls, body + 0.1])
    xb_wp = wp.array(xb.astype(np.float32), dtype=wp.vec3, device="cpu")
    search = NeighborSearch(len(x), xb_wp, H, "cpu", n_still=len(walls))
    x_wp = wp.array(x.astype(np.float32), dtype=wp.vec3, device="cpu")
    mask = search.moving_mask.mask
    for shift in (0.1, 0.4, 0.62, 2.0):  # the last two: in the mask's border cells, then far outside it
        xb[len(walls) :] = body + (shift, 0.1, 0.1)
        xb_wp.assign(xb.astype(np.float32))
        search.build(x_wp)
        assert search.boundary.to_sets(len(x)) == _brute(xb, x, H, same=False)
        dims, lower, cell = np.array(mask.cells.dims), np.array(mask.cells.lower), mask.cells.cell
        cb = np.floor((xb[len(walls) :] - lower) / cell).astype(int)  # the body's cells: all inside the border?
        inner = np.all((cb >= 1) & (cb <= dims - 2))
        outside = int(mask.outside.numpy()[0])
        assert outside == (not inner) and outside == (shift > 0.5)
        if not outside:
            c = np.floor((x - lower) / cell).astype(int)
            inside = np.all((c >= 0) & (c < dims), axis=1)
            near = np.zeros(len(x), bool)
            near[inside] = mask.cells.near.numpy().reshape(dims)[tuple(c[inside].T)] != 0
            has_body = np.array([len(s) > 0 for s in _brute(xb[len(walls) :], x, H, same=False)])
            assert near.mean() < 0.1 and has_body.sum() > 10 and np.all(near[has_body])


def test_list_layouts_hold_the_same_entries_and_give_the_same_run():
    """Slot-major storage (slot m of particle i at m * n + i, CUDA's default) and warp-blocked
    storage (32 particles interleaved slot by slot) against particle-major (the CPU's): the same
    neighbours in the same order, so a run is bitwise the same."""
    from warp_iisph import Simulation, scenes
    from warp_iisph.sph.neighbors import StridedListBuffer

    rng = np.random.default_rng(4)
    H = 0.04
    x = rng.uniform(0, 0.3, size=(2000, 3)).astype(np.float32)
    xd = wp.array(x, dtype=wp.vec3, device="cpu")
    n = len(x)
    layouts = {"particle": {"slot_major": False}, "slot": {"slot_major": True}, "warp": {"block": 32}}
    built = {}
    for name, kw in layouts.items():
        s = NeighborSearch(n, None, H, "cpu")
        s.fluid = StridedListBuffer(n, "cpu", **kw)
        s.build(xd)
        built[name] = s.fluid
    a, b, w = built["particle"], built["slot"], built["warp"]
    assert a.lists.step == 1 and b.lists.step == n and w.lists.step == 32
    assert b.to_sets(n) == a.to_sets(n) == w.to_sets(n) == _brute(x, x, H, same=True)
    stride = a.stride
    pm = a.lists.index.numpy().reshape(n, stride)
    sm = b.lists.index.numpy().reshape(stride, n).T
    wm = w.lists.index.numpy().reshape(-1, stride, 32).transpose(0, 2, 1).reshape(-1, stride)[:n]
    counts = a.lists.count.numpy()
    assert all(np.array_equal(pm[i, : counts[i]], sm[i, : counts[i]]) for i in range(n))  # same order
    assert all(np.array_equal(pm[i, : counts[i]], wm[i, : counts[i]]) for i in range(n))
    runs = []
    for kw in layouts.values():
        sim = Simulation(scenes.martin_moyce(spacing=0.02, a=0.2, depth=0.1), "cpu")
        sim.solver.search.fluid = StridedListBuffer(sim.n_particles, "cpu", **kw)
        sim.advance(0.1)
        runs.append(sim.positions)
    np.testing.assert_array_equal(runs[0], runs[1])
    np.testing.assert_array_equal(runs[0], runs[2])


@pytest.mark.parametrize("layout", [{"slot_major": False}, {"slot_major": True}, {"block": 32}])
def test_a_stride_too_short_grows_when_few_particles_fill_a_large_storage(layout):
    """Storage sized for 5,000 particles holding 216 with up to 56 neighbours each (over the
    first stride, 48): the stride grows and no list is cut (an emitter's first particles in a
    scene's full capacity; the check once compared 216 x 56 with 48 x 5,000 and let it pass)."""
    from warp_iisph.sph.grid import ParticleGrid
    from warp_iisph.sph.neighbors import StridedListBuffer

    g = np.arange(6, dtype=np.float32)
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    H = 2.45
    lists = StridedListBuffer(5000, "cpu", **layout)
    grid = ParticleGrid(5000, "cpu")
    xd = wp.array(np.concatenate([x, np.zeros((5000 - len(x), 3), np.float32)]), dtype=wp.vec3, device="cpu")
    grid.build(xd, H, len(x))
    lists.build(grid, xd, len(x), H)
    want = [len(s) for s in _brute(x, x, H, same=True)]
    assert max(want) > 48 and lists.stride >= max(want)
    assert lists.lists.count.numpy()[: len(x)].tolist() == want


def test_list_storage_beyond_32_bit_indices_is_refused_not_wrapped():
    """Entries are addressed with 32-bit indices: a need beyond them is held at the limit (not
    wrapped to a small or negative number that would pass the check and cut lists), and storage
    that large is refused with a message, before anything is allocated."""
    from warp_iisph.sph.neighbors import LIST_ENTRIES_LIMIT, StridedListBuffer, stride_needed

    needed = wp.zeros(1, dtype=wp.int32, device="cpu")
    wp.launch(
        stride_needed,
        dim=2,
        inputs=[45_000_000, wp.array([30, 50], dtype=wp.int32, device="cpu"), needed],
        device="cpu",
    )
    assert needed.numpy()[0] == LIST_ENTRIES_LIMIT
    lists = StridedListBuffer(1000, "cpu")
    with pytest.raises(MemoryError, match="32-bit indices"):
        lists.grow(int(needed.numpy()[0]))
    assert lists.capacity == 48 * 1000  # untouched


def test_a_liquid_beyond_32_bit_list_indices_is_refused_before_sampling():
    """On a device with the memory for 50M particles (a large GPU) the lists' 32-bit indices
    are the limit: refused with a message, as a liquid beyond the free memory is."""
    from types import SimpleNamespace

    from warp_iisph.setup.build import _check_memory

    big_gpu = SimpleNamespace(is_cuda=True, free_memory=140 * 2**30)
    with pytest.raises(ValueError, match="spacing: 50,000,000 fluid particles need more neighbour-list entries"):
        _check_memory(50_000_000, 0, big_gpu)
    _check_memory(40_000_000, 0, big_gpu)  # 1.9e9 entries: fits
    with pytest.raises(ValueError, match="GiB but"):
        _check_memory(200_000_000, 0, big_gpu)  # memory first
