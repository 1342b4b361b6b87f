"""An open repair for harvest: decoded wall logits -> the most probable layout the generator can make.

Why. ``HarvestRepair``'s default snaps the walls to the nearest *dataset* layout, so G(z) can only
return wall layouts already in the dataset: the repair is closed, and a search over z never finds
a new layout (DESIGN.md, "Repair and generator quality"). Thresholding the logits is open but
leaves broken walls that enclose nothing. ``OpenRooms`` is open and keeps closed rooms: it decodes
the walls into the procedural generator's own terms (paper §5.2.1, ``maps.py``) — per corner no
room or a rectangle (h, w) in the generator's range, merged and walled by the generator's own
functions, at most one entrance per merged region — and returns the choice the wall logits find
most probable. Every result is a layout the generator itself could produce (valid, rooms closed
by construction), but it need not be in any dataset.

Most probable. With Bernoulli logits ``l``, ``log p(W | l) = Σ W·l − Σ softplus(l)``: the rooms
maximise the sum of wall logits over the wall cells (the nearest repair's rule, over generator
layouts instead of dataset ones). A merged region's entrance is its candidate cell
(``maps.entrance_candidates``) with the lowest wall logit. Whether the region gets it weighs the
decoder's evidence against the generator's prior (no entrance with probability 1 − p, each of the
n candidates with p / n; carving cell c multiplies the likelihood by ``r_c = exp(−l_c)``):

- ``entrances="likelihood"``: iff that one logit is negative. A decoder unsure where along a wall
  the entrance is leaves some candidate below 0 in most rooms: 20% of maps kept a closed room,
  against the dataset's 52%.
- ``entrances="posterior"``: iff an entrance anywhere is more probable than none,
  ``Σ_c r_c > n (1 − p) / p``. Exact on a map's own cells, but decodes of z drawn from the prior
  are blurrier than the dataset's (their walls' median logit 2.1 against 4.5 for encoded dataset
  maps, quick VAE) and scatter small doubts along every wall: the sum counts them all, so 55% of
  merged regions got an entrance (the generator: half) and 44.8% of maps kept a closed room against
  fresh maps' 51.4% (``benchmarks/harvest_repair_fidelity.py``). The search itself is not at fault:
  given a dataset map's cells as logits it returns that map (closed rooms as closed) and more
  rounds change nothing; the VAE's decodes also hold fewer rooms (1.07 merged regions a map
  against 1.24), which the repair cannot add back.
- ``entrances="tempered"`` (the default since issue 48): the L^T norm of the ratios instead of their
  sum, ``(Σ_c r_c^T)^(1/T) > n (1 − p) / p`` with ``T = TEMPER`` (1.5): between the posterior's sum
  (T = 1) and the single most probable position (T → ∞, 57% closed); one decisive dip still opens
  a region, a wall unsure all along does not. On the quick VAE's decodes of the prior: 53% of maps
  with a closed room; on encoded dataset maps it separates entrances from none as well as the sum
  does (ROC AUC 0.85 against 0.84). T was chosen on those decodes; other VAEs blur differently.

Saved generators record their rule (``config``), so those saved before ``tempered`` decode as
they did.

Calibrated to the decoder (``fitted``, once, when a generator is made). The rules above are exact for
confident logits, and decodes of the prior are not: on the quick preset's 20-epoch VAE the unshifted
search found 0.98 rooms a map against the dataset's 1.94, and the tempered rule gave 28% of merged
regions an entrance against the generator's half. Like the apples' shift, two constants put each
of the generator's draws at its rate on 256 decodes of the prior: ``wall_shift``, added to the wall
logits before the rooms are chosen, so that they hold the dataset's mean number of rooms
(``fit_wall_shift``, the target read off 256 dataset maps by the same search, ``mean_rooms``), and
``entrance_shift``, which lowers the entrance rule's bar so that the generator's share of merged
regions gets an entrance (``fit_entrance_shift``; the entrances are carved by the unshifted
logits). Generators saved before record neither and decode without them.

Search. Corners interact through merging: where rectangles overlap, each one's edges are hidden,
and one corner at a time gets stuck (on 200 generated maps given as confident logits, coordinate
ascent over single corners recovered 70–89% of the walls). So the search moves two corners at a
time, the two on one side of the grid, over all ~101² pairs at once: the union's row ``r`` is
``[0, L_r) ∪ [S − R_r, S)`` and its walls in row ``r`` depend only on ``L`` in rows ``r − 1..r + 1``
(the other side ``R`` fixed), so a table of each row's wall-logit sum for every such triple
(``row_tables``) scores every pair with one lookup per row. The other three sides are the left side
of the mirrored or transposed grid. Block coordinate ascent over the four sides runs from eight
starts (no rooms and the largest rooms, each side first) and keeps the final layout with the
highest exact score (entrances carved). Given as confident logits, 998 of 1,000 generated maps
come back with their own walls; on a trained generator's decodes the layout found scores at least
the nearest dataset layout's likelihood on 98% (with ``entrances="likelihood"``,
``benchmarks/harvest_open_repair.py``). With the defaults (tempered entrances, spread apples),
61.6% of a 100-epoch VAE's decoded layouts are in no dataset map, against 68.6% of fresh procedural
maps; a map takes 20-55 ms on a shared CPU core (``benchmarks/harvest_repair_fidelity.py``).

Apples (``apples="spread"``, the default): as the generator places them, 1-3 round clusters in each
of the layout's rooms (its merged regions' interiors and the space outside), read off the apple
logits shifted by ``apple_shift``, which the repair fits once when its generator is made
(``fitted``; ``apples.placed_apples`` and ``apples.fit_shift``). ``apples="clusters"`` (what
generators saved from issue 48 until "spread" record): the same without the shift and the
spacing. ``apples=K`` (what generators saved before then record, so they decode as they did): as
``HarvestRepair``'s top-K rule (``repair.place_apples``), exactly K on the free cells with the
highest apple logits. Spawn corners are free either way.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.envs.harvest.apples import SHIFT_RANGE, SHIFT_STEPS, SPREAD, bisect, fit_shift, placed_apples
from worldagent.envs.harvest.maps import NUM_CORNERS, MapConfig, corner_bounds, entrance_candidates, region_walls
from worldagent.envs.harvest.repair import LOGIT_CLIP, apple_setting, corner_mask, mean_apples, place_apples, shift_setting
from worldagent.envs.harvest.world import HarvestMap
from worldagent.errors import WorldagentError

SETTINGS = ("apples", "apple_shift", "wall_shift", "entrance_shift", "rounds", "entrances")
ENTRANCE_RULES = ("tempered", "posterior", "likelihood")  # the first is the default
TEMPER = 1.5  # the exponent T of the tempered rule (module doc)
DEFAULT_ROUNDS = 1  # a second round recovered 2 more of 1,000 generated maps at twice the cost
FIT_MAPS = 256  # dataset maps whose rooms give the wall shift's target (``mean_rooms``; ~5 s on 2 cores)
WALL_SHIFT_RANGE = (-3.0, 5.0)  # where the wall shift is looked for: the quick VAE's is about 1
WALL_SHIFT_STEPS = 7  # to 0.06 logits (about 0.06 rooms a map); each step searches the rooms of 256 decodes (~5 s on 2 cores)
MAX_ROUNDS = 8

# A frame shows the grid so that the corners moved are its left side (TL, BL): transposed?,
# mirrored left-right?, the corners moved (its TL, BL) and the corners fixed (its TR, BR), in the
# order TL, TR, BL, BR of ``spawn_corners``. Transposing swaps a rectangle's height and width.
FRAMES = (
    (False, False, (0, 2), (1, 3)),  # left side
    (False, True, (1, 3), (0, 2)),  # right side
    (True, False, (0, 1), (2, 3)),  # top side
    (True, True, (2, 3), (0, 1)),  # bottom side
)
LEFT, RIGHT, TOP, BOTTOM = range(4)
ORDERS = ((LEFT, RIGHT, TOP, BOTTOM), (RIGHT, LEFT, BOTTOM, TOP), (TOP, BOTTOM, LEFT, RIGHT), (BOTTOM, TOP, RIGHT, LEFT))


def corner_options(size: int) -> tuple[np.ndarray, np.ndarray]:
    """(heights, widths) int32[O] of one corner's options: 0 is no room, then every (h, w) the generator draws."""
    low, high = MapConfig(size=size).extent_range
    heights, widths = np.meshgrid(np.arange(low, high + 1), np.arange(low, high + 1), indexing="ij")
    return np.concatenate([[low], heights.ravel()]).astype(np.int32), np.concatenate([[low], widths.ravel()]).astype(np.int32)


