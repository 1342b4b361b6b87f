"""Resource Harvest's registration: what the upper layers need to know about it (``registry.EnvSpec``)."""

from __future__ import annotations

import numpy as np

from worldagent.envs.harvest.env import BEAM_LENGTH, NUM_AGENTS, VIEW_BEHIND, VIEW_SIZE
from worldagent.envs.harvest.open_repair import OpenRooms
from worldagent.envs.harvest.render import AGENT_CSS, LEGEND
from worldagent.envs.harvest.repair import HarvestRepair, threshold_maps
from worldagent.envs.harvest.world import DEFAULT_SIZE, HarvestMap, spawn_corners
from worldagent.envs.registry import EnvOption, EnvSpec, Metrics, Pictures, ScriptedPolicy, register
from worldagent.errors import WorldagentError


def parse_tagger(text: str) -> tuple[int, ...]:
    """``"0"`` or ``"0,2"`` -> the agents allowed to TAG; ``"none"`` or ``""`` -> nobody."""
    text = text.strip().lower()
    if text in ("", "none"):
        return ()
    try:
        return tuple(int(part) for part in text.split(","))
    except ValueError:
        raise ValueError(f"{text!r} is not a list of agent indices") from None


def taggers(value) -> tuple[int, ...]:
    """The tagger option as a tuple of agent indices (None, an int or a sequence), checked."""
    chosen = () if value is None else (value,) if isinstance(value, (int, np.integer)) else tuple(value)
    if any(isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < NUM_AGENTS for i in chosen):
        raise WorldagentError(f"tagger {value!r}: agents are numbered 0 to {NUM_AGENTS - 1}.")
    return tuple(int(i) for i in chosen)


def positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise ValueError(f"{value} is not a positive integer")
    return value


def non_negative_int(text: str) -> int:
    value = int(text)
    if value < 0:
        raise ValueError(f"{value} is negative")
    return value


def non_negative_float(text: str) -> float:
    value = float(text)
    if not value >= 0:
        raise ValueError(f"{value} is not a non-negative number")
    return value


MEANINGS = {  # each metric in a line (the explorer's tooltips and legends; envs/harvest/metrics.py has the formulas)
    "group_reward": "apples collected by all agents together in the episode, one reward each (the paper's main harvest metric; higher is better)",
    "conflict": "share of steps in which at least one agent was tagged out, 0 to 1 (lower is more peaceful)",
    "equality": "1 - Gini of the agents' returns: 1 when all collected alike, 1/N when one took everything",
    "sustainability": "mean step at which apples were collected (later means the orchard was not stripped early)",
    "peace": "agents on the map per step, 0 to N (N: nobody was ever tagged out)",
}


def make(options):
    """``Harvest`` and params from the options: who may TAG (paper §6.2.2), the window, the beam, regrowth."""
    from worldagent.envs.harvest.env import Harvest, make_params, perolat_regrowth_table

    chosen = taggers(options.get("tagger"))
    env = Harvest(view_size=options["view_size"], view_behind=options["view_behind"], beam_length=options["beam_length"])
    regrowth = np.minimum(1.0, options["regrowth"] * perolat_regrowth_table())
    return env, make_params(can_tag=[i in chosen for i in range(NUM_AGENTS)], regrowth_probability=regrowth)


def generate(seeds):
    """The paper's corner-region map generator (``maps.generate_maps``)."""
    from worldagent.envs.harvest.maps import generate_maps

    return generate_maps(seeds)


def cells(maps) -> np.ndarray:
    """uint8[N, 2·H·W]: each map's wall grid and apple grid."""
    grids = np.stack([np.asarray(maps.walls), np.asarray(maps.apples)], axis=1)
    return grids.reshape(len(grids), -1).astype(np.uint8)


def wall_share(world) -> float:
    """Fraction of the cells that are walls."""
    return float(np.asarray(world.walls, bool).mean())


