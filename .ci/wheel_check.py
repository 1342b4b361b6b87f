#!/usr/bin/env python3
"""Install worldagent as its users will and run it there: a file missing from the package fails.

Copies the files git sees in the checkout (tracked or not ignored: no stale build output, whose old
SOURCES.txt setuptools would read and so ship a file pyproject no longer declares), builds the sdist
and, from it, the wheel there (``python -m build``), checks that the wheel holds every one of those
files under src/worldagent, installs the wheel into a fresh virtualenv in a temporary folder outside
the checkout, and from there (so ``import worldagent`` cannot come from src/) runs
``worldagent --version`` against the one version source, ``worldagent check racing``,
``worldagent reproduce --preset tiny --env racing`` and a request to ``worldagent explore`` over that run
(its page, the page's scripts and styles, and two API answers). Prints each step's time; exits 1 with
the failing step's message and the end of its log.

Usage (from any folder; needs ``build``, which the test extra installs):
    python .ci/wheel_check.py [--keep]
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import json
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "worldagent"
ENV = "racing"
SERVER_START_S = 180  # the explorer loads the run (stores, generator, agents) before it answers
LOG_TAIL = 40


class CheckFailed(Exception):
    """A step failed; its message says what and, where it can, the fix."""


def source_version(root: Path) -> str:
    """The version the package declares: ``__version__`` in src/worldagent/__init__.py (pyproject reads it there)."""
    tree = ast.parse((root / "src" / PACKAGE / "__init__.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__version__" for t in node.targets):
            return ast.literal_eval(node.value)
    raise CheckFailed(f"src/{PACKAGE}/__init__.py sets no __version__: it is the package's one version source.")


def source_files(root: Path) -> list[str]:
    """The checkout's files as git sees them (tracked, or untracked and not ignored), relative paths that exist."""
    command = ["git", "-C", str(root), "ls-files", "--cached", "--others", "--exclude-standard"]
    try:
        out = subprocess.run(command, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as error:
        raise CheckFailed(f"cannot list the checkout's files with git ({error}); run this from a git clone.") from None
    return sorted({line for line in out.splitlines() if line and (root / line).is_file()})


def package_files(sources: list[str]) -> set[str]:
    """The files under src/worldagent among ``sources``, as the wheel names them (``worldagent/...``)."""
    return {path.removeprefix("src/") for path in sources if path.startswith(f"src/{PACKAGE}/")}


def copy_files(root: Path, sources: list[str], dest: Path) -> None:
    for path in sources:
        (dest / path).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / path, dest / path)


def missing_from_wheel(wheel: Path, expected: set[str]) -> list[str]:
    """The expected files the wheel does not hold, sorted."""
    with zipfile.ZipFile(wheel) as archive:
        return sorted(expected - set(archive.namelist()))


def missing_message(missing: list[str]) -> str:
    """One message naming what the wheel lacks and where to declare it."""
    shown = ", ".join(missing[:8]) + (f" and {len(missing) - 8} more" if len(missing) > 8 else "")
    return (
        f"the wheel lacks {len(missing)} file(s) of the checkout's src/{PACKAGE}: {shown}. Data files go in "
        "[tool.setuptools.package-data] in pyproject.toml; a folder of modules needs an __init__.py."
    )


def free_port() -> int:
    """A TCP port on 127.0.0.1 nothing listens on now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def get(url: str, timeout: float = 60) -> tuple[int, bytes]:
    """(status, body) of a GET; an HTTP error's status is returned, not raised."""
    try:
        with urllib.request.urlopen(url, timeout=timeout) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


def page_assets(html: str) -> list[str]:
    """The local scripts and stylesheets a page loads (``src``/``href`` starting with /)."""
    return re.findall(r'<script[^>]*\bsrc="(/[^"]+)"', html) + re.findall(r'<link[^>]*\brel="stylesheet"[^>]*\bhref="(/[^"]+)"', html)


