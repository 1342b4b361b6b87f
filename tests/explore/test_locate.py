"""``Pictures.locate`` puts the positions ``EnvSpec.trace`` records where the world's picture draws them."""

from __future__ import annotations

import jax
import numpy as np

from worldagent.envs import registry

SIZE = 192


def start_pixels(name: str):
    """(picture as an RGB array, pixel (x, y) of each agent at the start of an episode) of generated world 0."""
    spec = registry.get(name)
    env, params = spec.make_env(spec.reproduce_options)
    world = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[0], spec.generate(np.array([0], np.int64)))
    _, state = jax.jit(env.reset)(jax.random.key(0), world, params)  # compiled: faster than op by op
    positions, _ = spec.trace(state)
    pixels = np.asarray(spec.pictures.locate(np.asarray(positions), world, SIZE)).reshape(-1, 2)
    return np.asarray(spec.pictures.world(world, SIZE).convert("RGB")), pixels


def colour_at(picture: np.ndarray, xy) -> tuple:
    x, y = (int(v) for v in np.clip(np.floor(xy), 0, SIZE - 1))
    return tuple(int(c) for c in picture[y, x])


def test_the_racing_particle_starts_on_the_road():
    picture, (start,) = start_pixels("racing")
    red, green, blue = colour_at(picture, start)
    assert max(red, green, blue) - min(red, green, blue) <= 12  # grey: the road at its start line, not green grass


def test_the_harvest_agents_start_on_their_drawn_squares():
    from worldagent.envs.harvest.render import AGENT, OBSERVER

    picture, starts = start_pixels("harvest")
    assert len(starts) == 4 and ((starts >= 0) & (starts <= SIZE)).all()
    assert [colour_at(picture, xy) for xy in starts] == [tuple(OBSERVER), *[tuple(AGENT)] * 3]
