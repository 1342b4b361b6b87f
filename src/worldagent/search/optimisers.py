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
  cost grows as O(evaluations³): budgets of a few hundred, as in the paper's comparison (a
  suggestion at 210 observations: ~0.11 s of CPU, ``benchmarks/bo_suggestion.py``).
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
        bo_starts: L-BFGS runs when maximising EI, from the best random candidates (the
            library's default is 10).
        bo_candidates: random candidates scored before those runs (the library's default is
            10,000; scoring them was half a suggestion's cost at 210 observations, and they only
            pick the L-BFGS starts).
        bo_gp_restarts: random restarts of the GP's hyperparameter fit, once per batch, besides
            the warm start from the last batch's fit (the library: 5 at every suggestion; with 1, a
            fit stuck at a poor length scale cost one seed in 10 most of its progress on a sphere).
        random_batch: random-search latents per round.
    """

    popsize: int = 21
    sigma0: float = 1.0
    bound: float = 3.0
    bo_batch: int = 4
    initial_points: int = 10
    xi: float = 0.01
    bo_starts: int = 3
    bo_candidates: int = 2_000
    bo_gp_restarts: int = 5
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
    """GP + expected improvement (``bayesian-optimization``), batches by constant liar.

    What a suggestion costs, and how it is kept small (``benchmarks/bo_suggestion.py``): the GP's
    hyperparameters (one Matern length scale) are fitted once per batch, on the real
    observations, from the previous batch's fit and ``bo_gp_restarts`` random starts; the
    constant liar's refits for the batch's later suggestions only update the posterior with
    those hyperparameters. EI is maximised from the best of ``bo_candidates`` random latents by
    ``bo_starts`` L-BFGS runs, each gradient a forward difference computed in one batched GP
    prediction instead of ``dim + 1`` calls. Linear algebra runs on one BLAS thread.
    """

    name = "bo"

    def __init__(self, dim: int, maximize: bool, seed: int, config: OptimiserConfig = OptimiserConfig()):
        super().__init__(dim, maximize, seed)
        from bayes_opt import BayesianOptimization, acquisition

        if config.bound <= 0:
            raise WorldagentError("Bayesian optimisation needs a box: pass a positive bound.")
        self.keys = [f"z{i:02d}" for i in range(dim)]  # zero-padded: the library sorts keys

        class EI(acquisition.ExpectedImprovement):
            def _smart_minimize(self, acq, space, x_seeds, random_state):
                return minimise_from(acq, x_seeds, space.bounds)

        class Liar(acquisition.ConstantLiar):
            """The constant liar with our budget for maximising the acquisition."""

            def _fit_gp(self, gp, target_space):  # hyperparameters fixed for the batch (BayesOpt.ask): the posterior only
                gp.fit(target_space.params, target_space.target)

            def suggest(self, gp, target_space, n_random=None, n_smart=None, fit_gp=True, random_state=None):
                return super().suggest(gp, target_space, config.bo_candidates, config.bo_starts, fit_gp, random_state)

        liar = Liar(EI(xi=config.xi), strategy="max")  # seeded at suggest() by random_state below
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
            from threadpoolctl import threadpool_limits

            # One BLAS thread: the GP's matrices are small, and threads waiting on busy cores
            # (an evaluation's XLA threads, another job) made each solve ~100x slower (measured).
            with threadpool_limits(limits=1, user_api="blas"):
                self._fit_hyperparameters()
                suggestions = [self.bo.suggest() for _ in range(n)]
        points = [self.bo.space.params_to_array(params) for params in suggestions]
        return np.asarray(points, np.float64).reshape(n, self.dim)

    def _fit_hyperparameters(self) -> None:
        """Fit the GP's kernel to the observations, warm-started from the last fit, and fix it for the batch."""
        import warnings

        gp = self.bo._gp  # the library's GP (it has no public handle): seeded by the optimiser's random state
        gp.optimizer, gp.n_restarts_optimizer = "fmin_l_bfgs_b", self.config.bo_gp_restarts
        with warnings.catch_warnings():  # sklearn warns when a length scale reaches its bound
            warnings.simplefilter("ignore")
            gp.fit(self.bo.space.params, self.bo.space.target)
        gp.kernel, gp.optimizer = gp.kernel_, None  # the next fit starts here; the liar's refits keep it

    def tell(self, z, scores) -> None:
        z, scores = self._checked(z, scores)
        for point, score in zip(z, -self._minimised(scores)):  # the library maximises
            self.bo.register(params=dict(zip(self.keys, point)), target=float(score))


def minimise_from(acq, starts: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, float]:
    """The lowest of ``acq`` (f[m, dim] -> f[m]) found by L-BFGS-B from each start, within ``bounds`` f[dim, 2].

    The gradient is a forward difference (scipy's step), its ``dim + 1`` points scored in one call:
    each GP prediction has a fixed cost that dominates at these sizes.
    """
    from scipy.optimize import minimize

    dim = bounds.shape[0]
    step = np.sqrt(np.finfo(np.float64).eps)

    def value_and_gradient(x):
        h = step * np.maximum(1.0, np.abs(x)) * np.where(x >= 0, 1.0, -1.0)
        values = np.asarray(acq(np.vstack([x, x + np.diag(h)])), np.float64).reshape(-1)
        return values[0], (values[1:] - values[0]) / h

    best_x, best = np.full(dim, np.nan), np.inf
    for start in starts:
        found = minimize(value_and_gradient, start, jac=True, bounds=bounds, method="L-BFGS-B")
        if found.success and float(found.fun) < best:
            best_x, best = found.x, float(found.fun)
    return np.clip(best_x, bounds[:, 0], bounds[:, 1]), best


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
