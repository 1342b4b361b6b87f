"""worldagent: optimise worlds to evaluate and influence reinforcement-learning agents."""

# The one version source: pyproject.toml reads it ([tool.setuptools.dynamic]), `worldagent --version`
# prints it, stores and manifests record it; CHANGELOG.md says what each version changed.
__version__ = "0.1.0"


def _register_gymnasium_envs() -> None:
    """Make ``gymnasium.make("worldagent/ParticleRacing-v0")`` and ``gymnasium.make_vec`` of it work after ``import worldagent``.

    ``make`` gives ``envs.adapters.ParticleRacingGym``; ``make_vec(..., num_envs=N)`` gives
    ``envs.vector.ParticleRacingVectorEnv`` (N envs in one jitted step, SAME_STEP autoreset).
    """
    from gymnasium.envs.registration import register, registry

    if "worldagent/ParticleRacing-v0" not in registry:
        register(
            id="worldagent/ParticleRacing-v0",
            entry_point="worldagent.envs.adapters:ParticleRacingGym",
            vector_entry_point="worldagent.envs.vector:ParticleRacingVectorEnv",
        )


_register_gymnasium_envs()
