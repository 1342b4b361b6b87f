"""Particle Racing's registration: what the upper layers need to know about it (``registry.EnvSpec``)."""

from __future__ import annotations

import functools

import numpy as np

from worldagent.envs.racing.open_repair import OpenTracks
from worldagent.envs.racing.render import LEGEND
from worldagent.envs.registry import EnvOption, EnvSpec, Metrics, Pictures, ScriptedPolicy, register
from worldagent.envs.repairs import NearestWorld

CORNER_SPAN = 8  # centreline segments over which a corner's turning is summed (256 per lap)
PAPER_WINDOW = 16  # the "surroundings" observation's full-resolution window (the paper's 16×16)
# Racing's departures from the algorithms' defaults, whatever the observation (docs/racing.md):
# rewards scaled for learning only (returns span −360..100; 0.01 brings value targets near unit
# scale) and respawn-on-crash while training (without it early crashes end episodes after ~15
# steps, the 10,000-episode budget buys ~150,000 steps and the agent learnt to park).
RACING_SETTINGS = {"reward_scale": 0.01, "respawn": True}
TRAINING_SETTINGS = {
    "ppo": RACING_SETTINGS,
    # Changed from ikostrikov's ACKTR (16 envs, 5 steps, entropy 0.01, kl_clip 0.001) to learn within the paper's budget
    # on 2 CPU cores: with kl_clip 0.001 the step was clipped on most updates and staying on the road took ~4,000 of the
    # 10,000 episodes; with the 0.01 reward scale an entropy weight of 0.01 outweighed the rewards (ACKTRConfig).
    "acktr": {**RACING_SETTINGS, "num_envs": 32, "num_steps": 16, "ent_coef": 0.001, "kl_clip": 0.01},
}
# Without the route sensor, agents learnt to lap only with these (docs/racing.md): a respawned
# agent restarts moving (at rest it learnt to park), and the networks' settings below.
ROUTELESS_RESPAWN_SPEED = 0.5
ROUTELESS_SETTINGS = {
    "ppo": {"crash_warmup": 0.5, "quadratic": True},
    # K-FAC's η_max: 0.25 learnt too slowly. kl_clip: a trust region of 0.003 (ikostrikov's 0.001, our earlier 0.01)
    # lapped ≥ 0.945 on 5 of 5 seeds; at 0.01 every η_max, schedule and heading tried left a seed parked or slow.
    "acktr": {"crash_warmup": 0.5, "quadratic": True, "learning_rate": 1.0, "kl_clip": 0.003},
}


def make(options):
    """``ParticleRacing`` with the chosen observation, and its default params."""
    from worldagent.envs.racing.env import ParticleRacing

    if options["observation"] == "surroundings":
        env = ParticleRacing(observation="surroundings", window=PAPER_WINDOW, reach=options["reach"])
    elif options["observation"] == "rays":
        env = ParticleRacing(observation="rays", reach=options["reach"], heading=options["heading"])
    else:
        env = ParticleRacing()
    speed = options["respawn_speed"]
    if speed is None:  # the observation's own default
        speed = 0.0 if options["observation"] == "route" else ROUTELESS_RESPAWN_SPEED
    return env, env.default_params.replace(respawn_speed=speed)


def option_overrides(algo: str, options) -> dict:
    """The training settings the observation needs (``EnvSpec.option_overrides``)."""
    return {} if options["observation"] == "route" else dict(ROUTELESS_SETTINGS.get(algo, {}))


def training_params(params, config, fraction):
    """The params an agent trains under (``EnvSpec.training_params``): respawn-on-crash as
    ``config.respawn``, and the crash penalty ramped from 0 over the first ``config.crash_warmup``
    of the budget, so a learner first finds that driving pays before crashes teach it to stop.
    Evaluation keeps the paper's rules (a crash ends the episode, the full penalty)."""
    import jax.numpy as jnp

    params = params.replace(respawn=config.respawn)
    if not config.crash_warmup:
        return params
    return params.replace(crash_penalty=params.crash_penalty * jnp.clip(fraction / config.crash_warmup, 0.0, 1.0))