@functools.lru_cache(maxsize=4)
def search_tables(size: int) -> dict[str, np.ndarray]:
    """Constants of the search for a ``size`` grid (numpy).

    Returns:
        ``top``, ``bottom`` int32[O, S]: the width a corner option covers in each row, grown from
        the top or the bottom of the left side (0 for no room); ``values`` int32[V]: the widths a
        row of one side can have (0, then the generator's range); ``triples`` int32[O², S]: for
        the left pair (top option i, bottom option j) at ``i·O + j``, the index ``a·V² + b·V + c``
        of each row's (above, own, below) width in ``values``; ``swap`` int32[O]: the option of
        the transposed rectangle.
    """
    heights, widths = corner_options(size)
    low, high = MapConfig(size=size).extent_range
    rows, present = np.arange(size), np.arange(len(heights)) > 0
    top = np.where(present[:, None] & (rows[None] < heights[:, None]), widths[:, None], 0)
    bottom = np.where(present[:, None] & (rows[None] >= size - heights[:, None]), widths[:, None], 0)
    values = np.concatenate([[0], np.arange(low, high + 1)]).astype(np.int32)
    own = np.maximum(top[:, None], bottom[None, :]).reshape(-1, size)
    own = np.where(own == 0, 0, own - low + 1)  # width -> index in values
    above = np.concatenate([own[:, :1], own[:, :-1]], axis=1)  # row 0's 'above' is off the grid (row_tables ignores it)
    below = np.concatenate([own[:, 1:], own[:, -1:]], axis=1)
    count = len(values)
    side = high - low + 1
    swap = np.concatenate([[0], 1 + np.arange(side * side).reshape(side, side).T.ravel()])
    return {
        "top": top.astype(np.int32),
        "bottom": bottom.astype(np.int32),
        "values": values,
        "triples": (above * count * count + own * count + below).astype(np.int32),
        "swap": swap.astype(np.int32),
    }


