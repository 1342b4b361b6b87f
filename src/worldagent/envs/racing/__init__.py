"""Particle Racing (paper §5.1.1): CarRacing-generated tracks and a pure-JAX particle racer."""
