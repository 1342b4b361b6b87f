"""The explorer's web server (FastAPI): the page, its assets, and a JSON/PNG API over one run.

Safe by default: ``serve`` binds 127.0.0.1; any other host needs a token, which every request
then carries (``?token=`` once: the page keeps it in a cookie; or the ``X-Worldagent-Token``
header). Without a token, requests naming another host than the loopback one are refused (a
web page elsewhere cannot reach the server through DNS rebinding), and a request carrying
another site's ``Origin`` is refused always (a page elsewhere cannot make the user's browser
play or save). Requests are checked
(latent length, finite and bounded numbers, capped counts, agents and metrics by name from
the run's own lists; bodies under ``MAX_BODY`` bytes, unknown fields refused): a bad one gets a 4xx
with ``{"error": "<one line>"}``. A play carries its page's ``client`` id and ``seq``uence number: one
that a newer play of the same page overtook while it waited is answered 409 unplayed. Files come only
from the package's ``static/`` folder; nothing is unpickled; nothing is written to the run
except the worlds a user saves (``POST /api/ENV/save``: a one-world dataset in ``<run>/ENV/explorer/``).

API (``ENV``: an environment of the run)::

    GET  /api/run                         the run: environments, metrics, agents, atlases
    GET  /api/ENV/map                     every stored world: projected latent, campaign, metric means; the world's share
    GET  /api/ENV/world/I                 stored world I: campaign, latent, metrics
    GET  /api/ENV/world/I.png             its picture          (?size=)
    GET  /api/ENV/decode.png?z=a,b,...    the picture of G(z)  (?size=)
    POST /api/ENV/play                    {"world": I | "z": [...], "agent", "episodes", "seed", "size", "client", "seq"}: episodes played now
    GET  /api/ENV/ready                   which agents' first play would compile (?agents=a,b&episodes=)
    GET  /api/ENV/failures                failing worlds     (?event=, by=likelihood|severity, limit=)
    GET  /api/ENV/atlas                   the atlas heat map (?name=)
    GET  /api/ENV/diff                    a `worldagent diff` campaign's regressed worlds (?campaign=, event=, limit=)
    GET  /api/ENV/export.npz|.json        a world as a one-world dataset / JSON  (?world=I or ?z=...)
    POST /api/ENV/save                    {"world": I | "z": [...]}: write it to <run>/ENV/explorer/ (the only write)
"""

import hashlib
import json
import math
import secrets
import socket
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Annotated, Any, Literal, Self

import numpy as np
from fastapi import Depends, FastAPI, HTTPException, Query
from fastapi.responses import FileResponse, Response
from pydantic import BaseModel, ConfigDict, Field, model_validator

from worldagent.errors import WorldagentError
from worldagent.explore.guard import install_errors, install_guard
from worldagent.explore.session import RUN_AGENT, EnvSession, Session

STATIC = Path(__file__).parent / "static"
LATENT_BOUND = 10.0  # |z_i| ≤ 10: the prior puts no mass beyond; larger values only decode the edge world
MAX_EPISODES = 16
MAX_SIZE = 768
MAX_FAILURES = 500
SAVED_FOLDER = "explorer"  # <run>/<env>/explorer/: the worlds a user saved (nothing else is ever written)
CLIENTS_KEPT = 1024  # pages whose latest play is remembered


def parse_latent(text: str) -> list[float]:
    """``"0.1,-2,0"`` -> floats (syntax only; ``check_latent`` checks the values)."""
    try:
        return [float(part) for part in text.split(",")] if text.strip() else []
    except ValueError:
        raise WorldagentError(f"z={text[:40]!r}: write the latent as comma-separated numbers, e.g. z=0,0.5,-1") from None


def check_latent(session: EnvSession, z: list[float]) -> np.ndarray:
    """A finite latent of the environment's size within ±LATENT_BOUND."""
    if len(z) != session.latent_dim:
        raise WorldagentError(f"a {session.env} latent has {session.latent_dim} numbers, not {len(z)}.")
    if not all(math.isfinite(v) for v in z):
        raise WorldagentError("the latent holds a non-finite number; send finite numbers only.")
    if max(abs(v) for v in z) > LATENT_BOUND:
        raise WorldagentError(f"latent values lie within ±{LATENT_BOUND:g}; scale the latent down.")
    return np.asarray(z, np.float64)


class WorldRequest(BaseModel):
    """A world to act on: stored world ``world`` or G(``z``), exactly one; no other fields."""

    model_config = ConfigDict(extra="forbid")
    world: int | None = Field(None, ge=0)
    z: list[float] | None = Field(None, max_length=256)

    @model_validator(mode="after")
    def one_source(self) -> Self:
        if (self.world is None) == (self.z is None):
            raise ValueError("give either world (a stored world's index) or z (a latent), not both or neither")
        return self


