"""Exact geodesic distance fields and matrices on the planning grid (docs/design.md §4, §7.1).

The graph
---------
Nodes are the unblocked planning cells (``blocked`` is False). Every cell is joined to
its 8 neighbours: an orthogonal move costs ``pc`` metres and a diagonal move
``pc * sqrt(2)`` metres, pc = ``preset.plan_cell_size``. Both ends of a move must be
unblocked, and a diagonal move is allowed only when both orthogonal cells it passes
(the other two cells of its 2 x 2 square) are unblocked too: no corner cutting. The
distance from a source is the shortest path length on this graph, in metres; ``inf``
for blocked or unreachable cells.

Sources inside the obstacle margin
----------------------------------
A point whose planning cell is blocked (for instance an agent standing inside the
robot-radius margin of a freshly seen wall) is snapped to the nearest unblocked cell
(Euclidean distance between cell centres, ties broken in a fixed order) within
``SNAP_RADIUS`` cells; the distance from the point to that cell is counted as 0. With
no unblocked cell in reach the point has no field (all ``inf``).

The solvers
-----------
Two formulations of the same relaxation, chosen per backend (``method``; see
:func:`geodesic_method`): ``"sweeps"`` on the CPU, ``"relax"`` on accelerators. Both
apply only the elementary update ``d[v] = min(d[v], d[u] + w(u, v))`` (float32) and stop
only at a fixed point, where every edge satisfies ``d[v] <= d[u] + w(u, v)``. Float32
addition is monotone, so every such iteration from the same start (0 at the sources,
inf elsewhere) ends at the same fixed point, the greatest one below the start, whatever
order the updates ran in: the two solvers return the same fields bit for bit (tested).

``"sweeps"``: Gauss-Seidel line sweeps, batched over sources. A sweep visits the lines
of the grid in order (rows top to bottom, rows bottom to top, columns left to right,
columns right to left; four sweeps make a round) and sets each cell of a line to the
minimum of itself and the three cells of the previous line it can be entered from
(straight and the two diagonals). After a sweep every move of its 90 degree cone is
relaxed in path order, so a path made of moves of one cone is exact after one sweep, and
each change of cone along a shortest path costs at most one more round. Houses need 5-12
rounds (more for bigger houses; see ``benchmarks/bench_distance.py``). Few, cheap passes
of dependent line updates: what a CPU core does best.

Convergence: a value lowered by the second, third or fourth sweep of a round is stored
negated (a mark; the first sweep of each round clears all marks). A round that ends
without a mark had three sweeps after its first that changed nothing, so every edge of
the graph satisfies ``d[v] <= d[u] + w(u, v)``; every value is always the length of a
real walk, so the fields then equal Dijkstra's, up to float32 rounding of sums.

``"relax"``: min-plus (Bellman-Ford / Jacobi) relaxation of every cell of every field at
once: each step sets each cell to the minimum of itself and its 8 neighbours plus the
move cost, one fused elementwise pass over the whole grid. It needs as many steps as the
longest shortest path has moves (a few hundred in a house) but each is fully parallel,
which is what an accelerator wants (the sweeps would be thousands of small dependent
line updates there). Steps run ``RELAX_STEPS`` at a time inside an early-exit
``lax.while_loop``; the loop stops after a step that changed nothing. Extra steps at the
fixed point change nothing, so the block size never changes a value. Move costs are
read from two boolean masks (free cell, free 2 x 2 square), not float cost arrays, to
keep the memory traffic per step low.

Layout: the field is one [Hp + 2, Wp + 2, M, S] array (an inf border, then M maps and S
sources as the innermost "lane" axes), updated in place by ``lax.fori_loop`` over lines.
Both sweep directions then read and write contiguous lane vectors, so no transposes are
needed. Under ``jax.vmap`` the batch is folded into the lanes (``_lane_solver``).
"""

from __future__ import annotations

import functools
import math
import os

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from bfsop_jax.config import Preset, require_preset
from bfsop_jax.navigation.grid import xy_to_plan_cell

