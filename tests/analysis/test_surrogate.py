"""The surrogate's pool descriptors: G(z) described once per distinct world, kept beside the store and read back."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from worldagent.analysis import surrogate
from worldagent.envs import registry
from worldagent.errors import WorldagentError


def test_the_describer_matches_the_specs_descriptors_on_each_world(racing_generator):
    spec = registry.get("racing")
    z = np.random.default_rng(0).standard_normal((23, racing_generator.latent_dim))
    z[5] = z[4]  # one world twice: described once, the same row
    described = surrogate.distinct_describer(spec, racing_generator, chunk=10)(z)
    worlds = jax.tree_util.tree_map(np.asarray, racing_generator(z.astype(np.float32)))
    names = list(spec.metrics.descriptors)
    for i in (0, 9, 10, 22):  # either side of a chunk's edge, and the padded last chunk
        world = jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], worlds)
        np.testing.assert_allclose(described[i], [spec.metrics.descriptors[name](world) for name in names], rtol=1e-6)
    np.testing.assert_array_equal(described[4], described[5])
    only = surrogate.distinct_describer(spec, racing_generator, names=["track_length"])(z[:3])
    np.testing.assert_allclose(only[:, 0], described[:3, names.index("track_length")])
    with pytest.raises(WorldagentError, match="unknown racing descriptor"):
        surrogate.distinct_describer(spec, racing_generator, names=["speed"])


def test_cached_descriptors_are_read_back_extended_and_a_missing_file_is_refused(tmp_path):
    calls = []

    def describe(z):
        calls.append(len(z))
        return z[:, :1] * 2

    path = surrogate.pool_cache(tmp_path / "store.sqlite", "f00d", 3)
    z = np.arange(24.0).reshape(12, 2)
    first = surrogate.cached_describer(path, describe)(z[:6])
    longer = surrogate.cached_describer(path, describe)(z)  # only the 6 new rows are described
    again = surrogate.cached_describer(path, None)(z)  # a replay with no generator reads the file
    np.testing.assert_array_equal(longer[:6], first)
    np.testing.assert_array_equal(again[:, 0], z[:, 0] * 2)
    assert calls == [6, 6]
    kept = surrogate.cached_describer(path, None)
    assert kept.held() == 12 and kept.seconds_per_world() > 0  # what a later run's plan counts as described, and at what cost
    with pytest.raises(WorldagentError, match="missing or stale; rerun `worldagent failure-rate`"):
        surrogate.cached_describer(tmp_path / "pools" / "other.npz", None)(z)
