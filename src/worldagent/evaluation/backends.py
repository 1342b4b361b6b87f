"""Where a campaign's world batches are evaluated: in this process, or on Ray workers.

``backend.run(evaluate, batches)`` takes the batches of one generation, ``[(slots, z, seeds)]``,
and yields ``(slots, outcomes)`` as each batch finishes; the campaign commits them to the store
as they arrive. An evaluation depends only on its latent and seed, never on which batch or
worker ran it, so both backends fill the store with the same evaluations, and resuming works
as for local runs.

- ``LocalBackend``: one batch after another here (the local evaluator already uses every local
  device).
- ``RayBackend`` (extra ``ray``): batches go to Ray tasks, one per worker, each running the same
  evaluator (jitted or host); ``map`` runs any function's tasks the same way (training programs,
  ``agents.many``). A task whose worker dies is retried by Ray (``max_retries``), and
  only the driver writes to the store, so nothing is lost or counted twice. ``address`` joins a
  running cluster (``ray start --head`` on one machine, then ``--ray-address HOST:6379``);
  without one a local cluster starts.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import socket
import tempfile
import threading
import uuid
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from worldagent.errors import WorldagentError

BACKENDS = ("local", "ray")
TASK_RETRIES = 3  # re-runs of a batch whose worker died
JOIN_TIMEOUT_S = 30  # Ray itself waits for an unanswering cluster for minutes

Batch = tuple[list[int], np.ndarray, np.ndarray]  # (slots, z[n, dim], seeds[n])


class LocalBackend:
    """Evaluate batches one after another in this process."""

    name = "local"
    workers = 1

    def run(self, evaluate: Callable, batches: Sequence[Batch]) -> Iterator[tuple[list[int], Any]]:
        for slots, z, seeds in batches:
            yield slots, evaluate(z, seeds)


class RayBackend:
    """Evaluate batches as Ray tasks, yielding each as it finishes (see the module docstring).

    Args:
        address: a running cluster's address (``ray start --head`` prints it); None starts a
            local cluster with ``workers`` CPUs.
        workers: CPUs of a local cluster (default: all of this machine's).
    """

    name = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None):
        try:
            import ray
        except ImportError:
            raise WorldagentError("--backend ray needs Ray: pip install 'worldagent[ray]'.") from None
        self.ray = ray
        if not ray.is_initialized():
            join_cluster(ray, address, workers)
        self.workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
        self._task = ray.remote(max_retries=TASK_RETRIES)(_evaluate_batch)
        self._shipped: tuple[Callable, str, Any] | None = None  # (evaluator, token, ref) last shipped

    def run(self, evaluate: Callable, batches: Sequence[Batch]) -> Iterator[tuple[list[int], Any]]:
        token, ref = self._ship(evaluate)
        pending = {self._task.remote(token, [ref], z, seeds): slots for slots, z, seeds in batches}
        while pending:
            done, _ = self.ray.wait(list(pending), num_returns=1)
            slots = pending.pop(done[0])
            yield slots, self._get(done[0])

    def map(self, function: Callable, tasks: Sequence[tuple], title: str = "", progress: bool = False) -> list:
        """``[function(*task) for task in tasks]``, each task on a worker (retried if its worker dies), in order."""
        from worldagent.progress import progress_bar

        remote = self.ray.remote(max_retries=TASK_RETRIES)(function)
        pending = {remote.remote(*task): i for i, task in enumerate(tasks)}
        results: list = [None] * len(tasks)
        with progress_bar(title or "tasks on Ray", total=len(tasks), enabled=progress) as advance:
            while pending:
                done, _ = self.ray.wait(list(pending), num_returns=1)
                results[pending.pop(done[0])] = self._get(done[0])
                advance(1)
        return results

    def _get(self, ref: Any) -> Any:
        """A finished task's result; the task's own error (e.g. a bad agent) as one line."""
        try:
            return self.ray.get(ref)
        except self.ray.exceptions.RayTaskError as error:
            cause = error.cause if isinstance(getattr(error, "cause", None), Exception) else error
            raise WorldagentError(str(cause).splitlines()[0] if str(cause) else type(cause).__name__) from None

    def _ship(self, evaluate: Callable) -> tuple[str, Any]:
        """The evaluator in the object store, once per evaluator, with a token workers cache it under.

        Known by identity while held here: an ``id()`` alone is reused once an evaluator is freed, and
        workers then ran the previous campaign's evaluator on the next one's batches."""
        if self._shipped is None or self._shipped[0] is not evaluate:
            self._shipped = (evaluate, uuid.uuid4().hex, self.ray.put(evaluate))
        return self._shipped[1:]


def join_cluster(ray: Any, address: str | None, workers: int | None) -> None:
    """``ray.init`` the cluster at ``address`` (None: a new local one), or fail in one line within
    ``JOIN_TIMEOUT_S`` saying why: nothing listening, no answer, or Ray's own reason (e.g. a token)."""
    where = address or "a new local cluster"
    check_listening(address)
    outcome: dict[str, BaseException | None] = {}

    def join() -> None:
        try:
            ray.init(
                address=address,
                num_cpus=None if address else workers,
                include_dashboard=False,
                log_to_driver=False,
                logging_level=logging.ERROR,  # our progress bar, not Ray's start-up chatter
            )
            outcome["error"] = None
        except BaseException as error:  # reported below, in the caller's thread
            outcome["error"] = error

    with stderr_to_file() as log:  # Ray's core logs its real reasons to stderr, not in the exception
        if address:  # in a thread, to stop waiting; a new local cluster starts here (its processes die with their thread)
            thread = threading.Thread(target=join, daemon=True)
            thread.start()
            thread.join(JOIN_TIMEOUT_S)
        else:
            join()
        logged = log.read_text(errors="replace")
    if "error" not in outcome:
        raise WorldagentError(
            f"the Ray cluster at {where} did not answer within {JOIN_TIMEOUT_S} s; check --ray-address (is it a Ray head's GCS port?)."
        )
    if outcome["error"] is not None:
        raise WorldagentError(f"cannot join the Ray cluster at {where}: {join_failure(outcome['error'], logged)}") from None


def join_failure(error: BaseException, log: str) -> str:
    """Why joining failed, in words that name the fix (Ray's logged cause beats its exception)."""
    if "Unauthenticated" in log or "InvalidAuthToken" in log:
        return "the cluster requires a token; run with RAY_AUTH_MODE=token and the head's token (~/.ray/auth_token, RAY_AUTH_TOKEN or RAY_AUTH_TOKEN_PATH)."
    first = (str(error).splitlines() or [""])[0][:160] or type(error).__name__
    return f"{first}; check --ray-address."


def check_listening(address: str | None) -> None:
    """One line, at once, when nothing listens at a ``HOST:PORT`` address (Ray would wait for minutes)."""
    if not address or address == "auto":
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise WorldagentError(f"--ray-address {address!r} is not HOST:PORT; pass the address `ray start --head` prints, e.g. 127.0.0.1:6379.")
    try:
        socket.create_connection((host, int(port)), timeout=5).close()
    except OSError as error:
        raise WorldagentError(
            f"nothing answers at {address} ({error.strerror or error}); start a cluster with `ray start --head` or fix --ray-address."
        ) from None


@contextlib.contextmanager
def stderr_to_file():
    """File descriptor 2 (where Ray's C++ core logs) sent to a temporary file, yielded as a Path."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "ray-join.log"
        saved = os.dup(2)
        with open(path, "wb") as sink:
            os.dup2(sink.fileno(), 2)
            try:
                yield path
            finally:
                os.dup2(saved, 2)
                os.close(saved)


_WORKER_CACHE: dict[str, Callable] = {}  # in each worker: evaluators by token, so jitted code compiles once


def _evaluate_batch(token: str, refs: list, z: np.ndarray, seeds: np.ndarray):
    """A Ray task: the shipped evaluator on one batch (the ref comes in a list so Ray leaves it unresolved)."""
    if token not in _WORKER_CACHE:
        import ray

        _WORKER_CACHE.clear()  # one campaign's evaluator at a time
        _WORKER_CACHE[token] = ray.get(refs[0])
    return _WORKER_CACHE[token](z, seeds)


def split(slots: Sequence[int], parts: int, chunk: int = 0) -> list[list[int]]:
    """``slots`` in consecutive batches: of ``chunk`` each, or (0) ``parts`` batches as even as possible."""
    slots = list(slots)
    if not slots:
        return []
    size = chunk or math.ceil(len(slots) / max(1, parts))
    return [slots[start : start + size] for start in range(0, len(slots), size)]


def make_backend(name: str = "local", address: str | None = None, workers: int | None = None) -> LocalBackend | RayBackend:
    """The backend ``--backend`` names; ``address`` and ``workers`` are Ray's."""
    if name not in BACKENDS:
        raise WorldagentError(f"unknown backend {name!r}; use one of: {', '.join(BACKENDS)}.")
    if name == "local":
        if address:
            raise WorldagentError("--ray-address needs --backend ray.")
        return LocalBackend()
    return RayBackend(address, workers)
