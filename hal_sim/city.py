"""The simulated city (SPEC section 4): a random street grid with dead ends and one-way
streets, its strongly connected part, landmarks along the streets and magnetic interference
zones. Compiled with numba; drawn from numba's generator, but for the streets' dead ends and
one-way draws (``hal_sim.rng``, seeded from numba's; see ``hal_sim.world``, which re-exports
these names).

Node ``n = j * nx + i`` sits at ``(xs[i], ys[j])``; ``adj[n, d]`` is the node reached by
driving from n in direction d (0 east, 1 north, 2 west, 3 south) or -1.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from hal_sim import rng

DIR_DX = np.array([1, 0, -1, 0])
DIR_DY = np.array([0, 1, 0, -1])


@njit(cache=True, error_model="numpy")
def _street_positions(length_m: float, block_min: float, block_max: float) -> np.ndarray:
    n_max = int(length_m / block_min) + 2
    pos = np.empty(n_max)
    pos[0] = 0.0
    n = 1
    while n < n_max:
        nxt = pos[n - 1] + np.random.uniform(block_min, block_max)
        if nxt > length_m and n >= 3:
            break
        pos[n] = nxt
        n += 1
    return pos[:n].copy()


@njit(cache=True, error_model="numpy")
def grid_adjacency(nx: int, ny: int) -> np.ndarray:
    """The full nx-by-ny grid's adjacency (every street both ways), -1 off the grid."""
    adj = np.full((nx * ny, 4), -1, dtype=np.int64)
    for j in range(ny):
        for i in range(nx):
            u = j * nx + i
            for d in range(4):
                ii, jj = i + DIR_DX[d], j + DIR_DY[d]
                if 0 <= ii < nx and 0 <= jj < ny:
                    adj[u, d] = jj * nx + ii
    return adj


@njit(cache=True, error_model="numpy")
def _reach(adj: np.ndarray, grid: np.ndarray, seed: int, forward: bool) -> np.ndarray:
    """The nodes ``seed`` reaches (``forward``) or that reach it: v -> u exists when the grid
    neighbour v of u in direction d (``grid``, the full grid's adjacency) drives back to u."""
    n_nodes = adj.shape[0]
    seen = np.zeros(n_nodes, dtype=np.bool_)
    stack = np.empty(n_nodes, dtype=np.int64)
    seen[seed] = True
    stack[0] = seed
    top = 1
    while top > 0:
        top -= 1
        u = stack[top]
        for d in range(4):
            if forward:
                v = adj[u, d]
                if v < 0:
                    continue
            else:
                v = grid[u, d]
                if v < 0 or adj[v, (d + 2) & 3] != u:
                    continue
            if not seen[v]:
                seen[v] = True
                stack[top] = v
                top += 1
    return seen


