"""lavagrid: an 11×11 lava gridworld for worldagent, installed as its own package.

Registered only through the ``worldagent.envs`` entry point (``pyproject.toml``); nothing in
worldagent knows it. ``pip install -e examples/lavagrid`` and ``worldagent envs`` lists it.
"""
