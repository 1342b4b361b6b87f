"""Batched rollouts -> per-episode metrics (DESIGN.md "Evaluator"; paper §4.4: 8 episodes per world)."""
