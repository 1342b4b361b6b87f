"""How fast the explorer answers over a real run, through HTTP on 127.0.0.1 (issue 27).

    python benchmarks/explorer.py --run runs/quick [--seconds 60 --clients 20]

For each environment of the run, after a warm-up (compiling G(z) and the run's agent):

- *play*: ``POST /api/ENV/play`` with a fresh latent each time, i.e. decode G(z) + 8 episodes of
  the run's agent, p50 / p95 over ``--requests`` requests (target for racing: p95 ≤ 100 ms);
- *decode*: ``GET /api/ENV/decode.png`` (a slider move), p50 / p95;
- *map*: ``GET /api/ENV/map`` (target ≤ 1 s), and how long ``Session.open`` took to read the run.

Then ``--clients`` threads send a mix of requests (map, pictures, decodes, plays, failures) for
``--seconds`` and count the answers that are not 200. Results: ``benchmarks/results/explorer-<backend>.json``.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import QUICK_RUN, record, require_input  # noqa: E402


def percentiles(seconds: list[float]) -> dict:
    ms = 1000 * np.asarray(seconds)
    return {"p50_ms": round(float(np.percentile(ms, 50)), 1), "p95_ms": round(float(np.percentile(ms, 95)), 1), "requests": len(ms)}


def timed(call) -> float:
    start = time.perf_counter()
    response = call()
    elapsed = time.perf_counter() - start
    if response.status_code != 200:
        raise SystemExit(f"{response.request.url} answered {response.status_code}: {response.text[:200]}")
    return elapsed


def latents(rng, dim: int) -> list[float]:
    return np.clip(rng.standard_normal(dim), -3, 3).round(3).tolist()


def env_timings(http, env: dict, requests: int, rng) -> dict:
    name, dim = env["name"], env["latent_dim"]
    agent = env["agents"][0]
    play = lambda: http.post(f"/api/{name}/play", json={"z": latents(rng, dim), "agent": agent, "episodes": 8})  # noqa: E731
    decode = lambda: http.get(f"/api/{name}/decode.png", params={"z": ",".join(map(str, latents(rng, dim)))})  # noqa: E731
    for _ in range(3):  # warm: whatever the first calls compile
        timed(play)
        timed(decode)
    return {
        "agent": agent,
        "play_decode_and_8_episodes": percentiles([timed(play) for _ in range(requests)]),
        "decode_picture": percentiles([timed(decode) for _ in range(requests)]),
        "map_s": round(min(timed(lambda: http.get(f"/api/{name}/map")) for _ in range(3)), 3),
        "worlds_on_map": env["worlds"],
    }


def load(url: str, envs: list[dict], clients: int, seconds: float) -> dict:
    """``clients`` threads, each with its own connection, sending a mix of requests until time is up."""
    import httpx

    counts = {"answered": 0, "errors": 0}
    failures: list[str] = []
    lock = threading.Lock()
    stop = time.monotonic() + seconds

    def client(seed: int) -> None:
        rng = np.random.default_rng(seed)
        with httpx.Client(base_url=url, timeout=120) as http:
            while time.monotonic() < stop:
                env = envs[rng.integers(len(envs))]
                name, dim, worlds = env["name"], env["latent_dim"], env["worlds"]
                kind = rng.integers(5)
                try:
                    if kind == 0:
                        response = http.get(f"/api/{name}/map")
                    elif kind == 1:
                        response = http.get(f"/api/{name}/world/{rng.integers(worlds)}.png", params={"size": 160})
                    elif kind == 2:
                        response = http.get(f"/api/{name}/decode.png", params={"z": ",".join(map(str, latents(rng, dim)))})
                    elif kind == 3:
                        response = http.post(f"/api/{name}/play", json={"z": latents(rng, dim), "agent": env["agents"][0], "episodes": 8})
                    else:
                        response = http.get(f"/api/{name}/failures", params={"limit": 20})
                    ok = response.status_code == 200
                    problem = f"{response.request.url}: {response.status_code}"
                except httpx.HTTPError as error:
                    ok, problem = False, f"{type(error).__name__}: {error}"
                with lock:
                    counts["answered" if ok else "errors"] += 1
                    if not ok and len(failures) < 10:
                        failures.append(problem)

    threads = [threading.Thread(target=client, args=(seed,)) for seed in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return {**counts, "clients": clients, "seconds": seconds, "first_errors": failures}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=Path("runs/quick"))
    parser.add_argument("--requests", type=int, default=100)
    parser.add_argument("--clients", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--port", type=int, default=8777)
    args = parser.parse_args()

    import httpx
    import uvicorn

    from worldagent.explore.server import make_app
    from worldagent.explore.session import Session

    start = time.perf_counter()
    session = Session.open(require_input(args.run, QUICK_RUN))
    open_s = time.perf_counter() - start
    server = uvicorn.Server(uvicorn.Config(make_app(session), host="127.0.0.1", port=args.port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    url = f"http://127.0.0.1:{args.port}"
    rng = np.random.default_rng(0)
    with httpx.Client(base_url=url, timeout=300) as http:
        envs = http.get("/api/run").json()["envs"]
        timings = {env["name"]: env_timings(http, env, args.requests, rng) for env in envs}
    for name, found in timings.items():
        print(f"{name}: play (decode + 8 episodes) {found['play_decode_and_8_episodes']}, decode {found['decode_picture']}, map {found['map_s']} s")
    concurrent = load(url, envs, args.clients, args.seconds)
    print(f"{args.clients} clients for {args.seconds:.0f} s: {concurrent['answered']} answered, {concurrent['errors']} errors")
    server.should_exit = True
    thread.join(timeout=10)
    # Other jobs on the machine slow every number down: the 1-minute load average says how busy it was.
    result = {
        "run": str(args.run),
        "session_open_s": round(open_s, 2),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "envs": timings,
        "concurrent": concurrent,
    }
    print(f"recorded in {record('explorer', result)}")


if __name__ == "__main__":
    main()