__all__ = [
    "SNAP_RADIUS",
    "distance_field",
    "distance_fields",
    "distance_fields_from_cells",
    "distance_matrix",
    "geodesic_method",
    "snap_to_free",
    "sweep_rounds",
]

# Valid sources of distance matrices solved together (lanes of one chunk; see
# ``_matrix_lanes``), per solver: few lanes keep a CPU core's sweeps in cache; an
# accelerator wants many lanes per relaxation step.
MATRIX_CHUNK = {"sweeps": 16, "relax": 1024}
RELAX_STEPS = 8  # relaxation steps between two convergence checks
METHODS = ("sweeps", "relax")
METHOD_ENV = "BFSOP_GEODESICS"  # "auto" (default), "sweeps" or "relax"
SNAP_RADIUS = 3  # planning cells searched around a blocked source (0.6 m at 0.2 m cells)
_INF = np.float32(np.inf)
# one round of sweeps: (axis, reverse); rows down, rows up, columns right, columns left
_ROUND = ((0, False), (0, True), (1, False), (1, True))


def geodesic_method(method: str | None = None) -> str:
    """The solver to use: ``method`` if given, else ``$BFSOP_GEODESICS``, else by backend.

    ``"auto"`` (or nothing) picks ``"sweeps"`` on the CPU and ``"relax"`` on GPUs and
    TPUs, from ``jax.default_backend()`` when the calling function is traced. Both
    give the same values bit for bit (module docstring); only the speed differs.
    """
    name = method if method is not None else os.environ.get(METHOD_ENV, "auto")
    if name == "auto":
        return "sweeps" if jax.default_backend() == "cpu" else "relax"
    if name not in METHODS:
        source = "method" if method is not None else f"${METHOD_ENV}"
        raise ValueError(f"{source} must be 'auto', 'sweeps' or 'relax', got {name!r}")
    return name


def _snap_offsets(radius: int) -> np.ndarray:
    """[K, 2] int32 (drow, dcol) within ``radius`` cells, nearest first (stable order)."""
    r = np.arange(-radius, radius + 1)
    off = np.stack(np.meshgrid(r, r, indexing="ij"), -1).reshape(-1, 2)
    d2 = (off**2).sum(-1)
    keep = d2 <= radius * radius
    off, d2 = off[keep], d2[keep]
    return off[np.argsort(d2, kind="stable")].astype(np.int32)