def parse_observation(text: str) -> str:
    from worldagent.envs.racing.env import OBSERVATIONS

    if text not in OBSERVATIONS:
        raise ValueError(f"unknown observation {text!r}; use {' or '.join(OBSERVATIONS)}")
    return text


def parse_heading(text: str) -> str:
    from worldagent.envs.racing.env import HEADINGS

    if text not in HEADINGS:
        raise ValueError(f"unknown heading {text!r}; use {' or '.join(HEADINGS)}")
    return text


def parse_fraction(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{value} is not a fraction in [0, 1]")
    return value


def parse_reach(text: str) -> int:
    value = int(text)
    if value < 16 or value % 16:
        raise ValueError(f"reach={value}; use a multiple of 16 pixels, e.g. 64")
    return value


def generate(seeds):
    """CarRacing's procedural generator (``tracks.generate_tracks``)."""
    from worldagent.envs.racing.tracks import generate_tracks

    return generate_tracks(seeds)


def cells(tracks) -> np.ndarray:
    """uint8[N, 64·64]: each track's 64×64 footprint raster (paper §5.2.1)."""
    raster = np.asarray(tracks.raster)
    return raster.reshape(len(raster), -1).astype(np.uint8)


MEANINGS = {  # each metric in a line (the explorer's tooltips and legends)
    "return": "episode reward: +lap reward for a whole lap, -crash penalty for leaving the road, -step penalty every step (higher is better)",
    "normalised_return": "the return scaled to [0, 1] between the worst and best the rules allow (paper §6; 1 is best)",
    "crashed": "1 if the particle left the road this episode, else 0 (as a mean over episodes: the crash rate)",
    "lap_completed": "1 if the episode ended with a whole lap on the road, else 0 (as a mean: the lap rate)",
    "progress": "net laps driven along the centreline (negative when driving backwards)",
    "steps": "steps the episode lasted (a crash or a lap ends it, else the step limit)",
}


def derive(metrics: dict, params) -> dict:
    """Add the normalised return (paper §6)."""
    from worldagent.envs.racing.metrics import normalised_return

    return {**metrics, "normalised_return": np.asarray(normalised_return(metrics["return"], params))}


def bounds(params) -> tuple[float, float]:
    from worldagent.envs.racing.metrics import racing_return_bounds

    return racing_return_bounds(params)


def _turning(centreline: np.ndarray) -> np.ndarray:
    """f64[K]: the signed turn (radians) at each point of a closed centreline."""
    heading = np.diff(centreline, axis=0, append=centreline[:1])
    angle = np.arctan2(heading[:, 1], heading[:, 0])
    return (np.diff(angle, append=angle[:1]) + np.pi) % (2 * np.pi) - np.pi


def total_curvature(track) -> float:
    """Σ |turn| over the lap, radians (2π for a convex track; more for wiggles)."""
    return float(np.abs(_turning(np.asarray(track.centreline, np.float64))).sum())


def sharpest_corner(track) -> float:
    """The largest |turn| over ``CORNER_SPAN`` consecutive segments, radians."""
    turn = _turning(np.asarray(track.centreline, np.float64))
    window = np.convolve(np.concatenate([turn, turn[: CORNER_SPAN - 1]]), np.ones(CORNER_SPAN), mode="valid")
    return float(np.abs(window).max())


def track_length(track) -> float:
    """Lap length in normalised units (the playfield is 2 wide)."""
    centreline = np.asarray(track.centreline, np.float64)
    return float(np.linalg.norm(np.diff(centreline, axis=0, append=centreline[:1]), axis=1).sum())


@functools.lru_cache(maxsize=1)
def _draw_reader():
    """(the open repair, its jitted ``draws``), built once."""
    import jax

    return OpenTracks.from_dataset(None), jax.jit(lambda repair, logits: repair.draws(logits))


def checkpoint_draws(tracks) -> dict[str, np.ndarray]:
    """CarRacing's 20 checkpoint draws read back off tracks' footprints (``EnvSpec.generator_params``).

    ``angle_k``: checkpoint k's angle within its 30-degree sector, ``radius_k``: its radius, k = 1..10,
    each on the unit scale of upstream's uniform ranges (std 0.289 when drawn). Read as the open repair
    reads a decode (``OpenTracks.draws``: the footprint's radial profile through its fitted inverse), on the
    footprint rasters as certain logits: cheap (batched, jitted), not exact (on CarRacing's own tracks the
    read draws correlate 0.69-0.99 with the drawn ones, with their spread), and the same reading on both
    sides, so G(z) against fresh tracks compares like with like.
    """
    repair, read = _draw_reader()
    raster = np.asarray(tracks.raster, bool).reshape(len(tracks.raster), -1)
    logits = np.where(raster, 30.0, -30.0).astype(np.float32)  # sigmoid(±30) is 0 or 1 in float32
    unit = np.concatenate([np.asarray(read(repair, logits[i : i + 1000])) for i in range(0, len(logits), 1000)])
    free = unit.shape[1] // 2
    names = [f"angle_{k}" for k in range(1, free + 1)] + [f"radius_{k}" for k in range(1, free + 1)]
    return {name: unit[:, i].astype(np.float64) for i, name in enumerate(names)}


def trace(state):
    """(position f32[2], present) of the particle."""
    import jax.numpy as jnp

    return state.position, jnp.bool_(True)


def world_picture(world, size: int):
    from worldagent.envs.racing.render import track_image

    return track_image(world, size=size)


# A crash ends an evaluation episode: the explorer marks where, as the strategic figure does.
OUTCOMES = {"crashed": {"shape": "cross", "colour": "#ff1a1a", "radius": 0.022, "label": "crash: the episode ended off the road"}}


def locate(positions, world, size: int):
    """Pixel (x, y) of normalised positions on ``world_picture`` (it always shows the same square)."""
    from worldagent.envs.racing.render import _xy_to_canvas

    return _xy_to_canvas(np.asarray(positions, np.float64), size)


def draw_episodes(axis, world, episodes) -> None:
    from worldagent.envs.racing.render import draw_episodes as draw

    draw(axis, world, episodes)


def sheet(worlds, path):
    from worldagent.envs.racing.render import draw_track_sheet

    return draw_track_sheet(worlds, path)


def driver(env, params) -> ScriptedPolicy:
    """The reference driver: follows the centreline from the env state (privileged)."""
    from worldagent.envs.racing.driver import DriverParams, driver_action

    return ScriptedPolicy((params, DriverParams()), lambda p, obs, key, state: driver_action(state, *p), privileged=True)


def uniform(env, params) -> ScriptedPolicy:
    """Uniformly random actions."""
    import jax

    return ScriptedPolicy(None, lambda p, obs, key, state: jax.random.randint(key, (), 0, env.num_actions))


def episode_note(metrics: dict) -> str:
    """ ", 6/8 episodes crashed"."""
    crashed = np.asarray(metrics.get("crashed", []), bool)
    return f", {int(crashed.sum())}/{len(crashed)} episodes crashed" if len(crashed) else ""


def training_check(means) -> str:
    """Why a trained racing agent failed to learn ("" if it laps): one that laps in under half its
    episodes mostly parks or crashes (a failed training run, not a property of the worlds)."""
    laps = means.get("lap_completed")
    return f"laps in only {laps:.0%} of its episodes (it parks or crashes)" if laps is not None and laps < 0.5 else ""


def _budgets(**values):
    return values


SPEC = register(
    EnvSpec(
        name="racing",
        description="Particle Racing (paper §5.1.1): one particle laps a CarRacing track; leaving the road is a crash.",
        make=make,
        options=(
            EnvOption(
                "observation",
                "route: position, velocity, 8 centreline points ahead; rays (no route, the paper's): road rays, heading, position, velocity; surroundings: road window + coarse view, position, velocity",
                parse_observation,
                "route",
            ),
            EnvOption(
                "respawn_speed",
                "training respawns: speed along the road afterwards, fraction of the top speed (default: 0 for route, 0.5 without it)",
                parse_fraction,
                None,
            ),
            EnvOption("reach", "surroundings: side of the coarse road view around the agent, pixels of 1/64 unit (multiple of 16)", parse_reach, 64),
            EnvOption(
                "heading", "rays: motion (the unit velocity) or kept (the last motion's direction, kept at rest; on trial)", parse_heading, "motion"
            ),
        ),
        world_type=__import__("worldagent.envs.racing.world", fromlist=["Track"]).Track,
        generate=generate,
        cells=cells,
        cell_shape=(64, 64),
        repair=NearestWorld.from_dataset,
        repairs={"nearest": NearestWorld.from_dataset, "open": OpenTracks.from_dataset},
        metrics=Metrics(
            main="return",
            names=("return", "normalised_return", "crashed", "lap_completed", "progress", "steps"),
            aliases={"crash_rate": "crashed", "lap_rate": "lap_completed"},
            derive=derive,
            bounds=bounds,
            compared=("return", "normalised_return", "crashed", "lap_completed"),
            highlighted=("crashed",),
            descriptors={"total_curvature": total_curvature, "sharpest_corner": sharpest_corner, "track_length": track_length},
            default_descriptors=("total_curvature", "sharpest_corner"),
            meanings=MEANINGS,
        ),
        trace=trace,
        pictures=Pictures(
            world=world_picture, episodes=draw_episodes, sheet=sheet, locate=locate, legend=LEGEND, agents=("the particle",), outcomes=OUTCOMES
        ),
        scripted={"driver": driver, "random": uniform},
        algorithms=("ppo", "acktr"),
        algorithm_overrides=TRAINING_SETTINGS,
        option_overrides=option_overrides,
        training_params=training_params,
        presets={
            "paper": _budgets(
                worlds=10_000,
                vae_epochs=25,
                episodes=10_000,
                random_worlds=1_000,
                strategic_budget=2_100,
                compare_budget=1_050,
                bo_budget=210,
                compare_seeds=(0, 1, 2),
                influence_candidates=1_000,
                influence_episodes=10_000,
                influence_eval_worlds=1_000,
                influence_seeds=(0, 1, 2, 3, 4),
                influence_search_budget=2_100,
                influence_search="atlas",
                atlas_budget=2_100,
                failure_worlds=10_000,
                influence_selection="crash_rate > 0",
                options={"observation": "rays"},  # the paper's agent: its surroundings, position and directional speed
                algo="acktr",
            ),
            "quick": _budgets(  # sized to 10 minutes on 2 cores with harvest's (docs/main-job.md)
                worlds=10_000,
                vae_epochs=4,
                episodes=6_000,
                random_worlds=1_000,
                strategic_budget=420,
                compare_budget=105,
                bo_budget=21,
                compare_seeds=(0, 1),
                influence_candidates=300,  # 200 selected 33 worlds, too few to train on: the agent parked
                influence_episodes=3_000,
                influence_eval_worlds=150,
                influence_seeds=(0,),
                atlas_budget=105,  # at least the atlas's 100 cells
                failure_worlds=500,
                influence_selection="crash_rate > 0",
            ),
            "tiny": _budgets(
                worlds=128,
                vae_epochs=3,
                episodes=64,
                random_worlds=42,
                strategic_budget=21,
                compare_budget=21,
                bo_budget=6,
                compare_seeds=(0,),
                influence_candidates=42,
                influence_episodes=64,
                influence_eval_worlds=10,
                influence_seeds=(0,),
                atlas_budget=105,
                failure_worlds=64,
                train_envs=8,
            ),
        },
        selection="crash_rate > 0.5",
        failure="crash_rate > 0.5",  # the paper's crash-prone worlds (§6.2.1)
        paper={
            "random.mean_normalised": 0.87,
            "random.crashed": 0.11,
            "min.normalised": 0.13,
            "max.normalised": 0.99,
            "max.crashed": 0.0,
            "influence.crashed.default": 0.11,
            "influence.crashed.influenced": 0.04,
            "influence.reward_change_pct": -5.0,
        },
        episode_note=episode_note,
        generator_params=checkpoint_draws,
        training_check=training_check,
    )
)
