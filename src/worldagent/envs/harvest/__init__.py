"""Resource Harvest (paper §5.1.2): corner-region map generator, 4-agent pure-JAX env, metrics,
reference policies, pictures and a PettingZoo adapter (``pettingzoo_env``, imported on demand)."""

from worldagent.envs.harvest.env import NUM_ACTIONS, Harvest, HarvestParams, HarvestState, make_params
from worldagent.envs.harvest.maps import MapConfig, generate_map, generate_maps, seeds_from
from worldagent.envs.harvest.metrics import episode_metrics
from worldagent.envs.harvest.world import HarvestMap

__all__ = [
    "NUM_ACTIONS",
    "Harvest",
    "HarvestMap",
    "HarvestParams",
    "HarvestState",
    "MapConfig",
    "episode_metrics",
    "generate_map",
    "generate_maps",
    "make_params",
    "seeds_from",
]
