"""Shared racing fixtures: generated CarRacing tracks, built once per test session."""

from __future__ import annotations

import numpy as np
import pytest

from worldagent.envs.racing.tracks import generate_track, generate_tracks


@pytest.fixture(scope="session")
def tracks():
    """A ``Track`` batch (numpy arrays) of the 8 CarRacing tracks of seeds 0..7."""
    return generate_tracks(np.arange(8))


@pytest.fixture(scope="session")
def track():
    """The CarRacing track of seed 0, unbatched."""
    return generate_track(0)
