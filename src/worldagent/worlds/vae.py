"""The VAE over worlds (paper §3.1, §5.2.1, Figure 3): binary cells -> 10-d latent -> cells.

Encoder: two fully connected hidden layers of 1024 and 512 units (ReLU) to a diagonal Gaussian
``q(z|x)``; decoder: the transpose, 512 then 1024 units, to one Bernoulli logit per cell. The
loss is the negative ELBO per world, ``E_q[-log p(x|z)] + β·KL(q(z|x) || N(0, I))`` (β = 1 is the
plain VAE of Kingma & Welling, the paper's [20]), with the KL of each latent dimension floored at
``free_bits`` nats (Kingma et al. 2016) so that sparse, structureless datasets do not collapse the
posterior onto the prior. Training is Adam (optax), one jitted
``lax.scan`` over the minibatches of an epoch, a held-out split, and a checkpoint after every
epoch so a killed run resumes. The weights kept are those of the epoch with the lowest held-out
objective once the KL weight has reached β (``kept_epoch``), and training stops ``patience`` epochs
after it: with a dataset of a few thousand worlds the decoder goes on to memorise its training
worlds (harvest, 5,000 maps: held-out loss lowest at epoch 20, 146.5 nats, then rising to 233.5
at epoch 100 while the training NLL fell from 112.6 to 33.0).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import serialization

from worldagent.errors import WorldagentError
from worldagent.files import write_bytes, write_text
from worldagent.progress import progress_bar

CHECKPOINT_VERSION = 1
STATE_FILE = "training.msgpack"  # where training stands, in one atomic file: a killed run resumes from it exactly
LATEST_FILE = "latest.msgpack"  # checkpoints before STATE_FILE: the last epoch's weights (and optimizer.msgpack), read to resume them
# Settings added after version 1, at the values that reproduce how older checkpoints were trained
# (a resumed old run keeps training the way it started).
LEGACY_CONFIG = {"free_bits": 0.0, "patience": 0}
STOPPING_RULES = ("epochs", "patience")  # settings that say when to stop, not how to train: a resumed run may change them


@dataclass(frozen=True)
class VAEConfig:
    """Architecture and training settings (defaults: the paper's architecture).

    Attributes:
        latent_dim: size of z (paper: 10).
        encoder: hidden layer widths of the encoder (paper: 1024, 512).
        decoder: hidden layer widths of the decoder (paper: the transpose, 512, 1024).
        beta: weight of the KL term (1: the standard ELBO).
        warmup_epochs: the KL weight ramps linearly from 0 to ``beta`` over these first epochs
            (KL annealing, Bowman et al. 2016): without it the thin roads of the racing rasters
            let the decoder settle on the mean image and ignore z (posterior collapse).
        free_bits: λ, nats: while training, each latent dimension's KL (averaged over the minibatch)
            counts as at least λ (Kingma et al. 2016, "free bits"), so the encoder may spend up to λ
            nats per dimension at no cost. Without it, on worlds that share little structure
            (13x13 mazes of 0-25 scattered walls, issue 39; tests/scatter_env.py) z collapses
            onto the prior: a stranger's VAE had 0.009 nats of KL; ours, on 10,000 such mazes
            (25 epochs), kept 1 active dimension of 10 (held-out NLL 48.4 nats, mean maze 50.2),
            and with λ = 0.5 uses all 10 (NLL 43.7). Racing and harvest use > 1.5 nats per
            dimension anyway: the floor never binds there after warm-up. Old checkpoints that lack the
            field load with 0 (their training). The reported KL and held-out loss are the true
            ones, without the floor.
        learning_rate: Adam step size.
        batch_size: worlds per minibatch.
        epochs: passes over the training split.
        holdout: fraction of the dataset held out for the quality figures and for choosing the
            epoch whose weights are kept (``kept_epoch``).
        patience: stop once this many epochs have passed after warm-up without a lower held-out
            objective (early stopping, ``kept_epoch``); 0: train every epoch (the best epoch's weights are kept either
            way). Old checkpoints load with 0.
        seed: seed of the initialisation, the split, the shuffling and the sampling.
    """

    latent_dim: int = 10
    encoder: tuple[int, ...] = (1024, 512)
    decoder: tuple[int, ...] = (512, 1024)
    beta: float = 1.0
    warmup_epochs: int = 5
    free_bits: float = 0.5
    learning_rate: float = 1e-3
    batch_size: int = 128
    epochs: int = 25
    holdout: float = 0.1
    patience: int = 10
    seed: int = 0

    def validate(self) -> None:
        """Raise ``WorldagentError`` for settings training cannot honour."""
        if self.latent_dim < 1 or not self.encoder or not self.decoder or min(self.encoder + self.decoder) < 1:
            raise WorldagentError("VAE layers and latent_dim must be positive; the paper uses encoder 1024-512, latent 10.")
        if self.warmup_epochs < 0:
            raise WorldagentError(f"warmup_epochs={self.warmup_epochs}; pass 0 or more.")
        if not 0.0 <= self.free_bits < float("inf"):
            raise WorldagentError(f"free_bits={self.free_bits}; pass a finite number of nats >= 0 (0: the plain ELBO).")
        if self.beta < 0 or self.learning_rate <= 0 or self.batch_size < 1 or self.epochs < 1:
            raise WorldagentError("beta must be >= 0 and learning_rate, batch_size and epochs positive.")
        if not 0.0 <= self.holdout < 1.0:
            raise WorldagentError(f"holdout={self.holdout}; pick a fraction in [0, 1).")
        if self.patience < 0:
            raise WorldagentError(f"patience={self.patience}; pass 0 (train every epoch) or more epochs.")


class VAE(nn.Module):
    """MLP VAE over ``cell_count`` binary cells."""

    cell_count: int
    latent_dim: int = 10
    encoder: tuple[int, ...] = (1024, 512)
    decoder: tuple[int, ...] = (512, 1024)

    def setup(self):
        self.encoder_layers = [nn.Dense(width) for width in self.encoder]
        self.to_mean = nn.Dense(self.latent_dim)
        self.to_log_var = nn.Dense(self.latent_dim)
        self.decoder_layers = [nn.Dense(width) for width in self.decoder]
        self.to_logits = nn.Dense(self.cell_count)

    def encode(self, cells: jax.Array) -> tuple[jax.Array, jax.Array]:
        """f[B, D] cells -> (mean f32[B, L], log-variance f32[B, L]) of q(z|x)."""
        h = cells.astype(jnp.float32)
        for layer in self.encoder_layers:
            h = nn.relu(layer(h))
        return self.to_mean(h), self.to_log_var(h)

    def hidden(self, z: jax.Array) -> jax.Array:
        """f[B, L] latents -> f32[B, H] the decoder's last hidden layer (its logits are linear in it)."""
        h = z
        for layer in self.decoder_layers:
            h = nn.relu(layer(h))
        return h

    def decode(self, z: jax.Array) -> jax.Array:
        """f[B, L] latents -> f32[B, D] Bernoulli logits of the cells."""
        return self.to_logits(self.hidden(z))

    def __call__(self, cells: jax.Array, key: jax.Array):
        mean, log_var = self.encode(cells)
        z = mean + jnp.exp(0.5 * log_var) * jax.random.normal(key, mean.shape)
        return self.decode(z), mean, log_var


def logits_layer(params) -> tuple[jax.Array, jax.Array]:
    """(kernel f32[H, D], bias f32[D]) of the decoder's last layer: logits = hidden(z) @ kernel + bias."""
    layer = params["to_logits"]
    return layer["kernel"], layer["bias"]


def make_vae(cell_count: int, config: VAEConfig) -> VAE:
    return VAE(cell_count, config.latent_dim, tuple(config.encoder), tuple(config.decoder))


def negative_elbo(logits: jax.Array, cells: jax.Array, mean: jax.Array, log_var: jax.Array, beta: float, free_bits: float = 0.0):
    """Per-world mean of ``-log p(x|z) + β·KL(q(z|x) || N(0, I))``; returns (loss, (nll, kl)).

    Args:
        logits: f32[B, D] decoded Bernoulli logits.
        cells: f[B, D] the worlds' cells.
        mean, log_var: f32[B, L] of q(z|x).
        beta: weight of the KL term.
        free_bits: λ: in the loss, each dimension's minibatch-mean KL counts as ``max(λ, KL_d)``
            (Kingma et al. 2016); 0: the plain ELBO. ``kl`` is the true KL whatever λ.
    """
    nll = optax.sigmoid_binary_cross_entropy(logits, cells.astype(jnp.float32)).sum(-1)
    kl_dims = 0.5 * (jnp.exp(log_var) + mean**2 - 1.0 - log_var).mean(0)  # f32[L], nats per world
    floored = jnp.maximum(kl_dims, free_bits).sum()
    return jnp.mean(nll) + beta * floored, (jnp.mean(nll), kl_dims.sum())


@dataclass
class TrainedVAE:
    """A trained VAE: its module, parameters, config and provenance.

    Attributes:
        model: the ``VAE`` module.
        params: its parameters.
        config: the training settings.
        env: the environment of the worlds it was trained on.
        cell_shape: shape of one world's cells.
        fingerprint: the training dataset's fingerprint.
        history: per-epoch {"epoch", "train_loss", "holdout_loss" (the negative ELBO),
            "holdout_objective" (the loss training minimises, free bits included), "nll", "kl"}.
        holdout_indices: dataset indices of the held-out worlds.
        kept_epoch: the epoch whose weights ``params`` are (``kept_epoch``); None: the last one
            (checkpoints written before the choice).
    """

    model: VAE
    params: Any
    config: VAEConfig
    env: str
    cell_shape: tuple[int, ...]
    fingerprint: str
    history: list[dict]
    holdout_indices: np.ndarray
    kept_epoch: int | None = None

    @property
    def kept(self) -> dict:
        """The history entry of the epoch whose weights these are (``{}`` without a history)."""
        if not self.history:
            return {}
        return self.history[(self.kept_epoch or len(self.history)) - 1]

    def encode(self, cells) -> tuple[jax.Array, jax.Array]:
        return self.model.apply({"params": self.params}, jnp.asarray(cells), method=VAE.encode)

    def decode(self, z) -> jax.Array:
        return self.model.apply({"params": self.params}, jnp.asarray(z), method=VAE.decode)

    def save(self, directory: Path | str) -> Path:
        """Write ``vae.msgpack`` and ``vae.json`` (config, env, fingerprint, history) atomically."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        meta = {
            "checkpoint_version": CHECKPOINT_VERSION,
            "env": self.env,
            "cell_shape": list(self.cell_shape),
            "fingerprint": self.fingerprint,
            "config": asdict(self.config),
            "history": self.history,
            "kept_epoch": self.kept_epoch or len(self.history),
            "holdout_indices": np.asarray(self.holdout_indices).tolist(),
        }
        write_bytes(directory / "vae.msgpack", serialization.to_bytes(self.params))
        write_text(directory / "vae.json", json.dumps(meta, indent=1))
        return directory

    @classmethod
    def load(cls, directory: Path | str, env: str | None = None) -> TrainedVAE:
        """Read a checkpoint written by ``save``; refuses other versions and architectures (``env``: named in the refusal)."""
        directory = Path(directory)
        remedy = f"train one with `worldagent generator train {env or 'ENV'} --out {directory}`"
        try:
            meta = json.loads((directory / "vae.json").read_text())
            blob = (directory / "vae.msgpack").read_bytes()
        except (OSError, ValueError) as error:
            raise WorldagentError(f"no readable VAE checkpoint in {directory} ({type(error).__name__}); {remedy}.") from None
        if meta.get("checkpoint_version") != CHECKPOINT_VERSION:
            raise WorldagentError(
                f"VAE checkpoint in {directory} has version {meta.get('checkpoint_version')}, expected {CHECKPOINT_VERSION}; {remedy}."
            )
        config = VAEConfig(
            **{**LEGACY_CONFIG, **meta["config"], "encoder": tuple(meta["config"]["encoder"]), "decoder": tuple(meta["config"]["decoder"])}
        )
        cell_shape = tuple(meta["cell_shape"])
        model = make_vae(int(np.prod(cell_shape)), config)
        # shapes only (eval_shape): initialising the weights just to overwrite them cost seconds
        template = jax.eval_shape(lambda: model.init(jax.random.key(0), jnp.zeros((1, int(np.prod(cell_shape)))), jax.random.key(0))["params"])
        try:
            params = jax.tree_util.tree_map(jnp.asarray, serialization.from_bytes(template, blob))
            shapes_match = jax.tree_util.tree_all(jax.tree_util.tree_map(lambda a, b: tuple(a.shape) == np.shape(b), template, params))
        except (ValueError, KeyError, TypeError) as error:
            raise WorldagentError(f"VAE weights in {directory} do not fit the architecture in vae.json ({type(error).__name__}); {remedy}.") from None
        if not shapes_match:
            raise WorldagentError(f"VAE weights in {directory} do not fit the architecture in vae.json; {remedy}.")
        held = np.asarray(meta["holdout_indices"], np.int64)
        return cls(model, params, config, meta["env"], cell_shape, meta["fingerprint"], meta["history"], held, meta.get("kept_epoch"))


def split_holdout(count: int, holdout: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train indices, held-out indices): a seeded permutation of ``range(count)``."""
    order = np.random.default_rng(seed).permutation(count)
    held = int(round(count * holdout))
    return np.sort(order[held:]), np.sort(order[:held])


def make_epoch(model: VAE, optimizer: optax.GradientTransformation, batch_size: int, free_bits: float = 0.0):
    """A jitted ``epoch(params, opt_state, cells, key, beta) -> (params, opt_state, mean metrics)``."""

    def loss_fn(params, batch, key, beta):
        logits, mean, log_var = model.apply({"params": params}, batch, key)
        return negative_elbo(logits, batch, mean, log_var, beta, free_bits)

    @jax.jit
    def epoch(params, opt_state, cells, key, beta):
        def minibatch(carry, batch_and_key):
            params, opt_state = carry
            batch, key = batch_and_key
            (loss, (nll, kl)), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, batch, key, beta)
            updates, opt_state = optimizer.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), jnp.stack([loss, nll, kl])

        key_order, key_noise = jax.random.split(key)
        steps = cells.shape[0] // batch_size
        order = jax.random.permutation(key_order, cells.shape[0])[: steps * batch_size]
        batches = cells[order].reshape(steps, batch_size, -1)
        (params, opt_state), metrics = jax.lax.scan(minibatch, (params, opt_state), (batches, jax.random.split(key_noise, steps)))
        return params, opt_state, metrics.mean(axis=0)

    return epoch