class PlayRequest(WorldRequest):
    """Play episodes of ``agent`` on the world now."""

    agent: str = Field(RUN_AGENT, max_length=100)
    episodes: int = Field(8, ge=1, le=MAX_EPISODES)
    seed: int = Field(0, ge=0, lt=2**32)  # a campaign's evaluation seeds (search.campaign.evaluation_seed) are uint32
    size: int = Field(384, ge=64, le=MAX_SIZE)
    client: str | None = Field(None, max_length=64, pattern=r"^[A-Za-z0-9_-]+$")
    seq: int = Field(0, ge=0, lt=2**53)


class Plays:
    """The latest play ``seq`` of each page (``client``) and environment: an older play still waiting is superseded."""

    def __init__(self) -> None:
        self.latest: OrderedDict = OrderedDict()
        self.lock = threading.Lock()

    def arrived(self, env: str, client: str | None, seq: int) -> None:
        if client is None:
            return
        with self.lock:
            key = (env, client)
            self.latest[key] = max(seq, self.latest.get(key, seq))
            self.latest.move_to_end(key)
            while len(self.latest) > CLIENTS_KEPT:
                self.latest.popitem(last=False)

    def superseded(self, env: str, client: str | None, seq: int) -> bool:
        with self.lock:
            return client is not None and self.latest.get((env, client), seq) > seq


Size = Annotated[int, Query(ge=32, le=MAX_SIZE)]
LatentText = Annotated[str | None, Query(max_length=4096)]
WorldIndex = Annotated[int | None, Query(ge=0)]


def resolve(env: EnvSession, world: int | None, z: list[float] | None, superseded=lambda: False) -> tuple[Any, dict]:
    """(the world, where it came from) of a stored world's index or a latent (exactly one)."""
    if (world is None) == (z is None):
        raise WorldagentError("give either world=I (a stored world) or z=a,b,... (a latent).")
    if world is not None:
        return env.stored_world(world), env.world_summary(world)
    latent = check_latent(env, z)
    return env.decode(latent, superseded), {"latent": latent.tolist()}


def make_app(session: Session, token: str | None = None) -> FastAPI:
    """The explorer over ``session``; with ``token``, every request must carry it."""
    app = FastAPI(title="worldagent explore", docs_url=None, redoc_url=None, openapi_url=None)
    install_errors(app)
    install_guard(app, token)

    def env_session(env: str) -> EnvSession:
        try:
            return session.env(env)
        except KeyError:
            raise HTTPException(404, f"no environment {env!r} in this run; use one of: {', '.join(session.envs)}.") from None

    Env = Annotated[EnvSession, Depends(env_session)]
    add_page(app)
    add_views(app, session, Env)
    add_world_actions(app, Env)
    return app


def add_page(app: FastAPI) -> None:
    """The page and its assets, looked up by exact name in the package's ``static/`` folder."""

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(STATIC / "index.html", media_type="text/html")

    @app.get("/static/{name}", include_in_schema=False)
    def asset(name: str) -> FileResponse:
        known = {p.name: p for p in STATIC.iterdir() if p.is_file()}
        if name not in known:  # only the package's own files, by exact name: no path ever reaches the disk
            raise HTTPException(404, f"no asset {name!r}.")
        return FileResponse(known[name])


def add_views(app: FastAPI, session: Session, Env: Any) -> None:
    """What the map, world, atlas and failures views read."""

    @app.get("/api/run")
    def run_info() -> dict:
        return session.describe()

    @app.get("/api/{env}/map")
    def world_map(env: Env) -> Response:
        return plain_json(env.map_data())

    @app.get("/api/{env}/world/{index}.png")
    def world_picture(env: Env, index: int, size: Size = 384) -> Response:
        return png(env.stored_picture(index, size))

    @app.get("/api/{env}/world/{index}")
    def world_info(env: Env, index: int) -> dict:
        return env.world_summary(index)

    @app.get("/api/{env}/decode.png")
    def decode_picture(env: Env, z: Annotated[str, Query(max_length=4096)], size: Size = 384) -> Response:
        return png(env.picture(env.decode(check_latent(env, parse_latent(z))), size))

    @app.get("/api/{env}/failures")
    def failures(
        env: Env,
        event: Annotated[str | None, Query(max_length=200)] = None,
        by: Literal["likelihood", "severity"] = "likelihood",
        limit: Annotated[int, Query(ge=1, le=MAX_FAILURES)] = 50,
    ) -> dict:
        return env.failures(event, by, limit)

    @app.get("/api/{env}/ready")
    def ready(env: Env, agents: Annotated[str, Query(max_length=2000)] = "", episodes: Annotated[int, Query(ge=1, le=MAX_EPISODES)] = 8) -> dict:
        return env.cold([a for a in agents.split(",") if a], episodes)

    @app.get("/api/{env}/atlas")
    def atlas(env: Env, name: Annotated[str | None, Query(max_length=200)] = None) -> dict:
        return env.atlas(name)

    @app.get("/api/{env}/diff")
    def diff(
        env: Env,
        campaign: Annotated[str | None, Query(max_length=200)] = None,
        event: Annotated[str | None, Query(max_length=200)] = None,
        limit: Annotated[int, Query(ge=1, le=MAX_FAILURES)] = 50,
    ) -> dict:
        return env.diff(campaign, event, limit)