def cut_off_from_tagger(world) -> np.ndarray:
    """bool[3]: whether walls cut agent 0's corner off from each other agent's (4-connected moves)."""
    from scipy.ndimage import label

    walls = np.asarray(world.walls, bool)
    regions, _ = label(~walls)
    corners = np.array([regions[r, c] for r, c in spawn_corners(*walls.shape)])
    return corners[1:] != corners[0]


def closed_room(world) -> float:
    """1.0 when walls split the free cells into more than one area (4-connected moves): a room without an entrance."""
    from scipy.ndimage import label

    return float(label(~np.asarray(world.walls, bool))[1] > 1)


def tagger_isolated(world) -> float:
    """1.0 when walls cut agent 0's corner off from every other corner (paper Figure 8b), else 0.0."""
    return float(cut_off_from_tagger(world).all())


def tagger_separated(world) -> float:
    """1.0 when walls cut agent 0's corner off from at least one other corner, else 0.0."""
    return float(cut_off_from_tagger(world).any())


def apple_clustering(world) -> float:
    """Mean number of apples among each apple's 8 neighbours (regrowth depends on it)."""
    apples = np.asarray(world.apples, bool)
    if not apples.any():
        return 0.0
    padded = np.pad(apples, 1).astype(np.int32)
    neighbours = sum(np.roll(np.roll(padded, dr, 0), dc, 1) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc)[1:-1, 1:-1]
    return float(neighbours[apples].mean())


def apple_distance(world) -> float:
    """Mean over the four spawns of the walk to the nearest apple (4-moves around walls), cells.

    Near apples are taken early: of these descriptors it predicts sustainability best (corr 0.68
    on the failure-rate benchmark's 100,000 maps, docs/failure-rate.md). A spawn that reaches no
    apple counts H + W, longer than any walk to one.
    """
    walls, apples = np.asarray(world.walls, bool), np.asarray(world.apples, bool)
    height, width = walls.shape
    rows, cols = spawn_corners(height, width).T
    distance = np.full(walls.shape, height + width)
    reached, step = apples & ~walls, 0
    while True:  # breadth-first from every apple at once, until every spawn is reached or nothing grows
        distance[reached & (distance > step)] = step
        if reached[rows, cols].all():
            break
        padded = np.pad(reached, 1)
        grown = (padded[:-2, 1:-1] | padded[2:, 1:-1] | padded[1:-1, :-2] | padded[1:-1, 2:] | reached) & ~walls
        if (grown == reached).all():
            break
        reached, step = grown, step + 1
    return float(distance[rows, cols].mean())


def largest_patch(world) -> float:
    """Apples in the largest patch (8-connected): an eaten patch regrows only from apples near it."""
    from scipy.ndimage import label

    patches, count = label(np.asarray(world.apples, bool), structure=np.ones((3, 3)))
    return float(np.bincount(patches.ravel())[1:].max()) if count else 0.0


def trace(state):
    """(positions i32[4, 2], present bool[4]): agents are off the map while tagged out."""
    return state.position, state.tagged_timer == 0


def marks(env, state):
    """What the explorer's animation draws besides the agents, as (row, col) cells with which are there now:
    ``apple`` every cell (shown: an apple on it), ``beam`` every agent's beam cells (shown: lit by a
    beam fired this step), ``tagged`` each agent's cell (shown: it is tagged out; where it was hit)."""
    import jax.numpy as jnp

    from worldagent.envs.harvest.env import beam_reach

    apples = state.apples
    height, width = apples.shape
    rows, cols = jnp.meshgrid(jnp.arange(height, dtype=jnp.int32), jnp.arange(width, dtype=jnp.int32), indexing="ij")
    cells, lit = beam_reach(state.position, state.heading, state.fired, state.world.walls, env.beam_length)
    return {
        "apple": (jnp.stack([rows.ravel(), cols.ravel()], axis=-1), apples.ravel()),
        "beam": (cells.reshape(-1, 2).astype(jnp.int32), lit.ravel()),
        "tagged": (state.position, state.tagged_timer > 0),
    }