def make_evaluate(model: VAE, beta: float, free_bits: float = 0.0):
    """A jitted ``evaluate(params, cells, key) -> (negative ELBO, training objective)`` (one sample of z per world).

    The objective is the negative ELBO with each dimension's KL floored at ``free_bits``, what
    training minimises; it is the negative ELBO when ``free_bits`` is 0.
    """

    @jax.jit
    def evaluate(params, cells, key):
        logits, mean, log_var = model.apply({"params": params}, cells, key)
        objective, (nll, kl) = negative_elbo(logits, cells, mean, log_var, beta, free_bits)
        return nll + beta * kl, objective

    return evaluate


def kept_epoch(history: list[dict], warmup_epochs: int) -> int:
    """The epoch (1-based) whose weights training keeps: the lowest finite held-out objective after warm-up.

    The objective is what training minimises (free bits included), measured on the held-out
    worlds. The plain held-out ELBO would not do: on worlds with little shared structure it stays
    flat while z comes into use (scattered-wall mazes, tests/scatter_env.py: 54.7 nats at epoch 5
    with a training KL of 1.2 nats, 53.8 at epoch 27 with 5.1), and an early epoch whose z is barely used
    would be kept. Epochs within warm-up trained with a KL weight below β, toward another
    objective, so they are not candidates; the earliest of equal values wins. When no epoch is a
    candidate (training ended within warm-up, or there is no held-out split) it is the last epoch
    (0: no epoch).

    Args:
        history: per-epoch rows with ``holdout_objective`` (``TrainedVAE.history``; rows written
            before it: ``holdout_loss``), in epoch order.
        warmup_epochs: the first epochs, whose KL weight ramps up to β.
    """
    losses = [row.get("holdout_objective", row["holdout_loss"]) for row in history]
    candidates = [i for i in range(warmup_epochs, len(losses)) if np.isfinite(losses[i])]
    if not candidates:
        return len(history)
    return min(candidates, key=lambda i: losses[i]) + 1