def snap_to_free(blocked: jax.Array, cells: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Nearest unblocked cell to each cell within ``SNAP_RADIUS``.

    Args:
        blocked: [Hp, Wp] bool planning map.
        cells: [..., 2] int32 (row, col).
    Returns:
        ``(snapped [..., 2] int32, found [...] bool)``; ``snapped`` equals ``cells`` when
        the cell itself is free or nothing free is in reach (then ``found`` is False).
    """
    hp, wp = blocked.shape
    off = jnp.asarray(_snap_offsets(SNAP_RADIUS))  # [K, 2]
    cand = cells[..., None, :] + off  # [..., K, 2]
    inside = (cand[..., 0] >= 0) & (cand[..., 0] < hp) & (cand[..., 1] >= 0) & (cand[..., 1] < wp)
    free = inside & ~blocked[jnp.clip(cand[..., 0], 0, hp - 1), jnp.clip(cand[..., 1], 0, wp - 1)]
    first = jnp.argmax(free, axis=-1)
    found = jnp.any(free, axis=-1)
    snapped = jnp.take_along_axis(cand, first[..., None, None], axis=-2)[..., 0, :]
    return jnp.where(found[..., None], snapped, cells).astype(jnp.int32), found


def _free_squares(free: jax.Array) -> jax.Array:
    """[M, Hp + 1, Wp + 1] bool: entry [:, a, b] tells whether the 2 x 2 square with
    top-left cell (a - 1, b - 1) is entirely free (False where it leaves the grid): a
    diagonal move across it is allowed."""
    square = free[:, :-1, :-1] & free[:, 1:, 1:] & free[:, 1:, :-1] & free[:, :-1, 1:]
    return jnp.pad(square, ((0, 0), (1, 1), (1, 1)))


def _entry_costs(blocked: jax.Array, pc: float) -> dict[str, jax.Array]:
    """Cost of entering each cell by each kind of move (inf: move not allowed).

    ``blocked`` [M, Hp, Wp] (M maps) -> each cost [Hp, Wp, M, 1], laid out like the
    field's lanes (maps, sources). ``orth``: from an orthogonal neighbour (the target must
    be free; a blocked source holds inf anyway). The diagonal costs go through the 2 x 2
    square shared by the two cells, which must be entirely free.
    """
    free = ~blocked
    orth = jnp.where(free, np.float32(pc), _INF)
    sq = jnp.where(_free_squares(free), np.float32(pc * math.sqrt(2.0)), _INF)
    # sq[:, a, b]: square with top-left cell (a - 1, b - 1)
    lanes = lambda a: jnp.transpose(a, (1, 2, 0))[..., None]
    return {
        "orth": lanes(orth),
        # entering (i, j) from (i - 1, j - 1), (i - 1, j + 1), (i + 1, j - 1), (i + 1, j + 1)
        "nw": lanes(sq[:, :-1, :-1]),
        "ne": lanes(sq[:, :-1, 1:]),
        "sw": lanes(sq[:, 1:, :-1]),
        "se": lanes(sq[:, 1:, 1:]),
    }


def _sweep(dp: jax.Array, costs: dict, axis: int, reverse: bool, mark: bool) -> jax.Array:
    """One Gauss-Seidel sweep over the lines of the padded field ``dp`` [Hp+2, Wp+2, M, S].

    ``axis`` 0 sweeps rows (lines of constant i), 1 sweeps columns. Every line is set to the
    min of itself and the three cells of the previous line it can be entered from.
    Values are stored as ``-d`` when marked: with ``mark`` a cell is marked when this sweep
    lowered it or it was already marked; without, every mark is cleared.
    """
    hp, wp = dp.shape[0] - 2, dp.shape[1] - 2
    n_lines, n_other = (hp, wp) if axis == 0 else (wp, hp)
    # the previous line is on the lower side (forward sweep) or the upper side (reverse)
    if axis == 0:
        c_lo, c_hi = (costs["sw"], costs["se"]) if reverse else (costs["nw"], costs["ne"])
    else:
        c_lo, c_hi = (costs["ne"], costs["se"]) if reverse else (costs["nw"], costs["sw"])

    def line_of(a, k, offset):
        # line k of a (index along `axis`), cells offset .. offset + n_other - 1
        lanes = a.shape[2:]
        zeros = (0,) * len(lanes)
        if axis == 0:
            return lax.dynamic_slice(a, (k, offset, *zeros), (1, n_other, *lanes))
        return lax.dynamic_slice(a, (offset, k, *zeros), (n_other, 1, *lanes))

    def step(t, dp):
        k = (n_lines - 1 - t) if reverse else t  # line index, unpadded
        prev = k + 2 if reverse else k  # padded index of the previous line
        raw = line_of(dp, k + 1, 1)
        # the previous line was written earlier in this sweep: unmarked in a clearing sweep
        fix = jnp.abs if mark else (lambda a: a)
        p_mid, p_lo, p_hi = (fix(line_of(dp, prev, off)) for off in (1, 0, 2))
        o, lo, hi = (line_of(c, k, 0) for c in (costs["orth"], c_lo, c_hi))
        best = jnp.minimum(p_mid + o, jnp.minimum(p_lo + lo, p_hi + hi))
        cur = jnp.abs(raw)
        new = jnp.minimum(cur, best)
        if mark:  # marked: lowered now, or earlier in this round
            out = jnp.where((best < cur) | (raw < 0), -new, new)
        else:
            out = new
        start = (k + 1, 1) if axis == 0 else (1, k + 1)
        return lax.dynamic_update_slice(dp, out, (*start, 0, 0))

    return lax.fori_loop(0, n_lines, step, dp)


def _initial_field(src: jax.Array, src_ok: jax.Array, hp: int, wp: int) -> jax.Array:
    """Padded [Hp + 2, Wp + 2, M, S]: 0 at each valid source, inf elsewhere."""
    m, s = src_ok.shape
    mi, si = jnp.meshgrid(jnp.arange(m), jnp.arange(s), indexing="ij")
    d0 = jnp.full((hp + 2, wp + 2, m, s), _INF)
    return d0.at[src[..., 0] + 1, src[..., 1] + 1, mi, si].set(jnp.where(src_ok, 0.0, _INF))


def _relax_lanes(blocked: jax.Array, src: jax.Array, src_ok: jax.Array, pc: float):
    """``_solve_lanes`` by whole-grid min-plus relaxation (module docstring, "relax").

    Returns the padded [Hp + 2, Wp + 2, M, S] fields and the number of relaxation steps
    run (int32, a multiple of ``RELAX_STEPS``).
    """
    m, hp, wp = blocked.shape
    free = ~blocked
    sq = _free_squares(free)
    lanes = lambda a: jnp.transpose(a, (1, 2, 0))[..., None]  # [Hp, Wp, M, 1]
    # entering (i, j) diagonally from its NW, NE, SW, SE neighbour: that 2 x 2 square free
    diag_ok = [lanes(sq[:, a : a + hp, b : b + wp]) for a in (0, 1) for b in (0, 1)]
    free_l = lanes(free)
    orth, diag = np.float32(pc), np.float32(pc * math.sqrt(2.0))

    def relax(dp):
        # Neighbour values of every interior cell, each read from a shifted window.
        at = lambda a, b: dp[a : a + hp, b : b + wp]
        # fl(min(x, y) + c) == min(fl(x + c), fl(y + c)): rounding is monotone, so taking
        # the minimum first gives the elementary updates' values bit for bit.
        straight = jnp.minimum(jnp.minimum(at(0, 1), at(2, 1)), jnp.minimum(at(1, 0), at(1, 2)))
        corners = [at(a, b) for a in (0, 2) for b in (0, 2)]  # NW, NE, SW, SE
        corner = functools.reduce(
            jnp.minimum, [jnp.where(ok, c, _INF) for ok, c in zip(diag_ok, corners, strict=True)]
        )
        best = jnp.minimum(straight + orth, corner + diag)
        new = jnp.minimum(at(1, 1), jnp.where(free_l, best, _INF))
        return lax.pad(new, _INF, ((1, 1, 0), (1, 1, 0), (0, 0, 0), (0, 0, 0)))

    def block(state):
        dp, _, steps = state
        for _ in range(RELAX_STEPS - 1):
            dp = relax(dp)
        new = relax(dp)
        return new, jnp.any(new != dp), steps + RELAX_STEPS

    d0 = _initial_field(src, src_ok, hp, wp)
    dp, _, steps = lax.while_loop(lambda st: st[1], block, (d0, jnp.bool_(True), jnp.int32(0)))
    return dp, steps


def _solve_lanes(
    blocked: jax.Array, src: jax.Array, src_ok: jax.Array, pc: float, method: str = "sweeps"
):
    """Fields of S sources on each of M maps: padded [Hp + 2, Wp + 2, M, S] float32.

    ``blocked`` [M, Hp, Wp] bool, ``src`` [M, S, 2] int32 free source cells, ``src_ok``
    [M, S] bool (False: no source). Also returns the number of rounds of sweeps run
    (``"sweeps"``) or of relaxation steps (``"relax"``), int32.
    """
    if method == "relax":
        return _relax_lanes(blocked, src, src_ok, pc)
    m, hp, wp = blocked.shape
    costs = _entry_costs(blocked, pc)
    d0 = _initial_field(src, src_ok, hp, wp)

    def round_(state):
        dp, _, rounds = state
        # The first sweep clears all marks; the other three mark what they lower. No
        # mark after a round: three sweeps after the first changed nothing -> converged.
        for k, (axis, reverse) in enumerate(_ROUND):
            dp = _sweep(dp, costs, axis=axis, reverse=reverse, mark=k > 0)
        return dp, jnp.min(dp) < 0, rounds + 1  # min: faster than any()

    dp, _, rounds = lax.while_loop(lambda st: st[1], round_, (d0, jnp.bool_(True), jnp.int32(0)))
    return dp, rounds


@functools.cache
def _lane_solver(pc: float, method: str):
    """``_solve_lanes`` whose ``jax.vmap`` folds the batch into the lanes.

    Plain vmap would put the batch in front of the grid axes, so every line step would
    touch many small strided pieces; folding it into the innermost (lane) axes keeps each
    step one wide contiguous vector operation. A batch over sources only (a shared map)
    is folded into the sources, so the map's costs are not repeated.
    """

    @jax.custom_batching.custom_vmap
    def solve(blocked, src, src_ok):
        return _solve_lanes(blocked, src, src_ok, pc, method)

    @solve.def_vmap
    def _batched(axis_size, in_batched, blocked, src, src_ok):
        b_map, b_src, b_ok = in_batched
        a = axis_size
        m, hp, wp = blocked.shape[-3:]
        s = src.shape[-2]
        if b_map:  # A * M maps
            src = src if b_src else jnp.broadcast_to(src, (a, *src.shape))
            src_ok = src_ok if b_ok else jnp.broadcast_to(src_ok, (a, *src_ok.shape))
            dp, rounds = solve(
                blocked.reshape(a * m, hp, wp), src.reshape(a * m, s, 2), src_ok.reshape(a * m, s)
            )
            dp = dp.reshape(hp + 2, wp + 2, a, m, s)
        else:  # one map set, A * S sources: [A, M, S] -> [M, A * S]
            src = src if b_src else jnp.broadcast_to(src, (a, *src.shape))
            src_ok = src_ok if b_ok else jnp.broadcast_to(src_ok, (a, *src_ok.shape))
            src = jnp.moveaxis(src, 0, 1).reshape(m, a * s, 2)
            src_ok = jnp.moveaxis(src_ok, 0, 1).reshape(m, a * s)
            dp, rounds = solve(blocked, src, src_ok)
            dp = jnp.moveaxis(dp.reshape(hp + 2, wp + 2, m, a, s), 3, 2)
        return (jnp.moveaxis(dp, 2, 0), rounds), (True, False)

    return solve


def _solve(
    blocked: jax.Array, src: jax.Array, src_ok: jax.Array, pc: float, method: str = "sweeps"
):
    """Fields of S sources on one map: padded [Hp + 2, Wp + 2, S] float32, and rounds.

    ``blocked`` [Hp, Wp], ``src`` [S, 2] free cells, ``src_ok`` [S]. Vmappable with the
    batch folded into the lanes (see ``_lane_solver``).
    """
    dp, rounds = _lane_solver(float(pc), method)(blocked[None], src[None], src_ok[None])
    return dp[:, :, 0], rounds


def _matrix_lanes(
    blocked: jax.Array, cells: jax.Array, ok: jax.Array, pc: float, chunk: int, method: str
) -> jax.Array:
    """Raw distance matrices of M maps, solving only the valid sources.

    ``blocked`` [M, Hp, Wp] bool, ``cells`` [M, S, 2] int32 free cells, ``ok`` [M, S] bool.
    Returns [M, S, S] float32 with ``out[m, a, b]`` the field of source a of map m read at
    cell b (``inf`` rows for invalid sources).

    Only the valid (map, source) pairs are solved: they are gathered into chunks of
    ``chunk`` lanes, each lane carrying its own map (with M = 1 the lanes share the map's
    costs, as in the dense layout), and the chunks run one after another
    (as many as the valid pairs need; none when there are none). SOP instances are mostly
    padding (an instance posed over one or two landmarks uses a handful of its
    ``1 + n_loi * n_viewpoints`` nodes), so this solves a fraction of the lanes a dense
    [M, S] layout would. A lane's sweeps do not depend on the other lanes of its chunk,
    and a converged lane is unchanged by further rounds, so the values equal the dense
    solver's bit for bit.
    """
    m, s = ok.shape
    total = m * s
    size = min(chunk, total)
    flat_ok = ok.reshape(total)
    count = jnp.sum(flat_ok, dtype=jnp.int32)
    order = jnp.nonzero(flat_ok, size=total, fill_value=0)[0].astype(jnp.int32)
    order = jnp.concatenate([order, jnp.zeros(size, jnp.int32)])  # room for the last chunk
    flat_cells = cells.reshape(total, 2)
    lane = jnp.arange(size)

    def one_chunk(r, out):
        pairs = lax.dynamic_slice(order, (r * size,), (size,))
        real = r * size + lane < count
        if m == 1:  # one map: the chunk's lanes share its costs (cheaper sweeps)
            dp, _ = _solve_lanes(blocked, flat_cells[pairs][None], real[None], pc, method)
            got = dp[cells[0, :, 0] + 1, cells[0, :, 1] + 1, 0].T  # [C, S]
        else:
            maps = pairs // s
            dp, _ = _solve_lanes(
                blocked[maps], flat_cells[pairs][:, None], real[:, None], pc, method
            )
            read = cells[maps]  # [C, S, 2]: every cell of the lane's map
            got = dp[read[..., 0] + 1, read[..., 1] + 1, lane[:, None], 0]  # [C, S]
        into = jnp.where(real, pairs, total)  # padding lanes are dropped
        return out.at[into].set(got, mode="drop")

    rounds = (count + size - 1) // size
    out = lax.fori_loop(0, rounds, one_chunk, jnp.full((total, s), _INF))
    return out.reshape(m, s, s)


@functools.cache
def _matrix_solver(pc: float, chunk: int, method: str):
    """``_matrix_lanes`` whose ``jax.vmap`` folds the batch into the maps (one pool of
    valid lanes for the whole batch)."""

    @jax.custom_batching.custom_vmap
    def solve(blocked, cells, ok):
        return _matrix_lanes(blocked, cells, ok, pc, chunk, method)

    @solve.def_vmap
    def _batched(axis_size, in_batched, blocked, cells, ok):
        a = axis_size
        blocked, cells, ok = (
            x if b else jnp.broadcast_to(x, (a, *x.shape))
            for x, b in zip((blocked, cells, ok), in_batched, strict=True)
        )
        m, s = ok.shape[-2:]
        out = solve(
            blocked.reshape(a * m, *blocked.shape[-2:]),
            cells.reshape(a * m, s, 2),
            ok.reshape(a * m, s),
        )
        return out.reshape(a, m, s, s), True

    return solve


def _check_blocked(blocked: jax.Array, preset: Preset) -> None:
    if blocked.shape[-2:] != tuple(preset.plan_shape):
        raise ValueError(
            f"blocked map has shape {blocked.shape[-2:]}, preset {preset.name!r} expects "
            f"plan_shape {preset.plan_shape}"
        )


def distance_fields_from_cells(
    blocked: jax.Array,
    cells: jax.Array,
    valid: jax.Array,
    preset: Preset,
    method: str | None = None,
) -> jax.Array:
    """Fields from source cells: [Hp, Wp] bool, [S, 2] int32, [S] bool -> [S, Hp, Wp].

    Blocked source cells are snapped (module docstring); invalid sources give all-inf.
    ``method``: the solver (:func:`geodesic_method`; same values either way).
    """
    preset = require_preset(preset)
    _check_blocked(blocked, preset)
    method = geodesic_method(method)
    blocked = jnp.asarray(blocked, bool)
    src, found = snap_to_free(blocked, jnp.asarray(cells, jnp.int32))
    ok = jnp.asarray(valid, bool) & found
    dp, _ = _solve(blocked, src, ok, preset.plan_cell_size, method)
    return jnp.transpose(dp[1:-1, 1:-1], (2, 0, 1))


def sweep_rounds(
    blocked: jax.Array,
    cells: jax.Array,
    valid: jax.Array,
    preset: Preset,
    method: str = "sweeps",
) -> jax.Array:
    """Diagnostic: iterations the solver runs for these sources (int32).

    ``"sweeps"``: rounds of four sweeps; ``"relax"``: relaxation steps (a multiple of
    ``RELAX_STEPS``). The last round (block of steps) is the one that finds nothing left
    to change.
    """
    preset = require_preset(preset)
    _check_blocked(blocked, preset)
    method = geodesic_method(method)
    blocked = jnp.asarray(blocked, bool)
    src, found = snap_to_free(blocked, jnp.asarray(cells, jnp.int32))
    ok = jnp.asarray(valid, bool) & found
    return _solve(blocked, src, ok, preset.plan_cell_size, method)[1]


def distance_fields(
    blocked: jax.Array, sources_xy: jax.Array, preset: Preset, method: str | None = None
) -> jax.Array:
    """Geodesic distance (metres) from each source: [Hp, Wp] bool, [S, 2] xy -> [S, Hp, Wp].

    ``inf`` where blocked or unreachable. Equals Dijkstra on the graph of the module
    docstring up to float32 rounding. ``method``: the solver (:func:`geodesic_method`).
    """
    preset = require_preset(preset)
    sources_xy = jnp.asarray(sources_xy, jnp.float32)
    if sources_xy.ndim != 2 or sources_xy.shape[-1] != 2:
        raise ValueError(f"sources_xy must have shape [S, 2], got {sources_xy.shape}")
    cells = xy_to_plan_cell(sources_xy, preset)
    valid = jnp.ones(sources_xy.shape[0], bool)
    return distance_fields_from_cells(blocked, cells, valid, preset, method)


def distance_field(
    blocked: jax.Array, source_xy: jax.Array, preset: Preset, method: str | None = None
) -> jax.Array:
    """Geodesic distance (metres) from one point: [Hp, Wp] bool, [2] xy -> [Hp, Wp] float32."""
    source_xy = jnp.asarray(source_xy, jnp.float32)
    if source_xy.shape != (2,):
        raise ValueError(f"source_xy must have shape [2], got {source_xy.shape}")
    return distance_fields(blocked, source_xy[None], preset, method)[0]


def distance_matrix(
    blocked: jax.Array,
    points_xy: jax.Array,
    valid: jax.Array,
    preset: Preset,
    method: str | None = None,
) -> jax.Array:
    """Pairwise geodesic distances: [Hp, Wp] bool, [S, 2] xy, [S] bool -> [S, S] float32.

    ``d[a, b]`` is the field from point a read at point b's (snapped) cell, made exactly
    symmetric with an elementwise min with its transpose; ``inf`` for invalid points and
    unreachable pairs; 0 on the diagonal of valid points. ``method``: the solver
    (:func:`geodesic_method`; same values either way).
    """
    preset = require_preset(preset)
    _check_blocked(blocked, preset)
    method = geodesic_method(method)
    points_xy = jnp.asarray(points_xy, jnp.float32)
    if points_xy.ndim != 2 or points_xy.shape[-1] != 2:
        raise ValueError(f"points_xy must have shape [S, 2], got {points_xy.shape}")
    valid = jnp.asarray(valid, bool)
    if valid.shape != points_xy.shape[:1]:
        raise ValueError(f"valid must have shape {points_xy.shape[:1]}, got {valid.shape}")
    blocked = jnp.asarray(blocked, bool)
    cells, found = snap_to_free(blocked, xy_to_plan_cell(points_xy, preset))
    ok = valid & found
    solve = _matrix_solver(float(preset.plan_cell_size), MATRIX_CHUNK[method], method)
    m = solve(blocked[None], cells[None], ok[None])[0]  # m[a, b] = field a at cell b
    m = jnp.minimum(m, m.T)
    pair_ok = ok[:, None] & ok[None, :]
    m = jnp.where(pair_ok, m, _INF)
    eye = jnp.eye(points_xy.shape[0], dtype=bool)
    return jnp.where(eye & valid[:, None], 0.0, m)
