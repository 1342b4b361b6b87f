"""worldagent: optimise worlds to evaluate and influence reinforcement-learning agents."""

__version__ = "0.1.0"


def _register_gymnasium_envs() -> None:
    """Make ``gymnasium.make("worldagent/ParticleRacing-v0")`` work after ``import worldagent``."""
    from gymnasium.envs.registration import register, registry

    if "worldagent/ParticleRacing-v0" not in registry:
        register(id="worldagent/ParticleRacing-v0", entry_point="worldagent.envs.adapters:ParticleRacingGym")


_register_gymnasium_envs()