def stopped_early(history: list[dict], config: VAEConfig) -> bool:
    """Whether ``config.patience`` epochs after warm-up have passed without a lower held-out objective (``kept_epoch``)."""
    if config.patience == 0 or len(history) <= config.warmup_epochs:
        return False
    return len(history) - kept_epoch(history, config.warmup_epochs) >= config.patience


def train_vae(dataset, config: VAEConfig = VAEConfig(), progress: bool = True, checkpoint_dir: Path | str | None = None) -> TrainedVAE:
    """Train a VAE on ``dataset`` (a ``WorldDataset``), resuming from ``checkpoint_dir`` if it holds one.

    Trains until ``config.epochs`` or until ``stopped_early``, and returns the weights of the
    ``kept_epoch`` (the lowest held-out loss after warm-up). A checkpoint is written after every
    epoch when ``checkpoint_dir`` is given (``vae.msgpack``: the kept weights; ``latest.msgpack``
    and ``optimizer.msgpack``: where training stands); a resumed run continues from where it
    stood and refuses a checkpoint trained on other data or with other settings (``epochs`` and
    ``patience`` aside: they say when to stop).
    """
    config.validate()
    cells_all = np.asarray(dataset.cells, np.float32)
    train_idx, held_idx = split_holdout(len(cells_all), config.holdout, config.seed)
    if len(train_idx) < config.batch_size:
        raise WorldagentError(f"only {len(train_idx)} training worlds for batch_size={config.batch_size}; use more worlds or a smaller batch.")
    model = make_vae(cells_all.shape[1], config)
    optimizer = optax.adam(config.learning_rate)
    key_init, key = jax.random.split(jax.random.key(config.seed))
    params = model.init(key_init, jnp.zeros((1, cells_all.shape[1])), key_init)["params"]
    opt_state = optimizer.init(params)
    history: list[dict] = []
    kept_params, kept = params, 0

    resumed = _resume(checkpoint_dir, dataset, config, optimizer)
    if resumed is not None:
        params, opt_state, history, kept_params, kept = resumed

    epoch_fn = make_epoch(model, optimizer, config.batch_size, config.free_bits)
    evaluate = make_evaluate(model, config.beta, config.free_bits)
    train_cells, held_cells = jnp.asarray(cells_all[train_idx]), jnp.asarray(cells_all[held_idx])
    with progress_bar(f"training the {dataset.env} VAE", total=config.epochs, enabled=progress) as advance:
        advance(len(history))
        for epoch in range(len(history), config.epochs):
            if stopped_early(history, config):
                break
            key_epoch, key_eval = jax.random.split(jax.random.fold_in(key, epoch))
            beta = config.beta * min(1.0, (epoch + 1) / (config.warmup_epochs + 1))
            params, opt_state, (loss, nll, kl) = epoch_fn(params, opt_state, train_cells, key_epoch, beta)
            held, objective = (float(value) for value in evaluate(params, held_cells, key_eval)) if len(held_idx) else (float("nan"),) * 2
            history.append(
                {
                    "epoch": epoch + 1,
                    "train_loss": float(loss),
                    "holdout_loss": held,
                    "holdout_objective": objective,
                    "nll": float(nll),
                    "kl": float(kl),
                }
            )
            if kept_epoch(history, config.warmup_epochs) == len(history):
                kept_params, kept = params, len(history)
            trained = TrainedVAE(model, kept_params, config, dataset.env, tuple(dataset.cell_shape), dataset.fingerprint, history, held_idx, kept)
            if checkpoint_dir is not None:
                _checkpoint(checkpoint_dir, trained, params, opt_state)
            advance(1, loss=float(loss), holdout=held)
    final = TrainedVAE(model, kept_params, config, dataset.env, tuple(dataset.cell_shape), dataset.fingerprint, history, held_idx, kept or None)
    if checkpoint_dir is not None:  # a run killed between its last state and its vae.json resumes with no epoch left: write them here
        final.save(checkpoint_dir)
    return final


