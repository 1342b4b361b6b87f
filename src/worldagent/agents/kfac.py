"""K-FAC: Kronecker-factored approximate curvature for flax linen ``nn.Dense`` layers.

Our own implementation (kfac-jax does not run on current JAX) of the optimiser inside ACKTR
(Wu et al. 2017, "Scalable trust-region method for deep reinforcement learning using
Kronecker-factored approximation", the paper's [21]; K-FAC itself is Martens & Grosse 2015).

For a Dense layer ``s = ā W̃`` with input ā (the activations with a trailing 1 for the bias)
and weight ``W̃ = [kernel; bias]`` of shape ``[in + 1, out]``, the Fisher block of ``vec(W̃)``
(row-major) is approximated by the Kronecker product ``A ⊗ G`` with ``A = E[ā āᵀ]`` and
``G = E[g gᵀ]``, where ``g = ∂ log p(ỹ|x) / ∂s`` is the gradient of the log-likelihood of a
target ``ỹ`` *sampled from the model itself* (the "sampled Fisher"). The natural-gradient step of
the layer is then ``Δ = A⁻¹ ∇W̃ G⁻¹``, computed from eigendecompositions of the factors.

How the pieces are captured: every ``nn.Dense.__call__`` of the model is intercepted
(``nn.intercept_methods``); its input is recorded and a zero "perturbation" is added to its
output, so the gradient with respect to the perturbations is the gradient with respect to the
pre-activations. One forward pass serves both the loss gradient and the sampled-Fisher
gradients (two VJPs). Each Dense module must be called once per forward pass.

Usage (explicit state, everything jittable)::

    kfac = KFAC(KFACConfig(), model.apply)
    state = kfac.init(variables, example_obs)
    loss, aux, grads, stats = kfac.gradients(key, variables, (obs,), loss_fn, fisher_fn)
    params, state, info = kfac.update(grads, stats, state, variables["params"])

Parameters outside Dense layers (if any) get the plain gradient (identity preconditioner) and
do not enter the trust-region estimate.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from worldagent.errors import WorldagentError

DAMPING_MODES = ("exact", "factored")


@dataclass(frozen=True)
class KFACConfig:
    """K-FAC hyper-parameters; defaults are ACKTR's (sources in brackets).

    Attributes:
        learning_rate: η_max, the largest step size [Wu et al. 2017 §4; baselines ``acktr`` lr=0.25;
            ikostrikov ``KFACOptimizer`` lr=0.25].
        kl_clip: δ, the trust-region radius: the step size is
            ``η = min(η_max, sqrt(2δ / (Δᵀ F̂ Δ)))`` (Wu et al. 2017 eq. 9) [baselines kfac_clip=0.001,
            ikostrikov kl_clip=0.001; both implementations write ``sqrt(δ / (Δᵀ∇))``, i.e. without the
            2 and with the damped Fisher; we follow the paper's formula and take ``Δᵀ F̂ Δ`` from the
            current (undamped) Kronecker factors].
        momentum: heavy-ball momentum; the step is applied as SGD with rate ``(1 - momentum)`` on the
            momentum buffer, as both implementations do [baselines, ikostrikov: 0.9].
        stat_decay: running-average decay of the factors, ``F ← d·F + (1 - d)·F_batch``; the first
            update sets them to the batch's [ikostrikov 0.99, which is also baselines' ACKTR setting;
            baselines' class default is 0.95].
        damping: Tikhonov damping λ [ikostrikov 1e-2, baselines epsilon=1e-2].
        damping_mode: ``"factored"``: ``(A + π√λ I)⁻¹ ⊗ (G + √λ/π I)⁻¹``, λ split between the factors
            (Martens & Grosse 2015 §6.3), through matrix inverses refreshed every ``inverse_every``
            updates; ``"exact"``: ``(A ⊗ G + λI)⁻¹`` through eigendecompositions, as ikostrikov.
            Factored is the default because ``eigh`` of a 261×261 factor costs ~50× an inverse on
            CPU (measured with jax 0.10), which dominated an ACKTR update.
        pi_correction: in factored mode, use π = sqrt((tr A / dim A) / (tr G / dim G)) (Martens &
            Grosse 2015 §6.3); otherwise π = 1.
        inverse_every: T_inv: the eigendecompositions are recomputed every this many updates (first
            at update 0) and kept in the state between [ikostrikov Tf=10]. Factors are updated every
            update (ikostrikov Ts=1). ACKTR's "cold iterations" (baselines cold_iter=10: SGD while the
            factors warm up) are not used, as in ikostrikov: the first update sets the factors.
        eigen_floor: eigenvalues of the factors below this are set to 0 (ikostrikov: 1e-6).
    """

    learning_rate: float = 0.25
    kl_clip: float = 0.001
    momentum: float = 0.9
    stat_decay: float = 0.99
    damping: float = 0.01
    damping_mode: str = "factored"
    pi_correction: bool = True
    inverse_every: int = 10
    eigen_floor: float = 1e-6

    def __post_init__(self):
        checks = [
            (self.learning_rate > 0, f"learning_rate={self.learning_rate} must be > 0"),
            (self.kl_clip > 0, f"kl_clip={self.kl_clip} must be > 0"),
            (0 <= self.momentum < 1, f"momentum={self.momentum} must be in [0, 1)"),
            (0 <= self.stat_decay < 1, f"stat_decay={self.stat_decay} must be in [0, 1)"),
            (self.damping > 0, f"damping={self.damping} must be > 0"),
            (self.damping_mode in DAMPING_MODES, f"damping_mode={self.damping_mode!r} must be one of {DAMPING_MODES}"),
            (self.inverse_every >= 1, f"inverse_every={self.inverse_every} must be >= 1"),
        ]
        for ok, message in checks:
            if not ok:
                raise WorldagentError(f"KFACConfig: {message}; fix that field.")


@struct.dataclass
class LayerFactors:
    """Running Kronecker factors of one Dense layer and their last eigendecompositions.

    Attributes:
        a: f32[in+1, in+1] running E[ā āᵀ] (ā = the layer input with a trailing 1 when it has a bias).
        g: f32[out, out] running E[g gᵀ] of sampled-Fisher pre-activation gradients.
        a_vals, a_vecs: exact mode: eigenvalues f32[in+1] and eigenvectors f32[in+1, in+1] of ``a``
            at the last inversion; factored mode: zeros and ``(a + π√λ I)⁻¹``.
        g_vals, g_vecs: the same for ``g`` (factored mode: ``(g + √λ/π I)⁻¹``).
        pi: f32 the π of factored damping at the last inversion (1 in exact mode).
    """

    a: jax.Array
    g: jax.Array
    a_vals: jax.Array
    a_vecs: jax.Array
    g_vals: jax.Array
    g_vecs: jax.Array
    pi: jax.Array


@struct.dataclass
class KFACState:
    """Explicit optimiser state.

    Attributes:
        factors: layer name ("/"-joined module path, "" when the model is one Dense) -> LayerFactors.
        velocity: momentum buffer, same pytree as the params.
        count: i32 number of updates done.
    """

    factors: dict
    velocity: Any
    count: jax.Array


@dataclass(frozen=True)
class _Layer:
    """Static description of one intercepted Dense layer."""

    path: tuple[str, ...]
    fan_in: int
    fan_out: int
    bias: bool
    output_shape: tuple[int, ...]


def _layer_name(path: tuple[str, ...]) -> str:
    """ "actor/Dense_0" for module path ("actor", "Dense_0"); "" for a Dense model itself."""
    return "/".join(path)


def _layer_path(name: str) -> tuple[str, ...]:
    return tuple(name.split("/")) if name else ()


def _is_dense_call(context) -> bool:
    return isinstance(context.module, nn.Dense) and context.method_name == "__call__"


def dense_layers(apply_fn: Callable, variables: Any, *args, **kwargs) -> dict[str, _Layer]:
    """The Dense layers that ``apply_fn(variables, *args, **kwargs)`` calls, by name (no compute).

    Raises:
        WorldagentError: no Dense layer was called, or one was called more than once.
    """
    layers: dict[str, _Layer] = {}

    def record(next_fun, call_args, call_kwargs, context):
        if _is_dense_call(context):
            module = context.module
            name = _layer_name(module.path)
            if name in layers:
                raise WorldagentError(f"K-FAC: Dense layer {name!r} is called more than once per forward pass; give each call its own layer.")
            out = next_fun(*call_args, **call_kwargs)
            layers[name] = _Layer(tuple(module.path), int(call_args[0].shape[-1]), int(module.features), bool(module.use_bias), tuple(out.shape))
            return out
        return next_fun(*call_args, **call_kwargs)

    def run(variables):
        with nn.intercept_methods(record):
            return apply_fn(variables, *args, **kwargs)

    jax.eval_shape(run, variables)
    if not layers:
        raise WorldagentError("K-FAC: the model calls no flax nn.Dense layer; K-FAC here preconditions Dense layers only.")
    return layers


def _tapped_apply(apply_fn, variables, perturbations, args, kwargs):
    """Apply with each Dense output shifted by its perturbation; returns (outputs, layer inputs)."""
    inputs: dict[str, jax.Array] = {}

    def tap(next_fun, call_args, call_kwargs, context):
        out = next_fun(*call_args, **call_kwargs)
        if _is_dense_call(context):
            name = _layer_name(context.module.path)
            inputs[name] = call_args[0]
            out = out + perturbations[name]
        return out

    with nn.intercept_methods(tap):
        outputs = apply_fn(variables, *args, **kwargs)
    return outputs, inputs


def _with_ones(x: jax.Array, bias: bool) -> jax.Array:
    x = x.reshape(-1, x.shape[-1])
    return jnp.concatenate([x, jnp.ones((x.shape[0], 1), x.dtype)], axis=1) if bias else x


def _get(tree: Any, path: tuple[str, ...]) -> Any:
    for name in path:
        tree = tree[name]
    return tree


def _set(tree: dict, path: tuple[str, ...], value: Any) -> dict:
    """A copy of nested dict ``tree`` with ``tree[path]`` replaced."""
    if not path:
        return value
    out = dict(tree)
    out[path[0]] = _set(tree[path[0]], path[1:], value)
    return out


def _combined(layer_params: dict, bias: bool) -> jax.Array:
    """[kernel; bias] as one f32[in(+1), out] matrix."""
    kernel = layer_params["kernel"]
    return jnp.concatenate([kernel, layer_params["bias"][None, :]], axis=0) if bias else kernel


def _split(matrix: jax.Array, bias: bool) -> dict:
    return {"kernel": matrix[:-1], "bias": matrix[-1]} if bias else {"kernel": matrix}


@dataclass(frozen=True)
class KFAC:
    """The K-FAC optimiser for one model; static (config and apply function), state is explicit.

    Attributes:
        config: the hyper-parameters.
        apply_fn: the model's ``apply(variables, *args, **kwargs) -> outputs`` (flax linen).
    """

    config: KFACConfig
    apply_fn: Callable

    def layers(self, variables: Any, *args, **kwargs) -> dict[str, _Layer]:
        """The model's Dense layers by name (see ``dense_layers``)."""
        return dense_layers(self.apply_fn, variables, *args, **kwargs)

    def init(self, variables: Any, *example_args, **example_kwargs) -> KFACState:
        """Zero factors (identity eigenvectors) for every Dense layer, zero momentum.

        Args:
            variables: the model's variables (``{"params": ...}``).
            example_args: inputs of the shape the model will be trained on (only shapes are used).
        """
        factors = {}
        for name, layer in self.layers(variables, *example_args, **example_kwargs).items():
            n_a = layer.fan_in + int(layer.bias)
            factors[name] = LayerFactors(
                a=jnp.zeros((n_a, n_a)), g=jnp.zeros((layer.fan_out, layer.fan_out)),
                a_vals=jnp.zeros(n_a), a_vecs=jnp.eye(n_a), g_vals=jnp.zeros(layer.fan_out),
                g_vecs=jnp.eye(layer.fan_out), pi=jnp.float32(1.0),
            )  # fmt: skip
        velocity = jax.tree_util.tree_map(jnp.zeros_like, variables["params"])
        return KFACState(factors=factors, velocity=velocity, count=jnp.int32(0))

    def gradients(self, key: jax.Array, variables: Any, args: tuple, loss_fn: Callable, fisher_fn: Callable, **kwargs):
        """Loss gradient and per-layer batch Kronecker factors from one forward pass.

        Args:
            key: PRNG key handed to ``fisher_fn`` for sampling targets from the model.
            variables: the model's variables (``{"params": ...}``).
            args: positional inputs of ``apply_fn`` (batched: leading dims are samples).
            loss_fn: ``loss_fn(outputs) -> (loss, aux)``, the scalar training loss.
            fisher_fn: ``fisher_fn(outputs, key) -> scalar``: the *sum over samples* of
                ``log p(ỹ | outputs)`` for targets ỹ sampled from the model's own predictive
                distribution with ``stop_gradient`` (so its pre-activation gradients are per-sample).

        Returns:
            (loss, aux, grads, stats): ``grads`` has the params' structure; ``stats`` maps each
            layer name to ``(A_batch f32[in+1, in+1], G_batch f32[out, out])`` = the batch means of
            ``ā āᵀ`` and ``g gᵀ``.
        """
        layers = self.layers(variables, *args, **kwargs)
        params = variables["params"]
        zeros = {name: jnp.zeros(layer.output_shape, jnp.float32) for name, layer in layers.items()}

        def forward(params, perturbations):
            return _tapped_apply(self.apply_fn, {**variables, "params": params}, perturbations, args, kwargs)

        outputs, pullback, inputs = jax.vjp(forward, params, zeros, has_aux=True)
        (loss, aux), loss_cotangent = jax.value_and_grad(loss_fn, has_aux=True)(outputs)
        grads, _ = pullback(loss_cotangent)
        _, fisher_grads = pullback(jax.grad(fisher_fn)(outputs, key))
        stats = {}
        for name, layer in layers.items():
            a = jax.lax.stop_gradient(_with_ones(inputs[name], layer.bias))
            g = fisher_grads[name].reshape(-1, layer.fan_out)
            n = a.shape[0]
            stats[name] = (a.T @ a / n, g.T @ g / n)
        return loss, aux, grads, stats

    def precondition(self, grads: Any, state: KFACState) -> Any:
        """Δ: each Dense layer's ``[kernel; bias]`` gradient times the damped inverse of ``A ⊗ G``.

        Uses the eigendecompositions in ``state`` (from the last inversion); other parameters
        pass through unchanged.
        """
        damping = self.config.damping
        out = grads
        for name, f in state.factors.items():
            path = _layer_path(name)
            layer_grads = _get(grads, path)
            bias = "bias" in layer_grads
            grad = _combined(layer_grads, bias)
            if self.config.damping_mode == "exact":
                rotated = f.a_vecs.T @ grad @ f.g_vecs
                direction = f.a_vecs @ (rotated / (f.a_vals[:, None] * f.g_vals[None, :] + damping)) @ f.g_vecs.T
            else:
                direction = f.a_vecs @ grad @ f.g_vecs  # the damped inverses
            out = _set(out, path, _split(direction, bias))
        return out

    def fisher_quadratic(self, direction: Any, state: KFACState) -> jax.Array:
        """Δᵀ F̂ Δ through the current factors: Σ_layers tr(Δᵀ A Δ G) (Dense layers only)."""
        total = jnp.float32(0.0)
        for name, f in state.factors.items():
            layer = _get(direction, _layer_path(name))
            delta = _combined(layer, "bias" in layer)
            total = total + jnp.sum((f.a @ delta) * (delta @ f.g))
        return total

    def _invert(self, factors: LayerFactors) -> LayerFactors:
        """Exact mode: eigendecompositions (small eigenvalues floored to 0); factored: damped inverses."""
        a, g = factors.a, factors.g
        if self.config.damping_mode == "exact":
            floor = self.config.eigen_floor
            a_vals, a_vecs = jnp.linalg.eigh(a)
            g_vals, g_vecs = jnp.linalg.eigh(g)
            a_vals = jnp.where(a_vals > floor, a_vals, 0.0)
            g_vals = jnp.where(g_vals > floor, g_vals, 0.0)
            return factors.replace(a_vals=a_vals, a_vecs=a_vecs, g_vals=g_vals, g_vecs=g_vecs, pi=jnp.float32(1.0))
        pi = jnp.float32(1.0)
        if self.config.pi_correction:
            ratio = (jnp.trace(a) / a.shape[0]) / jnp.maximum(jnp.trace(g) / g.shape[0], 1e-30)
            pi = jnp.sqrt(jnp.clip(ratio, 1e-30, 1e30))
        root = math.sqrt(self.config.damping)
        a_inv = jnp.linalg.inv(a + pi * root * jnp.eye(a.shape[0]))
        g_inv = jnp.linalg.inv(g + root / pi * jnp.eye(g.shape[0]))
        symmetric = lambda m: 0.5 * (m + m.T)  # noqa: E731
        return factors.replace(a_vecs=symmetric(a_inv), g_vecs=symmetric(g_inv), pi=pi)

    def update(self, grads: Any, stats: dict, state: KFACState, params: Any):
        """One K-FAC step: update factors, maybe re-invert, precondition, trust-region, momentum.

        Args:
            grads: the loss gradient (params' structure), from ``gradients``.
            stats: the batch factors from ``gradients``.
            state: the optimiser state.
            params: the current params.

        Returns:
            (new_params, new_state, info): ``info`` holds ``step_size`` (η), ``fisher_quadratic``
            (Δᵀ F̂ Δ) and ``clipped`` (1.0 when the trust region set η below η_max).
        """
        cfg = self.config
        first = state.count == 0
        factors = {}
        for name, f in state.factors.items():
            batch_a, batch_g = stats[name]
            mix = lambda old, new: jnp.where(first, new, cfg.stat_decay * old + (1.0 - cfg.stat_decay) * new)  # noqa: E731
            factors[name] = f.replace(a=mix(f.a, batch_a), g=mix(f.g, batch_g))
        refresh = state.count % cfg.inverse_every == 0
        factors = _run_by_run(lambda refresh, fs: jax.lax.cond(refresh, lambda fs: {k: self._invert(v) for k, v in fs.items()}, lambda fs: fs, fs))(
            refresh, factors
        )
        state = state.replace(factors=factors)

        direction = self.precondition(grads, state)
        quadratic = self.fisher_quadratic(direction, state)
        bound = jnp.sqrt(2.0 * cfg.kl_clip / jnp.maximum(quadratic, 1e-30))
        step_size = jnp.minimum(cfg.learning_rate, bound)
        velocity = jax.tree_util.tree_map(lambda v, d: cfg.momentum * v + step_size * d, state.velocity, direction)
        new_params = jax.tree_util.tree_map(lambda p, v: p - (1.0 - cfg.momentum) * v, params, velocity)
        info = {"step_size": step_size, "fisher_quadratic": quadratic, "clipped": (bound < cfg.learning_rate).astype(jnp.float32)}
        return new_params, state.replace(velocity=velocity, count=state.count + 1), info


def _run_by_run(fn):
    """``fn`` that ``jax.vmap`` maps run by run (``lax.map``) instead of batching: vmapped runs
    (``many.py``) then re-invert only every ``inverse_every`` updates (a batched ``lax.cond``
    would invert on every one) and call LAPACK one matrix at a time, as a run alone does
    (batched LAPACK calls deadlocked XLA's 2-thread CPU pool here, jaxlib 0.10.2)."""
    return jax.custom_batching.sequential_vmap(fn)
