"""worldagent: optimise worlds to evaluate and influence reinforcement-learning agents."""

__version__ = "0.1.0"