@njit(cache=True, error_model="numpy")
def make_city(
    area_km2: float,
    aspect: float,
    block_min: float,
    block_max: float,
    dead_frac: float,
    oneway_frac: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A random grid city: (xs, ys, adj, in_network).

    Every node in the network reaches every other.
    """
    width = math.sqrt(area_km2 * aspect) * 1000.0
    height = area_km2 * 1e6 / width
    xs = _street_positions(width, block_min, block_max)
    ys = _street_positions(height, block_min, block_max)
    nx, ny = xs.shape[0], ys.shape[0]
    n = nx * ny
    grid = grid_adjacency(nx, ny)
    adj = grid.copy()
    # The per-street draws from the step's cheaper generator (hal_sim.rng; a few per node,
    # a fifth of the Mersenne Twister's cost), seeded from numba's.
    s0, s1 = rng.seed_state(np.random.randint(0, 1 << 62))
    # Dead ends: some nodes keep one street and lose the others (both ways).
    for u in range(n):
        r, s0, s1 = rng.uniform(s0, s1)
        if r >= dead_frac:
            continue
        r, s0, s1 = rng.uniform(s0, s1)
        keep = int(r * 4.0)
        for _ in range(4):
            if adj[u, keep] >= 0:
                break
            keep = (keep + 1) % 4
        # (A node whose neighbours have all cut it off keeps nothing; SCC pruning drops it.)
        for d in range(4):
            v = adj[u, d]
            if d != keep and v >= 0:
                adj[u, d] = -1
                adj[v, (d + 2) % 4] = -1
    # One-way streets: each remaining segment once (E and N of each node).
    for u in range(n):
        for d in range(2):
            v = adj[u, d]
            if v < 0 or adj[v, d + 2] != u:
                continue
            r, s0, s1 = rng.uniform(s0, s1)
            if r < oneway_frac:
                r, s0, s1 = rng.uniform(s0, s1)
                if r < 0.5:
                    adj[u, d] = -1
                else:
                    adj[v, d + 2] = -1
    # Keep the strongly connected part that holds a random node (retry for a big one).
    best = np.zeros(n, dtype=np.bool_)
    best_size = 0
    for _ in range(8):
        seed = np.random.randint(0, n)
        scc = _reach(adj, grid, seed, True) & _reach(adj, grid, seed, False)
        size = int(scc.sum())
        if size > best_size:
            best_size = size
            best = scc
        if size * 2 > n:
            break
    for u in range(n):
        for d in range(4):
            if not best[u] or (adj[u, d] >= 0 and not best[adj[u, d]]):
                adj[u, d] = -1
    return xs, ys, adj, best


@njit(cache=True, error_model="numpy")
def node_pos(xs: np.ndarray, ys: np.ndarray, n: int) -> tuple[float, float]:
    nx = xs.shape[0]
    return xs[n % nx], ys[n // nx]


@njit(cache=True, error_model="numpy")
def random_node(in_network: np.ndarray) -> int:
    return random_of(np.nonzero(in_network)[0])


@njit(cache=True, error_model="numpy")
def random_of(nodes: np.ndarray) -> int:
    """A random entry of ``nodes`` (the network's nodes, ``np.nonzero(in_network)[0]``): the
    same draw as ``random_node``, without listing the network again."""
    return int(nodes[np.random.randint(0, nodes.shape[0])])


@njit(cache=True, error_model="numpy")
def node_at_distance(
    xs: np.ndarray, ys: np.ndarray, in_network: np.ndarray, start: int, min_m: float, frac: float
) -> int:
    """A network node near a point at a random distance (uniform in [min_m, frac * diagonal])."""
    nx = xs.shape[0]
    sx, sy = xs[start % nx], ys[start // nx]
    diag = math.hypot(xs[-1] - xs[0], ys[-1] - ys[0])
    dist = np.random.uniform(min(min_m, frac * diag), frac * diag)
    best = -1
    for _ in range(20):
        phi = np.random.uniform(-math.pi, math.pi)
        px, py = sx + dist * math.cos(phi), sy + dist * math.sin(phi)
        if xs[0] <= px <= xs[-1] and ys[0] <= py <= ys[-1]:
            break
    px = min(max(px, xs[0]), xs[-1])
    py = min(max(py, ys[0]), ys[-1])
    best_d = math.inf
    for n in range(in_network.shape[0]):
        if not in_network[n] or n == start:
            continue
        d = (xs[n % nx] - px) ** 2 + (ys[n // nx] - py) ** 2
        if d < best_d:
            best_d = d
            best = n
    return best


@njit(cache=True, error_model="numpy")
def place_landmarks(
    xs: np.ndarray, ys: np.ndarray, adj: np.ndarray, in_network: np.ndarray, density_per_km2: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Landmarks along the streets: Poisson count for the area, uniform along random segments.

    Returns (lm_xy, node_start, node_lms): the landmarks near node n are
    ``node_lms[node_start[n]:node_start[n + 1]]`` (each landmark is listed at
    both ends of its segment), so sighting checks look at a handful, not all.
    """
    nx = xs.shape[0]
    n = adj.shape[0]
    area_km2 = (xs[-1] - xs[0]) * (ys[-1] - ys[0]) / 1e6
    count = np.random.poisson(density_per_km2 * area_km2) if density_per_km2 > 0 else 0
    lm_xy = np.empty((count, 2))
    ends = np.empty((count, 2), dtype=np.int64)
    nodes = np.nonzero(in_network)[0]
    k = 0
    while k < count:
        u = random_of(nodes)
        d = np.random.randint(0, 4)
        v = adj[u, d]
        if v < 0:
            continue
        f = np.random.random()
        ux, uy = xs[u % nx], ys[u // nx]
        vx, vy = xs[v % nx], ys[v // nx]
        lm_xy[k, 0] = ux + f * (vx - ux)
        lm_xy[k, 1] = uy + f * (vy - uy)
        ends[k, 0] = u
        ends[k, 1] = v
        k += 1
    counts = np.zeros(n + 1, dtype=np.int64)
    for k in range(count):
        counts[ends[k, 0] + 1] += 1
        counts[ends[k, 1] + 1] += 1
    node_start = np.cumsum(counts)
    fill = node_start[:-1].copy()
    node_lms = np.empty(2 * count, dtype=np.int64)
    for k in range(count):
        for e in range(2):
            u = ends[k, e]
            node_lms[fill[u]] = k
            fill[u] += 1
    return lm_xy, node_start, node_lms


@njit(cache=True, error_model="numpy")
def make_interference(adj: np.ndarray, frac: float, bias_min: float, bias_max: float) -> np.ndarray:
    """Magnetic interference zones: bias (rad) per directed block, NaN where there is none.

    Drawn only when ``frac > 0`` so the calibrated studies keep their random streams.
    """
    mag = np.full(adj.shape, np.nan)
    if frac <= 0.0:
        return mag
    for u in range(adj.shape[0]):
        for d in range(4):
            if adj[u, d] >= 0 and np.random.random() < frac:
                b = np.random.uniform(bias_min, bias_max)
                mag[u, d] = b if np.random.random() < 0.5 else -b
    return mag
