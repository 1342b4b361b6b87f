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

Inside the prior (issue 48): a campaign wraps its optimiser in ``WithinPrior``, which projects every latent asked
onto the prior's typical set |z| <= r (``prior.py``) before it is decoded and tells the optimiser where each was
evaluated (``tell_evaluated``); random search samples the prior and is left as it is.

Noise-aware searches (issue 50): a world's score is the mean of a few episodes, so the best score a search
saw is partly luck (the winner's curse). These re-ask latents they have already evaluated (a re-evaluation
is a new evaluation: its own (generation, slot) and episode seed) and report the latent with the best mean
over all its evaluations (``reported_evaluation``):

- ``cmaes-re``: CMA-ES with re-evaluation of the incumbents (``Reevaluating``): each generation of 21 is 18
  CMA-ES samples and the 3 latents with the best pooled means so far, asked again; CMA-ES is told its own
  samples' scores. (pycma's ``NoiseHandler``, Hansen et al. 2009, evaluates its re-samples itself by calling
  the objective and draws from numpy's global random state, so it does not fit an ask/tell campaign that
  must replay identically.)
- ``bo-noise``: BO whose GP has a learned noise level (a ``WhiteKernel`` fitted with the Matern kernel) and
  whose expected improvement is measured from the best posterior mean at the observed latents instead of
  the luckiest observation; each round of 4 suggestions also re-asks the incumbent.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from dataclasses import replace as dataclasses_replace
from typing import Any

import numpy as np

from worldagent.errors import WorldagentError

OPTIMISERS = ("cmaes", "bo", "random")
# Worlds a search evaluates by default (``strategic``, ``search``). BO's Gaussian process is refitted every round on all the
# worlds seen so far, so its cost grows with their cube: at 2,000 worlds a search would take hours. 210 is the budget at which
# BO's worlds were compared with CMA-ES's on fresh episodes (benchmarks/results/noisy-search.json).
DEFAULT_BUDGETS = {"cmaes": 2_000, "bo": 210, "random": 2_000}
NOISE_AWARE = ("cmaes-re", "bo-noise")  # searches that re-evaluate (see the module docstring)
CMAES_REEVALUATIONS = 3  # incumbents re-asked per CMA-ES generation (of the 21: 18 samples + 3)
BO_REEVALUATIONS = 1  # incumbents re-asked per BO round (4 suggestions + 1)
NOISE_LEVEL = (0.5, (1e-4, 10.0))  # the WhiteKernel's start and bounds, in units of the normalised scores' variance


