"""Environments: worlds as pytrees, pure-JAX dynamics, Gymnasium / PettingZoo adapters."""
