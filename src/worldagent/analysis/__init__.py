"""Analysis of evaluated worlds: the probability of a failure under the world distribution.

``failure_rate``: Monte Carlo and importance-sampling estimates of P(event) for worlds G(z),
z ~ N(0, I), with 95% intervals and the episodes spent (``experiments.failure_rate`` wires them
to an agent and a generator).
"""