CELL = 1 / DEFAULT_SIZE  # one cell, as a fraction of the picture's side
MARK_STYLES = {
    "apple": {"shape": "dot", "colour": "#5dff7a", "radius": 0.22 * CELL, "label": "apple (eaten ones vanish, regrown ones return)"},
    "beam": {"shape": "square", "colour": "#ffe14d", "radius": 0.45 * CELL, "label": "TAG beam, at the step it is fired"},
    "tagged": {"shape": "ring", "colour": "#b4b4b4", "radius": 0.38 * CELL, "label": "where a tagged-out agent was hit (until it respawns)"},
}
AGENT_NAMES = ("agent 0 (top left; the tagger when one is set)", "agent 1 (top right)", "agent 2 (bottom left)", "agent 3 (bottom right)")


def world_picture(world, size: int):
    from PIL import Image

    from worldagent.envs.harvest.render import draw_map

    image = draw_map(world, cell=max(1, size // np.shape(world.walls)[-1]), agents=True, reach=True)
    return image.resize((size, size), Image.NEAREST)


def locate(positions, world, size: int):
    """Pixel (x, y) of the centres of (row, col) cells on ``world_picture``."""
    height, width = np.shape(world.walls)[-2:]
    cells = np.asarray(positions, np.float64)
    return np.stack([(cells[..., 1] + 0.5) * size / width, (cells[..., 0] + 0.5) * size / height], axis=-1)


def draw_episodes(axis, world, episodes) -> None:
    from worldagent.envs.harvest.render import draw_episodes as draw

    draw(axis, world, episodes)


def sheet(worlds, path):
    from worldagent.envs.harvest.render import draw_map_sheet

    return draw_map_sheet(worlds, path)


def uniform(env, params) -> ScriptedPolicy:
    """Uniformly random actions for the four agents."""
    from worldagent.envs.harvest.policies import random_act

    return ScriptedPolicy(None, lambda p, obs, key, state: random_act(p, obs, key))


def greedy(env, params) -> ScriptedPolicy:
    """Each agent walks to the nearest apple it sees."""
    from worldagent.envs.harvest.policies import greedy_policy

    act = greedy_policy(env)
    return ScriptedPolicy(None, lambda p, obs, key, state: act(p, obs, key))


def _budgets(**values):
    return values


SPEC = register(
    EnvSpec(
        name="harvest",
        description="Resource Harvest (paper §5.1.2): four agents gather regrowing apples; one may TAG the others out.",
        make=make,
        options=(
            EnvOption("tagger", "agents allowed to TAG, e.g. 0 or 0,2 (the paper's influencing experiment: 0)", parse_tagger, ()),
            EnvOption("view_size", "side of each agent's square window, cells (odd)", positive_int, VIEW_SIZE),
            EnvOption("view_behind", "rows of the window behind the agent; the rest are ahead", non_negative_int, VIEW_BEHIND),
            EnvOption("beam_length", "reach of the TAG beam, cells", positive_int, BEAM_LENGTH),
            EnvOption("regrowth", "multiplier on Perolat's regrowth probabilities (below 1: scarcer apples)", non_negative_float, 1.0),
        ),
        world_type=HarvestMap,
        generate=generate,
        cells=cells,
        cell_shape=(2, DEFAULT_SIZE, DEFAULT_SIZE),
        repair=HarvestRepair.from_dataset,
        repairs={"nearest": HarvestRepair.from_dataset, "open": OpenRooms.from_dataset},
        metrics=Metrics(
            main="group_reward",
            names=("group_reward", "conflict", "equality", "sustainability", "peace"),
            compared=("group_reward", "conflict", "equality"),
            highlighted=("conflict", "equality"),
            descriptors={
                "wall_share": wall_share,
                "tagger_separated": tagger_separated,
                "tagger_isolated": tagger_isolated,
                "closed_room": closed_room,
                "apple_clustering": apple_clustering,
                "apple_distance": apple_distance,
                "largest_patch": largest_patch,
            },
            default_descriptors=("wall_share", "apple_clustering"),
            meanings=MEANINGS,
        ),
        trace=trace,
        pictures=Pictures(
            world=world_picture,
            episodes=draw_episodes,
            sheet=sheet,
            locate=locate,
            marks=marks,
            mark_styles=MARK_STYLES,
            legend=LEGEND,
            agents=AGENT_NAMES,
            agent_colours=AGENT_CSS,
        ),
        scripted={"random": uniform, "greedy": greedy},
        algorithms=("dqn",),
        # BO's reported worlds were lower on fresh episodes than CMA-ES's in 5 of 5 seeds at equal episode
        # budgets (confirmed group reward 17.2 against 33.8; benchmarks/results/noisy-search.json)
        optimiser="bo",
        presets={
            "paper": _budgets(
                worlds=10_000,
                vae_epochs=100,  # walls come out sharp enough to snap to closed rooms (docs/harvest.md)
                episodes=5_000,
                random_worlds=1_000,
                strategic_budget=1_050,
                compare_budget=525,
                bo_budget=105,
                compare_seeds=(0, 1, 2),
                influence_candidates=1_000,
                influence_episodes=5_000,
                influence_eval_worlds=1_000,
                influence_seeds=(0, 1, 2),
                atlas_budget=1_050,
                failure_worlds=2_000,
                influence_search_budget=525,
                optimiser="cmaes",  # the paper's, not the env's BO
            ),
            "quick": _budgets(  # sized to 10 minutes on 2 cores with racing's (docs/main-job.md)
                worlds=5_000,
                vae_epochs=20,  # held-out loss is lowest at epoch 20: the VAE early stopping kept of 100 epochs
                episodes=600,
                random_worlds=100,
                strategic_budget=42,  # BO's; it beat CMA-ES at 63 in 4 of 5 seeds (noisy-search-harvest-quick.json) at CMA-ES's cost
                compare_budget=21,  # one CMA-ES generation: ES, BO and random search at equal budgets
                bo_budget=21,
                compare_seeds=(0,),
                influence_candidates=100,
                influence_episodes=500,
                influence_eval_worlds=50,
                influence_seeds=(0,),
                atlas_budget=105,  # at least the atlas's 100 cells
                failure_worlds=50,
                influence_search_budget=42,
                learning_starts=4_000,
                # half the minibatch: 2/3 of the training's cost, agents about as good at 600 episodes
                # (benchmarks/results/harvest-dqn-budget.json); epsilon decays over each agent's whole budget
                settings={"dqn": {"batch_size": 64, "epsilon_decay_episodes": None, "epsilon_decay_fraction": 1.0}},
            ),
            "tiny": _budgets(
                worlds=256,
                vae_epochs=3,
                episodes=4,
                random_worlds=8,
                strategic_budget=21,
                compare_budget=0,
                compare_seeds=(0,),
                influence_candidates=8,
                influence_search_budget=42,  # 8 random maps held no conflict == 0 map for the 4-episode agents
                influence_episodes=4,
                influence_eval_worlds=4,
                influence_seeds=(0,),
                atlas_budget=105,
                failure_worlds=16,
                train_envs=4,
                learning_starts=1_000,
            ),
        },
        reproduce_options={"tagger": (0,)},
        raw_decode=lambda logits: threshold_maps(np.asarray(logits).reshape(len(logits), 2, DEFAULT_SIZE, DEFAULT_SIZE)),
        selection="conflict == 0",
        failure="group_reward < 50",  # ours: under a third of trained agents' mean group reward on random worlds (130-200)
        paper={
            "random.mean_normalised": 0.61,
            "min.normalised": 0.05,
            "max.normalised": 0.92,
            "influence.conflict.default": 0.51,
            "influence.conflict.influenced": 0.05,
            "influence.equality.default": 0.33,
            "influence.equality.influenced": 0.78,
        },
    )
)