def row_tables(wall_logit: jax.Array, other: jax.Array) -> jax.Array:
    """f32[S, V, V, V]: row r's sum of wall logits over its wall cells, for left widths (above, own, below).

    The union's row r is ``[0, L_r) ∪ [S − other_r, S)``: inside but for the gap ``[L_r, S − other_r)``.
    A cell is a wall iff it is inside and one of its 8 neighbours is not (beyond the grid counts
    as inside, as in ``maps.bordering_walls``): row r's walls are the cells of the gaps of rows
    r − 1..r + 1, each widened by one cell, less row r's own gap. Sums over intervals come from
    the row's cumulative logits; the union of three intervals by inclusion-exclusion.

    Args:
        wall_logit: f32[S, S] wall logits.
        other: int32[S] the width the right side covers in each row.
    """
    size = wall_logit.shape[0]
    values = jnp.asarray(search_tables(size)["values"])
    gap_start, gap_stop = jnp.broadcast_to(values[None, :], (size, len(values))), jnp.broadcast_to(size - other[:, None], (size, len(values)))
    has_gap = gap_start < gap_stop
    near_start = jnp.where(has_gap, jnp.maximum(gap_start - 1, 0), size)  # [S, V]; empty: [S, S)
    near_stop = jnp.where(has_gap, jnp.minimum(gap_stop + 1, size), size)
    no_gap = jnp.full((1, len(values)), size)  # off the grid
    cumulative = jnp.concatenate([jnp.zeros((size, 1)), jnp.cumsum(wall_logit, axis=1)], axis=1)  # [S, S + 1]
    rows = jnp.arange(size)[:, None, None, None]

    def total(start, stop):  # sum of row r's logits over [start, stop), broadcast over [S, V, V, V]
        return jnp.where(start < stop, cumulative[rows, stop] - cumulative[rows, jnp.minimum(start, stop)], 0.0)

    above = (jnp.concatenate([no_gap, near_start[:-1]])[:, :, None, None], jnp.concatenate([no_gap, near_stop[:-1]])[:, :, None, None])
    own = (near_start[:, None, :, None], near_stop[:, None, :, None])
    below = (jnp.concatenate([near_start[1:], no_gap])[:, None, None, :], jnp.concatenate([near_stop[1:], no_gap])[:, None, None, :])

    def meet(*intervals):
        return functools.reduce(jnp.maximum, [i[0] for i in intervals]), functools.reduce(jnp.minimum, [i[1] for i in intervals])

    singles = total(*above) + total(*own) + total(*below)
    pairs = total(*meet(above, own)) + total(*meet(above, below)) + total(*meet(own, below))
    return singles - pairs + total(*meet(above, own, below)) - total(gap_start[:, None, :, None], gap_stop[:, None, :, None])


