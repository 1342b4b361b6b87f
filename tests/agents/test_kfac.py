"""K-FAC against hand computations (numpy) on one Dense layer, and against an exact natural gradient."""

from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.agents.kfac import KFAC, KFACConfig
from worldagent.errors import WorldagentError

IN, OUT, N = 3, 4, 7


def softmax(x):
    e = np.exp(x - x.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


def combined(layer):
    """[kernel; bias] as float64 numpy."""
    return np.concatenate([np.asarray(layer["kernel"], np.float64), np.asarray(layer["bias"], np.float64)[None]], 0)


def with_ones(x):
    return np.concatenate([np.asarray(x, np.float64), np.ones((len(x), 1))], 1)


def softmax_problem(seed):
    """A linear-softmax net (one Dense layer), a batch, labels, and its loss / sampled-Fisher functions."""
    rng = np.random.default_rng(seed)
    model = nn.Dense(OUT)
    x = jnp.asarray(rng.normal(size=(N, IN)), jnp.float32)
    labels = jnp.asarray(rng.integers(0, OUT, N))
    variables = model.init(jax.random.key(seed), x)

    def loss_fn(logits):
        return -jnp.mean(jax.nn.log_softmax(logits)[jnp.arange(N), labels]), None

    def fisher_fn(logits, key):
        sampled = jax.random.categorical(key, jax.lax.stop_gradient(logits))
        return jnp.sum(jax.nn.log_softmax(logits)[jnp.arange(N), sampled])

    return model, variables, x, labels, loss_fn, fisher_fn


def hand_factors(variables, x, key):
    """numpy: ā, E[ā āᵀ], E[g gᵀ] with g = onehot(ỹ) - p for the actions ỹ that fisher_fn samples."""
    w = combined(variables["params"])
    a = with_ones(x)
    logits = a @ w
    sampled = np.asarray(jax.random.categorical(key, jnp.asarray(logits, jnp.float32)))
    g = np.eye(OUT)[sampled] - softmax(logits)
    return a, a.T @ a / N, g.T @ g / N, softmax(logits)


@pytest.mark.parametrize("damping_mode", ["exact", "factored"])
def test_factors_and_step_match_hand_computation(damping_mode):
    config = KFACConfig(learning_rate=0.5, kl_clip=1e-4, momentum=0.9, stat_decay=0.8, damping=0.03, damping_mode=damping_mode)
    model, variables, x, labels, loss_fn, fisher_fn = softmax_problem(0)
    kfac = KFAC(config, model.apply)
    state = kfac.init(variables, x)
    key = jax.random.key(1)
    gradients = jax.jit(lambda k, v: kfac.gradients(k, v, (x,), loss_fn, fisher_fn))
    update = jax.jit(kfac.update)
    loss, _, grads, stats = gradients(key, variables)

    a, A, G, p = hand_factors(variables, x, key)
    grad = a.T @ (p - np.eye(OUT)[np.asarray(labels)]) / N  # cross-entropy gradient wrt [kernel; bias]
    np.testing.assert_allclose(combined(grads), grad, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(stats[""][0], A, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(stats[""][1], G, rtol=1e-5, atol=1e-7)

    params, state, info = update(grads, stats, state, variables["params"])
    np.testing.assert_allclose(state.factors[""].a, A, rtol=1e-5, atol=1e-6)  # first update sets the factors
    np.testing.assert_allclose(state.factors[""].g, G, rtol=1e-5, atol=1e-7)

    lam = config.damping
    if damping_mode == "exact":
        damped = np.kron(A, G) + lam * np.eye(A.shape[0] * OUT)
    else:
        pi = np.sqrt((np.trace(A) / len(A)) / (np.trace(G) / OUT))
        damped = np.kron(A + pi * np.sqrt(lam) * np.eye(len(A)), G + np.sqrt(lam) / pi * np.eye(OUT))
    delta = np.linalg.solve(damped, grad.reshape(-1))  # row-major vec of the [in+1, out] matrix
    quadratic = delta @ np.kron(A, G) @ delta
    eta = min(config.learning_rate, np.sqrt(2 * config.kl_clip / quadratic))
    assert eta < config.learning_rate  # the trust region is active in this test
    expected = combined(variables["params"]) - (1 - config.momentum) * eta * delta.reshape(IN + 1, OUT)
    np.testing.assert_allclose(float(info["fisher_quadratic"]), quadratic, rtol=1e-4)
    np.testing.assert_allclose(float(info["step_size"]), eta, rtol=1e-4)
    np.testing.assert_allclose(combined(params), expected, rtol=1e-4, atol=1e-6)

    # second update: factors are running averages; the eigendecompositions are kept (T_inv = 10)
    key2 = jax.random.key(2)
    _, _, grads2, stats2 = gradients(key2, {"params": params})
    params2, state2, info2 = update(grads2, stats2, state, params)
    _, A2, G2, _ = hand_factors({"params": params}, x, key2)
    d = config.stat_decay
    np.testing.assert_allclose(state2.factors[""].a, d * A + (1 - d) * A2, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(state2.factors[""].g, d * G + (1 - d) * G2, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(state2.factors[""].a_vecs, state.factors[""].a_vecs)
    # momentum: velocity = m * v1 + eta2 * delta2, applied with rate (1 - m)
    delta2 = np.linalg.solve(damped, combined(grads2).reshape(-1)).reshape(IN + 1, OUT)  # same (stale) inverse
    v1 = eta * delta.reshape(IN + 1, OUT)
    v2 = config.momentum * v1 + float(info2["step_size"]) * delta2
    np.testing.assert_allclose(combined(params2), combined(params) - (1 - config.momentum) * v2, rtol=1e-4, atol=1e-6)
    assert int(state2.count) == 2


def test_step_size_is_max_learning_rate_when_the_trust_region_is_loose():
    config = KFACConfig(learning_rate=0.1, kl_clip=1e3, momentum=0.0)
    model, variables, x, _, loss_fn, fisher_fn = softmax_problem(3)
    kfac = KFAC(config, model.apply)

    @jax.jit
    def step(key, variables, state):
        _, _, grads, stats = kfac.gradients(key, variables, (x,), loss_fn, fisher_fn)
        return kfac.update(grads, stats, state, variables["params"])

    params, _, info = step(jax.random.key(0), variables, kfac.init(variables, x))
    assert float(info["step_size"]) == pytest.approx(0.1)
    assert float(info["clipped"]) == 0.0


def test_direction_is_the_exact_natural_gradient_of_a_linear_gaussian_model():
    """y ~ N(W̃ᵀā, I): the Fisher is exactly E[ā āᵀ] ⊗ I, so the natural gradient is A⁻¹ ∇W̃.

    The sampled Fisher's noise is a fixed set {±√out e_k} crossed with every input, so its
    empirical Fisher is exactly A ⊗ I too; F is also built explicitly from per-sample gradients.
    """
    rng = np.random.default_rng(5)
    n_x, out = 9, 2
    x_unique = rng.normal(size=(n_x, IN))
    noise_set = np.sqrt(out) * np.concatenate([np.eye(out), -np.eye(out)])  # E[εεᵀ] = I
    x = jnp.asarray(np.repeat(x_unique, len(noise_set), 0), jnp.float32)
    noise = jnp.asarray(np.tile(noise_set, (n_x, 1)), jnp.float32)
    targets = jnp.asarray(rng.normal(size=(len(x), out)), jnp.float32)
    model = nn.Dense(out)
    variables = model.init(jax.random.key(0), x)

    loss_fn = lambda mu: (0.5 * jnp.mean(jnp.sum((mu - targets) ** 2, -1)), None)  # noqa: E731
    fisher_fn = lambda mu, key: jnp.sum(-0.5 * jnp.sum((mu - jax.lax.stop_gradient(mu + noise)) ** 2, -1))  # noqa: E731
    kfac = KFAC(KFACConfig(damping=1e-7, damping_mode="exact"), model.apply)

    @jax.jit
    def direction_of(key, variables, state):
        _, _, grads, stats = kfac.gradients(key, variables, (x,), loss_fn, fisher_fn)
        _, state, _ = kfac.update(grads, stats, state, variables["params"])
        return grads, kfac.precondition(grads, state)

    grads, direction = direction_of(jax.random.key(1), variables, kfac.init(variables, x))
    direction = combined(direction)

    # the exact Fisher, built explicitly from per-sample score vectors (no K-FAC machinery)
    def score(params, xi, ei):
        mu = model.apply({"params": params}, xi)
        g = jax.grad(lambda p: -0.5 * jnp.sum((model.apply({"params": p}, xi) - jax.lax.stop_gradient(mu + ei)) ** 2))(params)
        return jnp.concatenate([g["kernel"].reshape(-1), g["bias"]])

    scores = np.asarray(jax.vmap(score, (None, 0, 0))(variables["params"], x, noise), np.float64)
    fisher = scores.T @ scores / len(x)
    a = with_ones(x)
    A = a.T @ a / len(x)
    np.testing.assert_allclose(fisher, np.kron(A, np.eye(out)), atol=1e-5)  # the problem is as designed
    grad = combined(grads).reshape(-1)
    natural = np.linalg.solve(fisher, grad).reshape(IN + 1, out)
    np.testing.assert_allclose(direction, natural, rtol=1e-3, atol=1e-5)
    np.testing.assert_allclose(direction, np.linalg.solve(A, combined(grads)), rtol=1e-3, atol=1e-5)


class TwoHeads(nn.Module):
    @nn.compact
    def __call__(self, x):
        h = nn.tanh(nn.Dense(5, name="torso")(x))
        return nn.Dense(3, name="policy")(h), nn.Dense(1, use_bias=False, name="value")(h)[..., 0]


def test_gradients_of_a_multi_layer_net_equal_jax_grad_and_update_jits_under_vmap():
    model = TwoHeads()
    x = jax.random.normal(jax.random.key(0), (2, 6, IN))  # any leading batch axes
    variables = model.init(jax.random.key(1), x)

    def loss_fn(outputs):
        logits, value = outputs
        return jnp.mean(jax.nn.logsumexp(logits, -1) - logits[..., 0]) + jnp.mean(value**2), None

    def fisher_fn(outputs, key):
        logits, value = outputs
        key_a, key_v = jax.random.split(key)
        sampled = jax.random.categorical(key_a, jax.lax.stop_gradient(logits))
        log_p = jnp.take_along_axis(jax.nn.log_softmax(logits), sampled[..., None], -1)
        target = jax.lax.stop_gradient(value + jax.random.normal(key_v, value.shape))
        return jnp.sum(log_p) - 0.5 * jnp.sum((value - target) ** 2)

    kfac = KFAC(KFACConfig(), model.apply)
    state = kfac.init(variables, x)
    assert sorted(state.factors) == ["policy", "torso", "value"]
    assert state.factors["value"].a.shape == (5, 5)  # no bias column

    def one_seed(key):
        _, _, grads, stats = kfac.gradients(key, variables, (x,), loss_fn, fisher_fn)
        expected = jax.grad(lambda p: loss_fn(model.apply({"params": p}, x))[0])(variables["params"])
        _, _, info = kfac.update(grads, stats, state, variables["params"])
        return grads, expected, info["step_size"]

    grads, expected, steps = jax.jit(jax.vmap(one_seed))(jax.random.split(jax.random.key(3), 3))
    jax.tree_util.tree_map(lambda u, v: np.testing.assert_allclose(u, v, rtol=1e-5, atol=1e-7), grads, expected)
    assert steps.shape == (3,) and np.all(np.isfinite(steps)) and np.all(steps > 0)


def test_bad_configs_and_models_name_the_fix():
    with pytest.raises(WorldagentError, match="damping_mode"):
        KFACConfig(damping_mode="diagonal")
    with pytest.raises(WorldagentError, match="kl_clip"):
        KFACConfig(kl_clip=0.0)

    class Twice(nn.Module):
        @nn.compact
        def __call__(self, x):
            layer = nn.Dense(IN)
            return layer(layer(x))

    x = jnp.ones((2, IN))
    twice = Twice()
    with pytest.raises(WorldagentError, match="more than once"):
        KFAC(KFACConfig(), twice.apply).init(twice.init(jax.random.key(0), x), x)
    no_dense = nn.LayerNorm()
    with pytest.raises(WorldagentError, match="no flax nn.Dense"):
        KFAC(KFACConfig(), no_dense.apply).init(no_dense.init(jax.random.key(0), x), x)
