"""Shared, session-scoped fixtures for the Resource Harvest tests: compile once, reuse."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.envs.harvest.env import Harvest, make_params
from worldagent.envs.harvest.maps import generate_maps, seeds_from
from worldagent.envs.harvest.world import HarvestMap


@pytest.fixture(scope="session")
def env() -> Harvest:
    return Harvest()


@pytest.fixture(scope="session")
def reset_fn(env):
    return jax.jit(env.reset)


@pytest.fixture(scope="session")
def step_fn(env):
    return jax.jit(env.step)


@pytest.fixture(scope="session")
def quiet_params():
    """No regrowth, so apple counts only change by harvesting."""
    return make_params(regrowth_probability=np.zeros(13))


@pytest.fixture(scope="session")
def tag_params():
    """Agent 0 may tag (the paper's influencing experiment); no regrowth."""
    return make_params(can_tag=[True, False, False, False], regrowth_probability=np.zeros(13))


@pytest.fixture(scope="session")
def generated_maps():
    """64 generated maps (DEFAULT_SIZE square), seeds 0..63."""
    return generate_maps(seeds_from(0, 64))


@pytest.fixture(scope="session")
def place(reset_fn):
    """``place(world, params, position=..., heading=..., apples=...)``: a state with agents put by hand."""

    def place(world: HarvestMap, params, position=None, heading=None, apples=None):
        _, state = reset_fn(jax.random.key(0), world, params)
        changes = {}
        if position is not None:
            changes["position"] = jnp.asarray(position, jnp.int32)
        if heading is not None:
            changes["heading"] = jnp.asarray(heading, jnp.int32)
        if apples is not None:
            changes["apples"] = jnp.asarray(apples, bool)
        return state.replace(**changes)

    return place


@pytest.fixture(scope="session")
def open_map() -> HarvestMap:
    """An empty 9x9 map."""
    return HarvestMap.from_str("\n".join(["." * 9] * 9))