def pair_scores(wall_logit: jax.Array, other: jax.Array) -> jax.Array:
    """f32[O²]: the sum of wall logits over the union's walls for every left pair (TL option i, BL option j) at ``i·O + j``.

    Args:
        wall_logit: f32[S, S] wall logits.
        other: int32[S] the width the right side covers in each row.
    """
    size = wall_logit.shape[0]
    tables = row_tables(wall_logit, other).reshape(size, -1)
    triples = jnp.asarray(search_tables(size)["triples"])
    # Row by row from each row's small table: about 5x faster on CPU than one gather from all.
    return sum(tables[r].at[triples[:, r]].get(mode="promise_in_bounds") for r in range(size))


def frame_logits(wall_logit: jax.Array) -> jax.Array:
    """f32[4, S, S]: the wall logits as each frame of ``FRAMES`` shows them."""
    views = []
    for transpose, mirror, _, _ in FRAMES:
        view = wall_logit.T if transpose else wall_logit
        views.append(view[:, ::-1] if mirror else view)
    return jnp.stack(views)


def block_step(views: jax.Array, choice: jax.Array, frame: jax.Array) -> jax.Array:
    """int32[4]: ``choice`` with the best pair of options for the two corners of side ``frame`` (i32), the others fixed.

    Args:
        views: f32[4, S, S] ``frame_logits``.
        choice: int32[4] each corner's option (``corner_options``).
        frame: index into ``FRAMES``.
    """
    size = views.shape[-1]
    tables = search_tables(size)
    count = len(tables["swap"])
    moved = jnp.asarray([f[2] for f in FRAMES])[frame]
    fixed = jnp.asarray([f[3] for f in FRAMES])[frame]
    swap = jnp.where(jnp.asarray([f[0] for f in FRAMES])[frame], jnp.asarray(tables["swap"]), jnp.arange(count))
    other = jnp.maximum(jnp.asarray(tables["top"])[swap[choice[fixed[0]]]], jnp.asarray(tables["bottom"])[swap[choice[fixed[1]]]])
    best = jnp.argmax(pair_scores(views[frame], other))
    return choice.at[moved].set(swap[jnp.stack([best // count, best % count])])


def entrance_decisions(wall_logit: jax.Array, candidates: jax.Array, rule: str = ENTRANCE_RULES[0], offset: float = 0.0) -> jax.Array:
    """bool[4]: whether each merged region gets an entrance, from its candidate cells ``candidates`` bool[4, H·W].

    ``rule`` (module doc): "likelihood", iff the lowest candidate logit is below ``offset`` (0 unfitted);
    "posterior", iff an entrance is more probable than none under the generator's prior (none with
    probability 1 − p, each of the n candidates with p / n) times the likelihood (carving cell c
    multiplies it by ``r_c = exp(−l_c)``), summed over where it is: ``Σ_c r_c > n (1 − p) / p``;
    "tempered", the same with the L^T norm of the ratios, ``(Σ_c r_c^T)^(1/T) > n (1 − p) / p``,
    ``T = TEMPER``. ``offset`` (the fitted ``entrance_shift``) lowers either bar by that many logits.
    """
    logit = wall_logit.reshape(1, -1)
    if rule == "likelihood":
        return jnp.where(candidates, logit, jnp.inf).min(axis=1) < offset
    power = TEMPER if rule == "tempered" else 1.0
    chance = MapConfig().entrance_probability
    evidence = jax.nn.logsumexp(jnp.where(candidates, -power * logit, -jnp.inf), axis=1) / power
    return evidence > jnp.log(jnp.maximum(candidates.sum(axis=1), 1)) + np.log((1.0 - chance) / chance) - offset


def carve_best_entrances(
    wall_logit: jax.Array, walls: jax.Array, group_masks: jax.Array, rule: str = ENTRANCE_RULES[0], offset: float = 0.0
) -> jax.Array:
    """bool[H, W]: per merged region, its entrance candidate with the lowest wall logit, if the region gets an
    entrance (``entrance_decisions``)."""
    candidates = entrance_candidates(walls, group_masks).reshape(NUM_CORNERS, -1)
    lowest = jnp.where(candidates, wall_logit.reshape(1, -1), jnp.inf)
    carve = entrance_decisions(wall_logit, candidates, rule, offset) & candidates.any(axis=1)
    chosen = jax.nn.one_hot(jnp.argmin(lowest, axis=1), lowest.shape[1], dtype=bool) & carve[:, None]
    return chosen.any(axis=0).reshape(walls.shape)


def rooms_of(choice: jax.Array, size: int) -> tuple[jax.Array, jax.Array]:
    """(present bool[4], bounds int32[4, 4]) of the corners' options ``choice`` int32[4]."""
    heights, widths = (jnp.asarray(side) for side in corner_options(size))
    return choice > 0, corner_bounds(heights[choice], widths[choice], size)


def layout_walls(wall_logit: jax.Array, choice: jax.Array, rule: str = ENTRANCE_RULES[0]) -> jax.Array:
    """bool[S, S]: the generator's walls for corner options ``choice`` int32[4], entrances carved by ``wall_logit`` f32[S, S]."""
    size = wall_logit.shape[0]
    group_masks, walls = region_walls(*rooms_of(choice, size), size)
    return walls & ~carve_best_entrances(wall_logit, walls, group_masks, rule)


def layout_scores(wall_logit: jax.Array, choices: jax.Array, rule: str = ENTRANCE_RULES[0]) -> jax.Array:
    """f32[N]: the sum of wall logits over the walls (entrances carved) of each row of ``choices`` int32[N, 4]."""
    return jax.vmap(lambda choice: jnp.where(layout_walls(wall_logit, choice, rule), wall_logit, 0.0).sum())(choices)


def choose_rooms(wall_logit: jax.Array, rounds: int = DEFAULT_ROUNDS, rule: str = ENTRANCE_RULES[0]) -> jax.Array:
    """int32[4]: each corner's option (``corner_options``) of the most probable layout found.

    Args:
        wall_logit: f32[S, S] decoded wall logits of a square grid.
        rounds: passes over the four sides from each start.
        rule: the entrance rule of ``carve_best_entrances`` that the starts' final layouts are compared with.
    """
    views = frame_logits(wall_logit)
    largest = len(corner_options(wall_logit.shape[0])[0]) - 1
    starts = jnp.asarray([[0] * NUM_CORNERS] * len(ORDERS) + [[largest] * NUM_CORNERS] * len(ORDERS), jnp.int32)
    orders = jnp.asarray([order * rounds for order in ORDERS * 2], jnp.int32)  # [starts, steps]

    def ascend(start, order):
        return jax.lax.scan(lambda choice, frame: (block_step(views, choice, frame), None), start, order)[0]

    finals = jax.vmap(ascend)(starts, orders)
    return finals[jnp.argmax(layout_scores(wall_logit, finals, rule))]


def chosen_rooms(wall_logit: jax.Array, rounds: int = DEFAULT_ROUNDS, rule: str = ENTRANCE_RULES[0], wall_shift: float = 0.0) -> jax.Array:
    """int32[4]: ``choose_rooms`` on the wall logits f32[S, S] shifted by ``wall_shift``, then clipped."""
    return choose_rooms(jnp.clip(wall_logit + wall_shift, -LOGIT_CLIP, LOGIT_CLIP), rounds, rule)


def closed_layout(wall_logit: jax.Array, rounds: int, rule: str, wall_shift: float) -> tuple[jax.Array, jax.Array]:
    """(group_masks bool[4, S, S], walls bool[S, S]) of the rooms ``chosen_rooms`` finds, before any entrance is carved."""
    size = wall_logit.shape[-1]
    return region_walls(*rooms_of(chosen_rooms(wall_logit, rounds, rule, wall_shift), size), size)


def open_layout(
    logits: jax.Array, rounds: int = DEFAULT_ROUNDS, rule: str = ENTRANCE_RULES[0], wall_shift: float = 0.0, entrance_shift: float = 0.0
) -> tuple[jax.Array, jax.Array]:
    """(walls bool[S, S], rooms bool[R, S, S]) from logits f32[2, S, S]: the generator layout the wall logits
    (shifted by ``wall_shift``) find most probable, entrances carved by the unshifted ones (the rule's bar
    lowered by ``entrance_shift``), and its rooms as the generator's apple step sees them (``maps.generate_map``)."""
    wall_logit = jnp.clip(logits[0], -LOGIT_CLIP, LOGIT_CLIP)
    group_masks, closed = closed_layout(logits[0], rounds, rule, wall_shift)
    walls = closed & ~carve_best_entrances(wall_logit, closed, group_masks, rule, entrance_shift)
    return walls, jnp.concatenate([group_masks & ~closed[None], ~group_masks.any(axis=0)[None]])


def open_map(
    logits: jax.Array,
    apples: int | str,
    rounds: int = DEFAULT_ROUNDS,
    rule: str = ENTRANCE_RULES[0],
    shift: float | None = None,
    wall_shift: float = 0.0,
    entrance_shift: float = 0.0,
) -> HarvestMap:
    """One valid map from logits f32[2, S, S]: ``open_layout``'s walls, its apples in clusters (``apples`` "spread"
    shifted by ``shift``, or "clusters") or on the K free cells with the highest logits (``apples=K``)."""
    wall_logit, apple_logit = jnp.clip(logits[0], -LOGIT_CLIP, LOGIT_CLIP), jnp.clip(logits[1], -LOGIT_CLIP, LOGIT_CLIP)
    walls, rooms = open_layout(logits, rounds, rule, wall_shift, entrance_shift)
    if isinstance(apples, int):
        return place_apples(walls, wall_logit, apple_logit, apples)
    size = wall_logit.shape[0]
    return HarvestMap(walls=walls & ~jnp.asarray(corner_mask(size, size)), apples=placed_apples(rooms, apple_logit, apples, shift))


@functools.partial(jax.jit, static_argnames=("rounds", "rule"))
def _mean_rooms(wall_shift: float, wall_logits: jax.Array, rounds: int, rule: str) -> jax.Array:
    return jax.vmap(lambda logit: (chosen_rooms(logit, rounds, rule, wall_shift) > 0).sum())(wall_logits).mean()


def mean_rooms(wall_logits: jax.Array, rounds: int = DEFAULT_ROUNDS, rule: str = ENTRANCE_RULES[0], wall_shift: float = 0.0) -> float:
    """The mean number of corners with a room in the layouts found for wall logits f32[B, S, S] shifted by ``wall_shift``."""
    return float(_mean_rooms(wall_shift, jnp.asarray(wall_logits, jnp.float32), rounds, rule))


def layout_logits(walls: jax.Array) -> jax.Array:
    """f32[B, S, S]: maps' walls bool[B, S, S] as confident wall logits (the search finds their own layouts)."""
    return jnp.where(jnp.asarray(walls), LOGIT_CLIP, -LOGIT_CLIP)


def fit_wall_shift(wall_logits: jax.Array, target: float, rounds: int = DEFAULT_ROUNDS, rule: str = ENTRANCE_RULES[0]) -> float:
    """The wall-logit shift with which the layouts found for decodes f32[B, S, S] have ``target`` rooms on average
    (the dataset's): a blurry decoder's walls are faint, and unshifted the search finds too few rooms."""
    return bisect(lambda shift: mean_rooms(wall_logits, rounds, rule, shift), target, WALL_SHIFT_RANGE, WALL_SHIFT_STEPS)


def region_candidates(wall_logits: jax.Array, wall_shift: float, rounds: int = DEFAULT_ROUNDS, rule: str = ENTRANCE_RULES[0]) -> jax.Array:
    """bool[B, 4, S·S]: each merged region's entrance candidates in the layouts found for wall logits f32[B, S, S]."""

    def one(logit):
        group_masks, closed = closed_layout(logit, rounds, rule, wall_shift)
        return entrance_candidates(closed, group_masks).reshape(NUM_CORNERS, -1)

    return jax.jit(jax.vmap(one))(wall_logits)


@functools.partial(jax.jit, static_argnames="rule")
def _entrance_share(offset: float, wall_logits: jax.Array, candidates: jax.Array, rule: str) -> jax.Array:
    possible = candidates.any(axis=-1)
    clipped = jnp.clip(wall_logits, -LOGIT_CLIP, LOGIT_CLIP)
    carve = jax.vmap(lambda logit, cells: entrance_decisions(logit, cells, rule, offset))(clipped, candidates)
    return (carve & possible).sum() / jnp.maximum(possible.sum(), 1)


def entrance_share(wall_logits: jax.Array, candidates: jax.Array, rule: str = ENTRANCE_RULES[0], offset: float = 0.0) -> float:
    """The share of merged regions with a candidate (``region_candidates``) that get an entrance (``entrance_decisions``)."""
    return float(_entrance_share(offset, wall_logits, candidates, rule))


def fit_entrance_shift(wall_logits: jax.Array, wall_shift: float, rounds: int = DEFAULT_ROUNDS, rule: str = ENTRANCE_RULES[0]) -> float:
    """The offset of the entrance rule's bar with which the merged regions of decodes f32[B, S, S] get an entrance
    as often as the generator gives one (``MapConfig.entrance_probability``)."""
    candidates = region_candidates(wall_logits, wall_shift, rounds, rule)
    chance = MapConfig().entrance_probability
    return bisect(lambda offset: entrance_share(wall_logits, candidates, rule, offset), chance, SHIFT_RANGE, SHIFT_STEPS)


def _count(name: str, value, low: int, high: int, hint: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
        raise WorldagentError(f"{name}={value!r}; pick an integer from {low} to {high} ({hint}).")
    return int(value)


@struct.dataclass
class OpenRooms:
    """New valid walls: the generator layout the decoder finds most probable (closed rooms kept), apples in clusters.

    Attributes:
        apples: ``"spread"`` or ``"clusters"`` (as the generator places them) or K, the apple count of every map (static).
        rounds: block-coordinate passes over the four sides from each start (static).
        entrances: "tempered" (default), "posterior" or "likelihood", the entrance rule (``carve_best_entrances``, static).
        grid: (S, S) of the maps (static).
        apple_shift: the apple logits' shift of ``"spread"`` (``fitted``; None: not fitted, no shift) (static).
        wall_shift: the wall logits' shift before the rooms are chosen (``fitted``; None: not fitted, no shift) (static).
        entrance_shift: how far the entrance rule's bar is lowered (``fitted``; None: not fitted, 0) (static).
    """

    apples: int | str = struct.field(pytree_node=False)
    rounds: int = struct.field(pytree_node=False)
    entrances: str = struct.field(pytree_node=False)
    grid: tuple = struct.field(pytree_node=False)
    apple_shift: float | None = struct.field(pytree_node=False, default=None)
    wall_shift: float | None = struct.field(pytree_node=False, default=None)
    entrance_shift: float | None = struct.field(pytree_node=False, default=None)

    @classmethod
    def from_dataset(cls, dataset, config=None) -> OpenRooms:
        """The repair for maps like ``dataset``'s (a harvest ``WorldDataset``).

        ``config``: ``apples`` "spread" (default: as the generator places them, kept apart), "clusters"
        or K (exactly K on the cells with the highest apple logits); ``apple_shift``, ``wall_shift`` and
        ``entrance_shift`` (default: fitted when the generator is made; generators saved before the wall
        and entrance shifts decode without them); ``rounds`` (default 1); ``entrances`` "tempered"
        (default), "posterior" (what generators saved before then record) or "likelihood".
        """
        config = dict(config or {})
        unknown = set(config) - set(SETTINGS)
        if unknown:
            raise WorldagentError(
                f"unknown setting(s) {sorted(unknown)} of harvest's open repair; "
                "use apples=spread|clusters|K, apple_shift=X, wall_shift=X, entrance_shift=X, rounds=N and entrances=tempered|posterior|likelihood."
            )
        grid = tuple(int(s) for s in dataset.cell_shape[1:])
        if grid[0] != grid[1] or grid[0] < 10:  # the generator's rooms are 5 to side - 5 cells
            raise WorldagentError(f"harvest's open repair needs square maps of side 10 or more, as the generator makes; got {grid}.")
        try:
            apples = apple_setting(SPREAD if config.get("apples") is None else config["apples"], grid, dataset.worlds)
        except ValueError as error:
            raise WorldagentError(f"apples={config['apples']!r}: {error}.") from None
        rounds = _count("rounds", config.get("rounds", DEFAULT_ROUNDS), 1, MAX_ROUNDS, f"default {DEFAULT_ROUNDS}")
        entrances = config.get("entrances", ENTRANCE_RULES[0])
        if entrances not in ENTRANCE_RULES:
            raise WorldagentError(f"entrances={entrances!r}; pick one of {', '.join(ENTRANCE_RULES)}.")
        shifts = {name: shift_setting(config.get(name), name) for name in ("apple_shift", "wall_shift", "entrance_shift")}
        return cls(apples, rounds, entrances, grid, **shifts)

    @property
    def config(self) -> dict:
        """The settings that rebuild this repair (``from_dataset(dataset, config)``)."""
        shift = {"apple_shift": self.apple_shift} if self.apples == SPREAD else {}
        walls = {name: value for name, value in (("wall_shift", self.wall_shift), ("entrance_shift", self.entrance_shift)) if value is not None}
        return {"apples": self.apples, **shift, **walls, "rounds": self.rounds, "entrances": self.entrances}

    def fitted(self, logits: jax.Array, worlds: HarvestMap) -> OpenRooms:
        """This repair calibrated on decoded logits f32[B, 2·S·S] of the prior, so that its decodes have the
        dataset ``worlds``' rooms per map (``wall_shift``), the generator's share of entrances
        (``entrance_shift``) and, for "spread" apples, the dataset's apples per map (``apple_shift``), in that
        order: each draw of the generator at its rate. Shifts already set are kept; itself if none is missing."""
        if None not in (self.wall_shift, self.entrance_shift) and (self.apples != SPREAD or self.apple_shift is not None):
            return self
        grids = logits.reshape(-1, 2, *self.grid)
        wall_shift = self.wall_shift
        if wall_shift is None:
            target = mean_rooms(layout_logits(worlds.walls[:FIT_MAPS]), self.rounds, self.entrances)
            wall_shift = fit_wall_shift(grids[:, 0], target, self.rounds, self.entrances)
        entrance_shift = self.entrance_shift
        if entrance_shift is None:
            entrance_shift = fit_entrance_shift(grids[:, 0], wall_shift, self.rounds, self.entrances)
        repair = self.replace(wall_shift=wall_shift, entrance_shift=entrance_shift)
        if self.apples != SPREAD or self.apple_shift is not None:
            return repair
        layout = functools.partial(open_layout, rounds=self.rounds, rule=self.entrances, wall_shift=wall_shift, entrance_shift=entrance_shift)
        rooms = jax.jit(jax.vmap(lambda one: layout(one)[1]))(grids)
        return repair.replace(apple_shift=fit_shift(rooms, jnp.clip(grids[:, 1], -LOGIT_CLIP, LOGIT_CLIP), mean_apples(worlds)))

    def __call__(self, logits: jax.Array) -> HarvestMap:
        """Valid maps from decoded logits f32[B, 2·S·S] (walls, then apples): ``HarvestMap`` of bool[B, S, S]."""
        grids = logits.reshape(-1, 2, *self.grid)
        wall_shift, entrance_shift = self.wall_shift or 0.0, self.entrance_shift or 0.0
        return jax.vmap(lambda one: open_map(one, self.apples, self.rounds, self.entrances, self.apple_shift, wall_shift, entrance_shift))(grids)
