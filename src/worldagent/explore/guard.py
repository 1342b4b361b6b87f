"""What every request to the explorer passes first: the guard (origin, token or loopback host, body size) and
the one-line JSON errors (``{"error": "<one line>"}``) every refusal and failure becomes.

See ``server``'s docstring for the rules; kept apart so the server reads as its routes.
"""

import secrets
from typing import Any
from urllib.parse import urlsplit

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from worldagent.errors import WorldagentError
from worldagent.explore.session import Superseded

TOKEN_HEADER = "x-worldagent-token"
TOKEN_COOKIE = "worldagent_token"
LOOPBACK = ("127.0.0.1", "localhost", "[::1]")
MAX_BODY = 64 * 1024  # bytes: the largest request the page sends (a 256-number latent) is a few kB


def one_line(text: Any) -> str:
    return " ".join(str(text).split())


def error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": one_line(message)}, status_code=status)


def install_errors(app: FastAPI) -> None:
    """Every error as ``{"error": "<one line>"}``: 400 for our refusals, 422 for malformed requests."""

    @app.exception_handler(WorldagentError)
    async def refused(request: Request, exc: WorldagentError) -> JSONResponse:
        return error(400, str(exc))

    @app.exception_handler(Superseded)
    async def superseded(request: Request, exc: Superseded) -> JSONResponse:
        return error(409, "superseded: a newer play from this page replaced this one before it started.")

    @app.exception_handler(RequestValidationError)
    async def malformed(request: Request, exc: RequestValidationError) -> JSONResponse:
        return error(422, validation_message(exc.errors()[0] if exc.errors() else {}))

    @app.exception_handler(Exception)
    async def crashed(request: Request, exc: Exception) -> JSONResponse:
        return error(500, f"the explorer failed on this request ({type(exc).__name__}: {exc}); the server keeps serving.")

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        return error(exc.status_code, exc.detail if isinstance(exc.detail, str) else "request refused")


def validation_message(first: dict) -> str:
    """One line for pydantic's first complaint: invalid JSON and unknown fields said plainly, else ``field: message``."""
    kind = first.get("type")
    where = ".".join(str(part) for part in first.get("loc", ()) if part != "body")
    if kind == "json_invalid":
        reason = (first.get("ctx") or {}).get("error", "not JSON")
        return f'the request body is not valid JSON ({reason} at character {where or 0}); send a JSON object, e.g. {{"world": 0}}.'
    if kind == "extra_forbidden":
        return f"unknown field {where!r}; send only the fields this request takes."
    message = first.get("msg", "invalid request")
    return f"{where}: {message}" if where else message


def body_refusal(request: Request) -> JSONResponse | None:
    """413 for a body over ``MAX_BODY`` bytes, 411 for one of unknown length (chunked): checked before it is read."""
    if request.method not in ("POST", "PUT", "PATCH"):
        return None
    length = request.headers.get("content-length")
    if length is None:
        if request.headers.get("transfer-encoding"):
            return error(411, "send the request body with a Content-Length header.")
        return None
    if not length.isdigit() or int(length) > MAX_BODY:
        return error(413, f"request body of {length} bytes refused; the explorer's requests are under {MAX_BODY // 1024} KiB.")
    return None


def install_guard(app: FastAPI, token: str | None) -> None:
    """Refuse requests from another site's page, without the token (when there is one), or naming a
    non-loopback host (when not)."""

    @app.middleware("http")
    async def guard(request: Request, call_next):
        origin = request.headers.get("origin")
        if origin and urlsplit(origin).netloc != request.headers.get("host"):  # another site's page, in the user's browser
            return error(403, f"cross-origin request from {origin!r} refused; open the explorer's own page.")
        refused = body_refusal(request)
        if refused is not None:
            return refused
        if token is None:
            host = host_name(request.headers.get("host", ""))
            if host not in LOOPBACK:
                return error(403, f"host {host!r} refused: the explorer answers 127.0.0.1 only; start it with --host and a token to serve others.")
            return await call_next(request)
        given = request.query_params.get("token") or request.headers.get(TOKEN_HEADER) or request.cookies.get(TOKEN_COOKIE) or ""
        if not secrets.compare_digest(given.encode(), token.encode()):
            return error(401, "missing or wrong token; open the URL `worldagent explore` printed (it carries ?token=...).")
        response = await call_next(request)
        if request.query_params.get("token"):
            response.set_cookie(TOKEN_COOKIE, token, httponly=True, samesite="strict")
        return response


def host_name(header: str) -> str:
    """The host of a ``Host`` header, without its port (``[::1]:8765`` -> ``[::1]``)."""
    return header.split("]")[0] + "]" if header.startswith("[") else header.rsplit(":", 1)[0]