def _checkpoint(directory, trained: TrainedVAE, params, opt_state) -> None:
    """Where training stands (``STATE_FILE``: weights, optimizer, kept weights and history in one atomic write, so a kill
    between files cannot pair one epoch's weights with another's optimizer), then the kept VAE (``vae.msgpack``, ``vae.json``)."""
    state = {"params": params, "opt_state": opt_state, "kept_params": trained.params, "kept": trained.kept_epoch or 0}
    write_bytes(Path(directory) / STATE_FILE, serialization.to_bytes({**state, "history": json.dumps(trained.history)}))
    trained.save(directory)


def _resume(directory, dataset, config: VAEConfig, optimizer):
    """(params, opt_state, history, kept params, kept epoch) from an earlier run of the same training, else None.

    A checkpoint written before ``latest.msgpack`` kept its last epoch's weights: training goes on from them."""
    if directory is None or not (Path(directory) / "vae.json").exists():
        return None
    previous = TrainedVAE.load(directory)
    changed = [
        f"{name} {getattr(previous.config, name)!r}, not {getattr(config, name)!r}"
        for name in asdict(config)
        if name not in STOPPING_RULES and getattr(previous.config, name) != getattr(config, name)  # more epochs may be asked for
    ]
    if previous.fingerprint != dataset.fingerprint or changed:
        settings = f" ({'; '.join(changed)})" if changed else ""
        raise WorldagentError(
            f"{directory} holds a VAE trained on other data or settings{settings}; pass a new --out directory or the same dataset and options."
        )
    state_file = Path(directory) / STATE_FILE
    if state_file.exists():  # one file, written whole: the weights, optimizer, kept weights and history of one epoch
        template = {"params": previous.params, "opt_state": optimizer.init(previous.params), "kept_params": previous.params, "kept": 0, "history": ""}
        state = serialization.from_bytes(template, state_file.read_bytes())
        params, kept_params = (jax.tree_util.tree_map(jnp.asarray, state[name]) for name in ("params", "kept_params"))
        history = json.loads(state["history"])
        return params, state["opt_state"], history, kept_params, int(state["kept"]) or len(history)
    optimizer_file = Path(directory) / "optimizer.msgpack"
    if not optimizer_file.exists():  # only the trained VAE (vae.json, vae.msgpack), e.g. copied from elsewhere
        trained = len(previous.history)
        if trained < config.epochs and not stopped_early(previous.history, config):
            raise WorldagentError(
                f"{directory} holds a VAE trained {trained} of {config.epochs} epochs but not where its training stands "
                f"({STATE_FILE}); use it as it is with --epochs {trained}, or train again in a new --out directory."
            )
        return previous.params, optimizer.init(previous.params), previous.history, previous.params, previous.kept_epoch or trained
    opt_state = serialization.from_bytes(optimizer.init(previous.params), optimizer_file.read_bytes())
    latest = Path(directory) / LATEST_FILE
    params = serialization.from_bytes(previous.params, latest.read_bytes()) if latest.exists() else previous.params
    params = jax.tree_util.tree_map(jnp.asarray, params)
    return params, opt_state, previous.history, previous.params, previous.kept_epoch or len(previous.history)