def add_world_actions(app: FastAPI, Env: Any) -> None:
    """Play a world, export it, save it."""
    plays = Plays()

    @app.post("/api/{env}/play")
    def play(env: Env, request: PlayRequest) -> Response:
        plays.arrived(env.env, request.client, request.seq)
        superseded = lambda: plays.superseded(env.env, request.client, request.seq)  # noqa: E731
        world, _ = resolve(env, request.world, request.z, superseded)
        played = env.play(world, request.agent, request.episodes, request.seed, request.size, superseded)
        source = {"world": request.world} if request.world is not None else {"z": request.z}
        return plain_json({**played, **source, "agent": request.agent, "seed": request.seed, "seq": request.seq})

    @app.get("/api/{env}/export.npz")
    def export_npz(env: Env, world: WorldIndex = None, z: LatentText = None) -> Response:
        found, source = resolve(env, world, None if z is None else parse_latent(z))
        data = dataset_bytes(one_world_dataset(env, found))
        return Response(data, media_type="application/octet-stream", headers=attachment(f"{env.env}-{export_name(source)}.npz"))

    @app.get("/api/{env}/export.json")
    def export_json(env: Env, world: WorldIndex = None, z: LatentText = None) -> Response:
        found, source = resolve(env, world, None if z is None else parse_latent(z))
        body = {"env": env.env, "source": source, "world": {k: v.tolist() for k, v in env.spec.world_to_arrays(found).items()}}
        return Response(json.dumps(body), media_type="application/json", headers=attachment(f"{env.env}-{export_name(source)}.json"))

    @app.post("/api/{env}/save")
    def save(env: Env, request: WorldRequest) -> dict:
        """Write the world as a one-world dataset to ``<run>/<env>/explorer/`` (a training pool, a fixture)."""
        found, source = resolve(env, request.world, request.z)
        folder = env.run.layout(env.env).dir / SAVED_FOLDER
        return {"saved": str(one_world_dataset(env, found).save(folder / f"{env.env}-{export_name(source)}.npz"))}


def plain_json(body: dict) -> Response:
    """JSON of plain lists and numbers, without FastAPI's per-element encoder (paths of thousands of points)."""
    return Response(json.dumps(body, separators=(",", ":")), media_type="application/json")


def png(data: bytes) -> Response:
    return Response(data, media_type="image/png", headers={"Cache-Control": "max-age=3600"})


def attachment(filename: str) -> dict:
    return {"Content-Disposition": f'attachment; filename="{filename}"'}


def export_name(source: dict) -> str:
    """``world-17``, or ``z-<hash>`` of a latent: a file name that says which world it is."""
    if "index" in source:
        return f"world-{source['index']}"
    return "z-" + hashlib.sha256(json.dumps(source["latent"]).encode()).hexdigest()[:10]


def one_world_dataset(env: EnvSession, world: Any):
    """The world as a one-world ``WorldDataset`` file (``WorldDataset.load`` reads it; seed -1: not generated)."""
    from worldagent.worlds.dataset import WorldDataset

    spec = env.spec
    batched = spec.world_from_arrays({k: v[None] for k, v in spec.world_to_arrays(world).items()})
    return WorldDataset(env.env, np.array([-1], np.int64), batched, np.asarray(spec.cells(batched), np.uint8), tuple(spec.cell_shape))


def dataset_bytes(dataset) -> bytes:
    """The bytes ``WorldDataset.save`` writes (it writes files only; a temporary one here, never in the run)."""
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        path = dataset.save(Path(folder) / "world.npz")
        return path.read_bytes()


def serve(session: Session, host: str = "127.0.0.1", port: int = 8765, token: str | None = None, echo=print) -> None:
    """Run the explorer until interrupted; a host other than the loopback one needs a token (one is made if not given)."""
    import uvicorn

    if host not in ("127.0.0.1", "localhost", "::1") and not token:
        token = secrets.token_urlsafe(18)
    app = make_app(session, token)
    echo(f"worldagent explore: {page_url(host, port, token)}  (Ctrl-C stops it)")
    if host in WILDCARD:
        echo(f"listening on every address of this machine ({host}): others open it by this machine's name or address, with the token.")
    uvicorn.run(app, host=host, port=port, log_level="warning")


WILDCARD = ("0.0.0.0", "::", "")


def page_url(host: str, port: int, token: str | None) -> str:
    """The URL to print: a wildcard address (0.0.0.0, ::) is no address a browser can open, so the machine's name."""
    name = socket.gethostname() if host in WILDCARD else host
    shown = f"[{name}]" if ":" in name else name
    return f"http://{shown}:{port}/" + (f"?token={token}" if token else "")
