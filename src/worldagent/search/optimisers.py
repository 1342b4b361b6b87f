"""Ask/tell optimisers over the latent space (paper §3.3, §4.4, §5.2.2).

Every optimiser has an explicit direction and a seed, and is deterministic given them: the same
sequence of ``ask``/``tell`` calls yields the same latents. A campaign relies on this to resume
by replaying its stored evaluations into a fresh optimiser (see ``campaign.py``)::

    opt = make_optimiser("cmaes", dim=10, maximize=False, seed=0)
    z = opt.ask(opt.batch_size)          # f64[n, dim]
    opt.tell(z, scores)                  # f64[n], finite

- ``cmaes``: CMA-ES with pycma (the reference implementation; the paper used Ha's
  ``estool`` wrapper of it with population 21). Initial mean 0, ``sigma0`` and optional box
  bounds as options. pycma minimises; maximising tells it the negated scores.
- ``bo``: Bayesian optimisation — a Gaussian process with expected improvement
  (``bayesian-optimization``; the paper used GPyOpt). ``initial_points`` random latents first,
  then EI; a batch of n is n suggestions made with the constant-liar strategy, so one round
  evaluates several worlds at once. It maximises; minimising tells it the negated scores. Its
  cost grows as O(evaluations³): budgets of a few hundred, as in the paper's comparison.
- ``random``: z ~ N(0, I), the baseline.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from worldagent.errors import WorldagentError

OPTIMISERS = ("cmaes", "bo", "random")


@dataclass(frozen=True)
class OptimiserConfig:
    """Settings of the optimisers (only those of the chosen one apply).

    Attributes:
        popsize: CMA-ES population per generation (paper: 21).
        sigma0: CMA-ES initial step size (the latent prior has unit scale).
        bound: box bound |z_i| <= bound for CMA-ES and BO (3: the prior's ±3σ); 0 = unbounded
            CMA-ES (BO always needs a box).
        bo_batch: BO suggestions per round.
        initial_points: BO random latents before the GP is used.
        xi: BO expected-improvement exploration margin.
        bo_starts: L-BFGS restarts when maximising EI (the library's default, 10, costs
            seconds per suggestion; 3 keeps a suggestion well under a second).
        bo_candidates: random candidates scored before those restarts.
        random_batch: random-search latents per round.
    """

    popsize: int = 21
    sigma0: float = 1.0
    bound: float = 3.0
    bo_batch: int = 4
    initial_points: int = 10
    xi: float = 0.01
    bo_starts: int = 3
    bo_candidates: int = 10_000
    random_batch: int = 21


class Optimiser:
    """Base class: direction, dimension, the finite-score check and the round size."""

    name = "optimiser"
    whole_generations = False  # asks only whole batches (a campaign's budget rounds up to them)

    def __init__(self, dim: int, maximize: bool, seed: int):
        if dim < 1:
            raise WorldagentError(f"latent dimension {dim}; it must be at least 1.")
        if seed < 0:
            raise WorldagentError(f"seed={seed}; pass a non-negative integer.")
        self.dim, self.maximize, self.seed = int(dim), bool(maximize), int(seed)

    @property
    def batch_size(self) -> int:
        """The natural number of latents per ``ask`` (a CMA-ES generation, a BO round)."""
        raise NotImplementedError

    def ask(self, n: int) -> np.ndarray:
        raise NotImplementedError

    def tell(self, z: np.ndarray, scores: np.ndarray) -> None:
        raise NotImplementedError

    def _checked(self, z, scores) -> tuple[np.ndarray, np.ndarray]:
        z, scores = np.asarray(z, np.float64), np.asarray(scores, np.float64)
        if z.ndim != 2 or z.shape[1] != self.dim or scores.shape != (len(z),):
            raise WorldagentError(f"tell() got latents {z.shape} and scores {scores.shape}; expected (n, {self.dim}) and (n,).")
        if not np.all(np.isfinite(scores)):
            raise WorldagentError(
                f"{int(np.sum(~np.isfinite(scores)))} of {len(scores)} scores are NaN or infinite; "
                "the optimiser will not search on them (check the policy and the objective)."
            )
        return z, scores

    def _minimised(self, scores: np.ndarray) -> np.ndarray:
        """Scores in the convention "lower is better"."""
        return -scores if self.maximize else scores


class CMAES(Optimiser):
    """CMA-ES (pycma) from mean 0; sampling from our own generator, so runs are reproducible."""

    name = "cmaes"
    whole_generations = True

    def __init__(self, dim: int, maximize: bool, seed: int, config: OptimiserConfig = OptimiserConfig()):
        super().__init__(dim, maximize, seed)
        import cma

        rng = np.random.default_rng(seed)
        options = {
            "popsize": config.popsize,
            "seed": seed + 1,  # pycma treats 0 as "seed from the clock"
            "randn": lambda *shape: rng.standard_normal(shape),  # not numpy's global state
            "verbose": -9,
            "verb_log": 0,
            "verb_disp": 0,
        }
        if config.bound > 0:
            options["bounds"] = [-config.bound, config.bound]
        self.es = cma.CMAEvolutionStrategy(np.zeros(dim), config.sigma0, options)
        self._pending: np.ndarray | None = None

    @property
    def batch_size(self) -> int:
        return int(self.es.popsize)

    def ask(self, n: int) -> np.ndarray:
        if n != self.batch_size:
            raise WorldagentError(f"CMA-ES asks a whole generation of {self.batch_size}; asked for {n}.")
        if self._pending is not None:
            raise WorldagentError("CMA-ES: tell() the scores of the last generation before asking again.")
        self._pending = np.asarray(self.es.ask(), np.float64)
        return self._pending.copy()

    def tell(self, z, scores) -> None:
        z, scores = self._checked(z, scores)
        if self._pending is None or not np.array_equal(z, self._pending):
            raise WorldagentError("CMA-ES must be told the scores of exactly the generation it asked for.")
        self.es.tell(list(z), list(self._minimised(scores)))
        self._pending = None


class BayesOpt(Optimiser):
    """GP + expected improvement (``bayesian-optimization``), batches by constant liar."""

    name = "bo"

    def __init__(self, dim: int, maximize: bool, seed: int, config: OptimiserConfig = OptimiserConfig()):
        super().__init__(dim, maximize, seed)
        from bayes_opt import BayesianOptimization, acquisition

        if config.bound <= 0:
            raise WorldagentError("Bayesian optimisation needs a box: pass a positive bound.")
        self.keys = [f"z{i:02d}" for i in range(dim)]  # zero-padded: the library sorts keys

        class Liar(acquisition.ConstantLiar):
            """The constant liar with our budget for maximising the acquisition."""

            def suggest(self, gp, target_space, n_random=None, n_smart=None, fit_gp=True, random_state=None):
                return super().suggest(gp, target_space, config.bo_candidates, config.bo_starts, fit_gp, random_state)

        liar = Liar(acquisition.ExpectedImprovement(xi=config.xi), strategy="max")  # seeded at suggest() by random_state below
        self.bo = BayesianOptimization(
            f=None,
            pbounds={key: (-config.bound, config.bound) for key in self.keys},
            acquisition_function=liar,
            random_state=seed,
            verbose=0,
            allow_duplicate_points=True,
        )
        self.config = config

    @property
    def batch_size(self) -> int:
        return self.config.bo_batch

    def ask(self, n: int) -> np.ndarray:
        if n < 1:
            raise WorldagentError(f"ask({n}): ask for at least one latent.")
        if len(self.bo.space) < self.config.initial_points:
            suggestions = self.bo.random_sample(n)  # seeded by the optimiser's random state
        else:
            suggestions = [self.bo.suggest() for _ in range(n)]
        points = [self.bo.space.params_to_array(params) for params in suggestions]
        return np.asarray(points, np.float64).reshape(n, self.dim)

    def tell(self, z, scores) -> None:
        z, scores = self._checked(z, scores)
        for point, score in zip(z, -self._minimised(scores)):  # the library maximises
            self.bo.register(params=dict(zip(self.keys, point)), target=float(score))


class RandomSearch(Optimiser):
    """z ~ N(0, I): the distribution the generator was trained for (the baseline)."""

    name = "random"

    def __init__(self, dim: int, maximize: bool, seed: int, config: OptimiserConfig = OptimiserConfig()):
        super().__init__(dim, maximize, seed)
        # Its own stream: with default_rng(seed) its first 21 draws would be CMA-ES's first
        # generation (σ₀ = 1, mean 0) for the same seed, and comparisons would share them.
        self.rng = np.random.default_rng([seed, RANDOM_STREAM])
        self.config = config

    @property
    def batch_size(self) -> int:
        return self.config.random_batch

    def ask(self, n: int) -> np.ndarray:
        if n < 1:
            raise WorldagentError(f"ask({n}): ask for at least one latent.")
        return self.rng.standard_normal((n, self.dim))

    def tell(self, z, scores) -> None:
        self._checked(z, scores)


RANDOM_STREAM = 1  # RandomSearch's rng is default_rng([seed, RANDOM_STREAM])


def make_optimiser(name: str, dim: int, maximize: bool, seed: int, config: OptimiserConfig = OptimiserConfig()) -> Optimiser:
    """The optimiser called ``name`` ("cmaes", "bo" or "random")."""
    kinds = {"cmaes": CMAES, "bo": BayesOpt, "random": RandomSearch}
    if name not in kinds:
        raise WorldagentError(f"unknown optimiser {name!r}; use one of: {', '.join(OPTIMISERS)}.")
    return kinds[name](dim, maximize, seed, config)