class Steps:
    """Runs the check's steps in a work folder, timing each and keeping each command's log there."""

    def __init__(self, work: Path):
        self.work = work
        self.times: dict[str, float] = {}

    def step(self, name: str, fn, *args):
        start = time.perf_counter()
        print(f"wheel check: {name} ...", flush=True)
        result = fn(*args)
        self.times[name] = time.perf_counter() - start
        print(f"wheel check: {name}: done in {self.times[name]:.1f} s", flush=True)
        return result

    def run(self, name: str, command: list[str], env: dict | None = None) -> str:
        """Run ``command`` in the work folder with its output in ``<name>.log``; its stdout, or CheckFailed with the log's end."""
        log = self.work / f"{name}.log"
        with log.open("w") as handle:
            code = subprocess.run(command, cwd=self.work, env=env, stdout=handle, stderr=subprocess.STDOUT).returncode
        text = log.read_text()
        if code != 0:
            raise CheckFailed(f"`{' '.join(command)}` exited {code}; the end of its log:\n{tail(text)}")
        return text


def tail(text: str, lines: int = LOG_TAIL) -> str:
    return "\n".join(text.splitlines()[-lines:])


def user_env(venv: Path) -> dict:
    """The environment a user of the installed wheel has: its virtualenv first on PATH, nothing pointing at the checkout."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["VIRTUAL_ENV"] = str(venv)
    # The test suite's fast-compile flags (tests/conftest.py): what is checked here is that the package is
    # whole, not XLA's optimised code, and they shorten the tiny run's compiles. A caller's XLA_FLAGS win.
    env.setdefault("XLA_FLAGS", "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true")
    return env


def build(steps: Steps, sources: list[str]) -> Path:
    """The sources copied to work/source, then the sdist and the wheel from it (build's default) into work/dist; the wheel's path."""
    if importlib.util.find_spec("build") is None:
        raise CheckFailed("the `build` package is missing: pip install build (the test extra has it).")
    copy_files(ROOT, sources, steps.work / "source")
    steps.run("build", [sys.executable, "-m", "build", "--outdir", str(steps.work / "dist"), str(steps.work / "source")])
    wheels = sorted((steps.work / "dist").glob("*.whl"))
    if len(wheels) != 1 or not list((steps.work / "dist").glob("*.tar.gz")):
        raise CheckFailed(f"python -m build made {[p.name for p in (steps.work / 'dist').iterdir()]}; expected one sdist and one wheel.")
    return wheels[0]


def check_contents(wheel: Path, version: str, sources: list[str]) -> None:
    if not wheel.name.startswith(f"{PACKAGE}-{version}-"):
        raise CheckFailed(f"the wheel is {wheel.name}, but src/{PACKAGE}/__init__.py says {version}: pyproject must read the version from there.")
    missing = missing_from_wheel(wheel, package_files(sources))
    if missing:
        raise CheckFailed(missing_message(missing))


def install(steps: Steps, wheel: Path) -> Path:
    """A fresh virtualenv with the wheel and its dependencies (pip's cache reused; --no-compile: only what runs gets compiled)."""
    venv = steps.work / "venv"
    steps.run("venv", [sys.executable, "-m", "venv", str(venv)])
    steps.run("install", [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", "--no-compile", str(wheel)])
    return venv


def check_import_location(steps: Steps, venv: Path, env: dict) -> None:
    out = steps.run("import", ["python", "-c", f"import {PACKAGE}; print({PACKAGE}.__file__)"], env=env)
    location = Path(out.strip().splitlines()[-1]).resolve()
    if not location.is_relative_to(venv.resolve()) or location.is_relative_to(ROOT):
        raise CheckFailed(f"`import {PACKAGE}` came from {location}, not from the wheel installed in {venv}.")


def check_version(steps: Steps, env: dict, version: str) -> None:
    printed = steps.run("version", [PACKAGE, "--version"], env=env).strip()
    if printed != f"{PACKAGE} {version}":
        raise CheckFailed(f"`{PACKAGE} --version` printed {printed!r}; src/{PACKAGE}/__init__.py says {version}.")


def reproduce(steps: Steps, env: dict) -> Path:
    run_dir = steps.work / "run"
    steps.run("reproduce", [PACKAGE, "reproduce", "--preset", "tiny", "--env", ENV, "--out", str(run_dir), "--quiet"], env=env)
    if not (run_dir / "report.html").is_file():
        raise CheckFailed(f"reproduce finished but wrote no {run_dir / 'report.html'}.")
    return run_dir


def wait_for(url: str, server: subprocess.Popen, log: Path) -> None:
    """Poll ``url`` until it answers 200; CheckFailed if the server exits or takes over SERVER_START_S."""
    deadline = time.monotonic() + SERVER_START_S
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise CheckFailed(f"`worldagent explore` exited {server.returncode} before answering; the end of its log:\n{tail(log.read_text())}")
        try:
            if get(url, timeout=5)[0] == 200:
                return
        except OSError:
            pass  # not listening yet
        time.sleep(0.5)
    raise CheckFailed(f"`worldagent explore` did not answer {url} within {SERVER_START_S} s; the end of its log:\n{tail(log.read_text())}")


def check_explorer_answers(base: str) -> None:
    """The page with every script and stylesheet it loads, the run's description and one env's map."""
    status, body = get(f"{base}/")
    html = body.decode()
    assets = page_assets(html)
    if status != 200 or not any(a.endswith(".js") for a in assets):
        raise CheckFailed(f"the explorer's page answered {status} with no script in it: its static files are not in the wheel.")
    for asset in assets:
        status, body = get(base + asset)
        if status != 200 or not body:
            raise CheckFailed(
                f"the explorer's page loads {asset}, which answered {status}: add it to the package data (worldagent.explore static/*)."
            )
    status, body = get(f"{base}/api/run")
    envs = [env["name"] for env in json.loads(body)["envs"]] if status == 200 else []
    if ENV not in envs:
        raise CheckFailed(f"/api/run answered {status} without {ENV!r} among its envs: {body[:300]!r}")
    status, body = get(f"{base}/api/{ENV}/map")
    if status != 200 or not json.loads(body):
        raise CheckFailed(f"/api/{ENV}/map answered {status}: {body[:300]!r}")


def explore(steps: Steps, env: dict, run_dir: Path) -> None:
    """Serve the run on a free local port, check its answers, stop the server."""
    port = free_port()
    log = steps.work / "explore.log"
    command = [PACKAGE, "explore", str(run_dir), "--host", "127.0.0.1", "--port", str(port), "--no-warm"]
    with log.open("w") as handle:
        server = subprocess.Popen(command, cwd=steps.work, env=env, stdout=handle, stderr=subprocess.STDOUT)
    try:
        base = f"http://127.0.0.1:{port}"
        wait_for(f"{base}/api/run", server, log)
        check_explorer_answers(base)
    finally:
        server.terminate()
        try:
            server.wait(timeout=20)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()


def check(work: Path) -> dict[str, float]:
    """Every step in ``work``; the seconds each took."""
    steps = Steps(work)
    version = source_version(ROOT)
    sources = source_files(ROOT)
    wheel = steps.step("build the sdist and the wheel", build, steps, sources)
    steps.step("wheel contents", check_contents, wheel, version, sources)
    venv = steps.step("fresh virtualenv with the wheel", install, steps, wheel)
    env = user_env(venv)
    steps.step("import location", check_import_location, steps, venv, env)
    steps.step("worldagent --version", check_version, steps, env, version)
    steps.step(f"worldagent check {ENV}", steps.run, f"check-{ENV}", [PACKAGE, "check", ENV, "--quiet"], env)
    run_dir = steps.step(f"worldagent reproduce --preset tiny --env {ENV}", reproduce, steps, env)
    steps.step("worldagent explore answers", explore, steps, env, run_dir)
    return steps.times


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder (wheel, virtualenv, run, logs) and print its path")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="worldagent-wheel-")).resolve()
    start = time.perf_counter()
    try:
        if work.is_relative_to(ROOT):
            raise CheckFailed(f"the temporary folder {work} is inside the checkout; set TMPDIR to a folder outside {ROOT}.")
        times = check(work)
    except CheckFailed as failure:
        print(f"wheel check FAILED: {failure}", file=sys.stderr)
        return 1
    finally:
        if args.keep:
            print(f"wheel check: kept {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)
    print(f"wheel check passed in {time.perf_counter() - start:.0f} s: " + ", ".join(f"{name} {s:.0f} s" for name, s in times.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