@dataclass(frozen=True)
class OptimiserConfig:
    """Settings of the optimisers (only those of the chosen one apply).

    Attributes:
        popsize: CMA-ES population per generation (paper: 21).
        sigma0: CMA-ES initial step size (the latent prior has unit scale).
        bound: box bound |z_i| <= bound for CMA-ES and BO (3: the prior's ±3σ); 0 = unbounded
            CMA-ES (BO always needs a box). A campaign inside the prior's ball (``CampaignSpec.prior_bound``)
            replaces it (``within_prior_config``): the box then applies only to searches beyond the prior.
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
    samples_prior = False  # draws from the prior itself (random search): a campaign keeps its latents as they are

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

    def tell_evaluated(self, asked: np.ndarray, evaluated: np.ndarray, scores: np.ndarray) -> None:
        """Tell the scores of the latents ``asked``, which were evaluated at ``evaluated`` (``WithinPrior``
        projected them into the prior's ball). Default: told the evaluated latents (a GP models the points it
        saw; CMA-ME describes the worlds played); an optimiser that must be told what it asked overrides this."""
        self.tell(evaluated, scores)

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
        self.tell_evaluated(z, z, scores)

    def tell_evaluated(self, asked, evaluated, scores) -> None:
        """Told the evaluated latents (Lamarckian repair): pycma takes solutions other than those it asked and clips
        their Mahalanobis length (``check_points``), so its mean stays where worlds were played. Without a box, as
        pycma disregards changed solutions under its own boundary handling."""
        asked = np.asarray(asked, np.float64)
        evaluated, scores = self._checked(evaluated, scores)
        if self._pending is None or not np.array_equal(asked, self._pending):
            raise WorldagentError("CMA-ES must be told the scores of exactly the generation it asked for.")
        self.es.tell(list(evaluated), list(self._minimised(scores)))
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
    plug_in = False  # measure improvement from the best posterior mean (``NoisyBayesOpt``)

    def __init__(self, dim: int, maximize: bool, seed: int, config: OptimiserConfig = OptimiserConfig()):
        super().__init__(dim, maximize, seed)
        from bayes_opt import BayesianOptimization, acquisition

        if config.bound <= 0:
            raise WorldagentError("Bayesian optimisation needs a box: pass a positive bound.")
        self.keys = [f"z{i:02d}" for i in range(dim)]  # zero-padded: the library sorts keys

        plug_in = self.plug_in

        class EI(acquisition.ExpectedImprovement):
            incumbent: float | None = None

            def _smart_minimize(self, acq, space, x_seeds, random_state):
                return minimise_from(acq, x_seeds, space.bounds)

            def suggest(self, gp, target_space, n_random=10_000, n_smart=10, fit_gp=True, random_state=None):
                # the liar has fitted ``gp`` to the observations and its dummies: improvement over the best
                # posterior mean there, not over the luckiest noisy observation (plug-in EI)
                self.incumbent = float(np.max(gp.predict(target_space.params))) if plug_in else None
                return super().suggest(gp, target_space, n_random, n_smart, fit_gp, random_state)

            def base_acq(self, mean, std):
                if self.incumbent is not None:
                    self.y_max = self.incumbent
                return super().base_acq(mean, std)

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
        import contextlib
        import io

        z, scores = self._checked(z, scores)
        with contextlib.redirect_stdout(io.StringIO()):  # the library prints a line for each repeated latent
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
    samples_prior = True  # its latents are the prior's draws: no bound applies (``WithinPrior``)

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


class NoisyBayesOpt(BayesOpt):
    """BO with a learned noise level: the GP's kernel is Matern + ``WhiteKernel``, both fitted to the
    observations (a world's score is a mean of a few episodes, not a noiseless value), and expected improvement
    is measured from the best posterior mean at the observed latents (plug-in EI)."""

    name = "bo-noise"
    plug_in = True

    def __init__(self, dim: int, maximize: bool, seed: int, config: OptimiserConfig = OptimiserConfig()):
        super().__init__(dim, maximize, seed, config)
        from sklearn.gaussian_process.kernels import Matern, WhiteKernel

        level, bounds = NOISE_LEVEL
        self.bo.set_gp_params(kernel=Matern(nu=2.5) + WhiteKernel(noise_level=level, noise_level_bounds=bounds))

    @property
    def noise_level(self) -> float:
        """The fitted noise variance, in units of the normalised scores' variance (NaN before the first fit)."""
        kernel = getattr(self.bo._gp, "kernel_", None)
        return float(kernel.k2.noise_level) if kernel is not None else float("nan")


def latent_key(z: np.ndarray) -> bytes:
    """A latent's identity for pooling: its float64 bytes (a re-asked latent is the very same array)."""
    return np.ascontiguousarray(z, np.float64).tobytes()


class Pooled:
    """Every latent's evaluations so far, pooled: the sum and count of its scores ("lower is better")."""

    def __init__(self, dim: int):
        self.dim = dim
        self.latents: dict[bytes, np.ndarray] = {}  # in order of first evaluation
        self.sums: dict[bytes, float] = {}
        self.counts: dict[bytes, int] = {}

    def add(self, z: np.ndarray, minimised: np.ndarray) -> None:
        for latent, score in zip(z, minimised):
            key = latent_key(latent)
            self.latents.setdefault(key, np.array(latent, np.float64))
            self.sums[key] = self.sums.get(key, 0.0) + float(score)
            self.counts[key] = self.counts.get(key, 0) + 1

    def best(self, count: int) -> np.ndarray:
        """f64[<=count, dim]: the latents with the lowest pooled means, the earliest first on ties."""
        keys = list(self.latents)
        means = np.array([self.sums[k] / self.counts[k] for k in keys])
        order = np.argsort(means, kind="stable")[:count]
        return np.array([self.latents[keys[i]] for i in order], np.float64).reshape(-1, self.dim)

    def count(self, z: np.ndarray) -> int:
        return self.counts.get(latent_key(z), 0)

    def mean(self, z: np.ndarray) -> float:
        key = latent_key(z)
        return self.sums[key] / self.counts[key] if key in self.counts else float("nan")


class Reevaluating(Optimiser):
    """Another optimiser's rounds, each followed by ``reevaluations`` incumbents asked again.

    A generation is the base optimiser's round and then the ``reevaluations`` latents with the best pooled means
    so far (before anything is scored: the round's own first latents), so a world that scored well by luck is
    played again, its mean regresses, and another takes its place; one that stays is a world that fails.
    ``tell_reevaluations``: the base optimiser is told the re-evaluations too (a GP learns its noise level from
    them); else only its own round (CMA-ES must be told exactly what it asked). Report by
    ``reported_evaluation``, which pools a latent's evaluations.
    """

    whole_generations = True

    def __init__(self, base: Optimiser, reevaluations: int, name: str, tell_reevaluations: bool = False):
        super().__init__(base.dim, base.maximize, base.seed)
        if reevaluations < 1:
            raise WorldagentError(f"reevaluations={reevaluations}; re-ask at least one incumbent per generation.")
        self.base, self.reevaluations, self.name = base, int(reevaluations), name
        self.tell_reevaluations = tell_reevaluations
        self.pooled = Pooled(base.dim)
        self._pending: np.ndarray | None = None

    @property
    def batch_size(self) -> int:
        return self.base.batch_size + self.reevaluations

    def ask(self, n: int) -> np.ndarray:
        if n != self.batch_size:
            raise WorldagentError(f"{self.name} asks a whole generation of {self.batch_size}; asked for {n}.")
        if self._pending is not None:
            raise WorldagentError(f"{self.name}: tell() the scores of the last generation before asking again.")
        fresh = np.asarray(self.base.ask(self.base.batch_size), np.float64)
        again = self.pooled.best(self.reevaluations)
        again = np.vstack([again, fresh[: self.reevaluations - len(again)]])  # nothing scored yet: the round's own
        self._pending = np.vstack([fresh, again])
        return self._pending.copy()

    def tell(self, z, scores) -> None:
        self.tell_evaluated(z, z, scores)

    def tell_evaluated(self, asked, evaluated, scores) -> None:
        """The base told its round (evaluated where ``WithinPrior`` moved it); the pool keeps the evaluated latents,
        so a re-asked incumbent is the latent that was played."""
        asked = np.asarray(asked, np.float64)
        evaluated, scores = self._checked(evaluated, scores)
        if self._pending is None or not np.array_equal(asked, self._pending):
            raise WorldagentError(f"{self.name} must be told the scores of exactly the generation it asked for.")
        told = len(asked) if self.tell_reevaluations else self.base.batch_size
        self.base.tell_evaluated(asked[:told], evaluated[:told], scores[:told])
        self.pooled.add(evaluated, self._minimised(scores))
        self._pending = None

    def incumbent(self) -> tuple[np.ndarray, float, int]:
        """(latent, pooled mean in the search's direction, evaluations) of the best pooled mean so far."""
        z = self.pooled.best(1)[0]
        mean = self.pooled.mean(z)
        return z, -mean if self.maximize else mean, self.pooled.count(z)


class WithinPrior(Optimiser):
    """Another optimiser whose latents are kept inside the prior's ball |z| <= ``radius`` (``prior.within_ball``).

    Every latent the base asks is projected onto the ball before it is returned, so the campaign decodes, scores and
    stores the projected latent; the base is told the scores through ``tell_evaluated`` (with what it asked and where
    it was evaluated). ``radius`` None: the base's latents unchanged. ``run_campaign`` wraps every optimiser in one.
    """

    def __init__(self, base: Optimiser, radius: float | None):
        super().__init__(base.dim, base.maximize, base.seed)
        self.base, self.radius, self.name = base, radius, base.name
        self.whole_generations = base.whole_generations
        self._asked: np.ndarray | None = None

    @property
    def batch_size(self) -> int:
        return self.base.batch_size

    def ask(self, n: int) -> np.ndarray:
        from worldagent.search.prior import within_ball

        self._asked = np.asarray(self.base.ask(n), np.float64)
        return within_ball(self._asked, self.radius)

    def tell(self, z, scores) -> None:
        from worldagent.search.prior import within_ball

        if self._asked is None or not np.array_equal(np.asarray(z, np.float64), within_ball(self._asked, self.radius)):
            raise WorldagentError(f"{self.name}: tell() the scores of exactly the latents it last asked for.")
        asked, self._asked = self._asked, None
        self.base.tell_evaluated(asked, np.asarray(z, np.float64), scores)

    def __getattr__(self, name: str) -> Any:  # the base's own attributes (an atlas's grid, a pool's incumbent)
        if name == "base":
            raise AttributeError(name)
        return getattr(self.base, name)


def within_prior_config(name: str, config: OptimiserConfig, radius: float | None) -> OptimiserConfig:
    """The settings optimiser ``name`` runs with inside the ball |z| <= ``radius`` (None: ``config`` as it is).

    The ball replaces the per-coordinate box: CMA-ES runs without one (pycma would disregard the projected
    solutions it is told under its boundary handling), BO's box is the smallest holding the ball, [-radius, radius].
    """
    if radius is None:
        return config
    return dataclasses_replace(config, bound=0.0 if name.startswith("cmaes") else float(radius))


def reported_evaluation(evaluations: Sequence[Any], maximize: bool) -> Any:
    """The world a search reports: the latent with the best mean over all its evaluations.

    A search that re-evaluates vouches only for the latents it re-evaluated, so when some latent was evaluated
    more than once the pick is among those; otherwise (a search without re-evaluation) among all, and it is
    ``campaign.best_evaluation``'s. Given worlds (no latent) are each their own world.

    Returns:
        The pick's first ``store.Evaluation`` with ``score`` its pooled mean and ``episodes`` all its episodes
        (what ``analysis.confirm`` reports as found), or None when no score is finite.
    """
    import dataclasses

    groups: dict[Any, list] = {}
    for e in evaluations:
        if np.isfinite(e.score):
            groups.setdefault(latent_key(e.latent) if np.size(e.latent) else (e.campaign, e.generation, e.slot), []).append(e)
    if not groups:
        return None
    repeated = [g for g in groups.values() if len(g) > 1]
    candidates = repeated or list(groups.values())
    means = np.array([sum(e.score * max(len(e.episodes), 1) for e in g) / sum(max(len(e.episodes), 1) for e in g) for g in candidates])
    pick = int(np.argmax(means) if maximize else np.argmin(means))
    group = candidates[pick]
    return dataclasses.replace(group[0], score=float(means[pick]), episodes=[episode for e in group for episode in e.episodes])


def samples_prior(name: str) -> bool:
    """Whether optimiser ``name`` draws its latents from the prior itself (random search: no bound applies)."""
    return name == RandomSearch.name


def make_optimiser(name: str, dim: int, maximize: bool, seed: int, config: OptimiserConfig = OptimiserConfig()) -> Optimiser:
    """The optimiser called ``name`` (one of ``OPTIMISERS`` or ``NOISE_AWARE``)."""
    if name == "cmaes-re":
        if config.popsize - CMAES_REEVALUATIONS < 2:
            raise WorldagentError(
                f"cmaes-re: popsize {config.popsize} leaves CMA-ES under 2 samples beside {CMAES_REEVALUATIONS} re-evaluations; raise it."
            )
        base = CMAES(dim, maximize, seed, dataclasses_replace(config, popsize=config.popsize - CMAES_REEVALUATIONS))
        return Reevaluating(base, CMAES_REEVALUATIONS, name)
    if name == "bo-noise":
        return Reevaluating(NoisyBayesOpt(dim, maximize, seed, config), BO_REEVALUATIONS, name, tell_reevaluations=True)
    kinds = {"cmaes": CMAES, "bo": BayesOpt, "random": RandomSearch}
    if name not in kinds:
        raise WorldagentError(f"unknown optimiser {name!r}; use one of: {', '.join(OPTIMISERS + NOISE_AWARE)}.")
    return kinds[name](dim, maximize, seed, config)
