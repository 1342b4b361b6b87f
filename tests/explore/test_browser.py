"""The explorer in a real browser (Playwright driving Debian's chromium): ``pytest -m browser``.

Loads the page with no console errors, opens a world from the map, moves a latent slider and
sees the world redraw, presses play and sees the animation advance, opens a world from an atlas
cell and from the failures table, exports a world that loads back as a ``WorldDataset``, and
reopens a latent with its agent from the page's link in a fresh page. Every view names what it
shows in text (axes, colour bars, legends); a world opened after a play shows none of the earlier
world's numbers, even when that play answers late; quick slider moves end in the latest world's
picture and episodes within twice one play's time (plays slowed to ``PLAY_DELAY`` s each).

By default it runs over the toy run of ``conftest.py``. ``WORLDAGENT_EXPLORER_RUN=runs/quick``
(and ``WORLDAGENT_EXPLORER_ENV=racing``) runs it over a real run instead;
``WORLDAGENT_EXPLORER_SHOTS=docs/images`` saves a screenshot of each view there (the README's).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import threading
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.browser

CHROMIUM = os.environ.get("WORLDAGENT_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
WAIT_MS = int(os.environ.get("WORLDAGENT_EXPLORER_WAIT_MS", 120_000))  # a real run's first play compiles its agent
PLAY_DELAY = 1.0  # s added to every play by ``slow_plays``: a busy machine's harvest play


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@contextlib.contextmanager
def serving(run_dir):
    """The explorer serving ``run_dir`` on a free local port, in a thread; yields its URL."""
    import uvicorn

    from worldagent.explore.server import make_app
    from worldagent.explore.session import Session

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(make_app(Session.open(run_dir)), host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    assert server.started, "the explorer did not start within 30 s"
    try:
        yield f"http://127.0.0.1:{port}/"
    finally:
        server.should_exit = True
        thread.join(timeout=10)


@pytest.fixture(scope="module")
def explorer_url(request):
    """The explorer serving the toy run (or ``WORLDAGENT_EXPLORER_RUN``) on a free local port, in a thread."""
    if not os.environ.get("WORLDAGENT_EXPLORER_RUN"):
        request.getfixturevalue("toy_spec")  # registered while this file's tests run
    run_dir = os.environ.get("WORLDAGENT_EXPLORER_RUN") or request.getfixturevalue("toy_run")
    with serving(run_dir) as url:
        yield url


@pytest.fixture(scope="module")
def diff_url(toy_spec, toy2_spec, diff_toy_run):
    """The explorer serving ``diff_toy_run``: ``toy`` with two diff campaigns, ``toy2`` with none."""
    with serving(diff_toy_run) as url:
        yield url


@pytest.fixture(scope="module")
def browser():
    playwright = pytest.importorskip("playwright.sync_api")
    if not Path(CHROMIUM).exists() and not shutil.which("chromium"):
        pytest.fail(f"no chromium at {CHROMIUM}; install it (`apt-get install -y chromium`) or set WORLDAGENT_CHROMIUM.")
    with playwright.sync_playwright() as p:
        launched = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield launched
        launched.close()


@contextlib.contextmanager
def opened(browser, url: str, viewport: tuple[int, int] = (1400, 900)):
    """A fresh page on ``url`` at ``viewport`` (width, height), failing the test on any console error or uncaught exception."""
    page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
    errors: list[str] = []
    page.on("console", lambda message: errors.append(message.text) if message.type == "error" else None)
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(url)
    page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    yield page
    page.close()
    assert not errors, f"console errors: {errors}"


@pytest.fixture
def page(browser, explorer_url):
    """A fresh page on the explorer (``opened``)."""
    env = os.environ.get("WORLDAGENT_EXPLORER_ENV", "")
    with opened(browser, explorer_url + (f"#env={env}" if env else "")) as page:
        yield page


@pytest.fixture
def diff_page(browser, diff_url):
    """A fresh page on the explorer over ``diff_toy_run``."""
    with opened(browser, diff_url) as page:
        yield page


def shot(page, name: str) -> None:
    folder = os.environ.get("WORLDAGENT_EXPLORER_SHOTS")
    if folder:
        page.screenshot(path=str(Path(folder) / f"explorer-{name}.png"))


def click_canvas(page, selector: str, x: float, y: float) -> None:
    """Click at (x, y) pixels of a canvas as a user would (through the mouse, not a synthetic event)."""
    box = page.locator(selector).bounding_box()
    page.mouse.click(box["x"] + x, box["y"] + y)


def open_world_from_map(page, index: int) -> tuple[float, float]:
    """Hover world ``index``'s dot, then click it; returns where (stacked dots: the first of them opens)."""
    x, y = page.evaluate(f"explorer.state.screen[{index}]")
    box = page.locator("#map-canvas").bounding_box()
    page.mouse.move(box["x"] + x, box["y"] + y)
    page.wait_for_selector("#map-hover:not([hidden])")
    page.wait_for_function("document.querySelector('#map-hover-img').complete")
    shot(page, "map")
    click_canvas(page, "#map-canvas", x, y)
    page.wait_for_selector("#world-img[data-loaded='1']", timeout=WAIT_MS)
    return x, y


def test_map_world_sliders_and_play(page):
    points = int(page.get_attribute("#map-canvas", "data-points"))
    assert points > 0
    x, y = open_world_from_map(page, points // 2)
    opened = int(page.text_content("#world-title").split()[1])
    ox, oy = page.evaluate(f"explorer.state.screen[{opened}]")
    assert abs(ox - x) < 3 and abs(oy - y) < 3  # the world under the pointer (dots overlap; a click lands on whole pixels)
    assert f"/world/{opened}.png" in page.get_attribute("#world-img", "data-src")

    slider = page.locator("#sliders input").first
    slider.focus()
    for _ in range(8):
        page.keyboard.press("ArrowRight")
    page.wait_for_function("(document.querySelector('#world-img').dataset.src || '').includes('/decode.png?z=')", timeout=WAIT_MS)
    page.wait_for_selector("#world-img[data-loaded='1']", timeout=WAIT_MS)
    assert "G(z)" in page.text_content("#world-title")
    page.click("button[data-view='map']")
    marker = [float(v) for v in page.get_attribute("#map-canvas", "data-marker").split(",")]
    assert marker != [x, y]  # the map marks where the sliders moved the world to
    page.click("button[data-view='world']")

    agents = page.eval_on_selector_all("#agent2 option", "options => options.map(o => o.value)")
    page.select_option("#agent2", agents[-1])
    page.click("#play")
    page.wait_for_function("Number(document.querySelector('#world-canvas').dataset.frame) > 0", timeout=WAIT_MS)
    first = int(page.get_attribute("#world-canvas", "data-frame"))
    page.wait_for_function(
        f"Number(document.querySelector('#world-canvas').dataset.frame) > {first} || "
        "document.querySelector('#frame').textContent === document.querySelector('#frames').textContent",
        timeout=WAIT_MS,
    )
    page.wait_for_function("document.querySelector('#frame').textContent === document.querySelector('#frames').textContent", timeout=WAIT_MS)
    if page.evaluate("explorer.state.run.envs.find(e => e.name === explorer.state.env).animates"):
        painted = page.evaluate(
            "(() => { const c = document.querySelector('#world-canvas'); const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
            " let n = 0; for (let i = 3; i < d.length; i += 4) n += d[i] > 0; return n; })()"
        )
        assert painted > 50  # trails and agents were drawn over the world
        check_marks(page)
    else:  # no Pictures.locate: the env's own picture of the episodes replaces the world's
        assert page.get_attribute("#world-img", "src").startswith("data:image/png;base64,")
    assert page.locator("#metrics-1 tr").count() > 1 and page.locator("#metrics-2 tr").count() > 1
    shot(page, "world")


def check_marks(page) -> None:
    """The env's marks (``Pictures.marks``: the toy's goal, harvest's apples and beams) drawn frame by frame."""
    marks = page.evaluate("explorer.state.players[0].marks")
    if not marks:
        assert page.get_attribute("#world-canvas", "data-marks") == "0"
        return
    shown = page.evaluate(
        "(() => { const r = explorer.state.players[0]; explorer.drawFrame(0, r, 0);"
        " const c = document.querySelector('#world-canvas'); const counts = {};"
        " r.episodes.forEach(e => Object.entries(e.marks).forEach(([k, ch]) => (ch[0] && ch[0][0] === 0 ? ch[0][1] : []).forEach(xy => { counts[xy] = (counts[xy] || 0) + 1; })));"
        " const full = Object.keys(counts).find(k => counts[k] === r.episodes.length);"
        " const [x, y] = full.split(',').map(v => Math.floor(Number(v) * c.width / r.size));"
        " return { drawn: Number(c.dataset.marks), points: Object.keys(counts).length, pixel: [...c.getContext('2d').getImageData(x, y, 1, 1).data] }; })()"
    )
    assert shown["drawn"] == shown["points"] > 0  # every mark there at the start, once
    kind = next(iter(marks))
    colour = [int(marks[kind]["colour"][i : i + 2], 16) for i in (1, 3, 5)]
    if len(marks) == 1:  # one kind: the pixel under a mark every episode shows is the mark's colour
        assert shown["pixel"] == [*colour, 255]
    last = int(page.text_content("#frames"))
    page.evaluate(f"explorer.drawFrame(0, explorer.state.players[0], {last})")
    ended = page.evaluate(
        "explorer.state.players[0].episodes.map(e => Object.values(e.marks).flat().map(c => c[1].length - c[2].length).reduce((a, b) => a + b, 0))"
    )
    assert int(page.get_attribute("#world-canvas", "data-marks")) <= sum(ended)  # what is left at the end (episodes sharing a place count once)


def test_an_atlas_cell_opens_its_world(page):
    page.click("button[data-view='atlas']")
    if not page.evaluate("explorer.state.run.envs.find(e => e.name === explorer.state.env).atlases.length"):
        page.wait_for_function("document.querySelector('#atlas-title').textContent.includes('no atlas')")
        pytest.skip("this run's store holds no atlas (the page says so)")
    page.wait_for_function("Number(document.querySelector('#atlas-canvas').dataset.cells) > 0", timeout=WAIT_MS)
    shot(page, "atlas")
    cell = page.evaluate("explorer.state.atlas.cells[0]")
    cols, rows = page.evaluate("explorer.state.atlas.size")
    box = page.locator("#atlas-canvas").bounding_box()
    x = (cell["x"] + 0.5) * box["width"] / cols
    y = (rows - cell["y"] - 0.5) * box["height"] / rows
    click_canvas(page, "#atlas-canvas", x, y)
    page.wait_for_selector("#world-img[data-loaded='1']", timeout=WAIT_MS)
    assert page.text_content("#world-title").startswith(f"world {cell['world']} ")


def test_a_failure_opens_and_exports(page, browser, tmp_path):
    from worldagent.worlds.dataset import WorldDataset

    page.click("button[data-view='failures']")
    page.wait_for_selector("#failures-table img", timeout=WAIT_MS)
    page.wait_for_function("[...document.querySelectorAll('#failures-table img')].slice(0, 12).every(i => i.naturalWidth > 0)", timeout=WAIT_MS)
    shot(page, "failures")
    found = page.evaluate("fetch(`/api/${explorer.state.env}/failures?limit=1`).then(r => r.json())")
    assert f"{found['failing']} of {found['worlds']} stored evaluations fail" in text(page, "#failures-summary")
    assert f"{found['distinct']} distinct worlds (repaired worlds, not latents)" in text(page, "#failures-summary")
    first = page.locator("#failures-table img").first
    index = int(first.get_attribute("data-world"))
    first.click()
    page.wait_for_selector("#world-img[data-loaded='1']", timeout=WAIT_MS)
    assert page.text_content("#world-title").startswith(f"world {index} ")
    with page.expect_download(timeout=WAIT_MS) as download:
        page.click("#export-npz")
    path = tmp_path / "world.npz"
    download.value.save_as(path)
    assert len(WorldDataset.load(path)) == 1
    link = page.get_attribute("#permalink", "href")
    assert f"w={index}" in link
    agent = page.eval_on_selector_all("#agent option", "options => options.map(o => o.value)")[-1]
    page.select_option("#agent", agent)  # the link follows the agents chosen
    page.evaluate("explorer.openLatent([...explorer.state.z].map((v, i) => i === 0 ? 0.5 : v))")
    link = page.get_attribute("#permalink", "href")
    assert "z=0.500%2C" in link and f"agent={agent.replace('/', '%2F')}" in link
    reopened = browser.new_page()  # a fresh page: only the link carries the state
    reopened.goto(link)
    reopened.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    reopened.wait_for_selector("#world-img[data-loaded='1']", timeout=WAIT_MS)
    assert reopened.input_value("#agent") == agent and "G(z)" in reopened.text_content("#world-title")
    assert reopened.input_value("#sliders input >> nth=0") == "0.5"
    reopened.close()


@pytest.fixture
def slow_plays(monkeypatch):
    """Every play's replay takes ``PLAY_DELAY`` s longer (the server runs in this process); yields when each replay ran."""
    import worldagent.explore.session as explorer_session

    ran: list[float] = []
    replay = explorer_session.replay_marked

    def slow(*args, **kwargs):
        time.sleep(PLAY_DELAY)
        ran.append(time.monotonic())
        return replay(*args, **kwargs)

    monkeypatch.setattr(explorer_session, "replay_marked", slow)
    return ran


def open_world(page, index: int) -> None:
    page.evaluate(f"explorer.openWorld({index})")
    page.wait_for_function(f"document.querySelector('#world-title').textContent.startsWith('world {index} ')", timeout=WAIT_MS)
    page.wait_for_selector("#world-img[data-loaded='1']", timeout=WAIT_MS)


PLAYED = "explorer.state.players[0] !== null && document.querySelector('#metrics-1').rows.length > 1"


def test_a_world_opened_after_a_play_shows_none_of_its_numbers(page, slow_plays):
    agents = page.eval_on_selector_all("#agent option", "options => options.map(o => o.value)")
    open_world(page, 0)
    page.select_option("#agent2", agents[-1])
    page.click("#play")
    page.wait_for_function(PLAYED, timeout=WAIT_MS)
    assert page.text_content("#frames") != "0"
    page.click("#play")  # a second play of world 0, still running when world 1 opens
    page.wait_for_function(
        "document.querySelector('#status').textContent.includes('playing') || document.querySelector('#status').textContent.includes('compiling')"
    )
    open_world(page, 1)
    page.wait_for_timeout(int(2.5 * PLAY_DELAY * 1000))  # both of its answers have come back by now
    assert page.evaluate("explorer.state.players") == [None, None]
    assert page.evaluate("[...document.querySelectorAll('#metrics-1 tr, #metrics-2 tr, #play-legend .row')].length") == 0
    assert page.text_content("#frame") == page.text_content("#frames") == "0"
    assert page.evaluate("explorer.state.stats.dropped") >= 1
    page.click("#play")
    page.wait_for_function(PLAYED, timeout=WAIT_MS)
    assert page.evaluate("explorer.state.players[0].world") == 1  # what is shown is world 1's


def test_quick_slider_moves_end_in_the_latest_world_within_twice_one_play(page, slow_plays):
    open_world(page, 0)
    started = time.monotonic()
    page.click("#play")
    page.wait_for_function(PLAYED, timeout=WAIT_MS)
    one_play = time.monotonic() - started
    replays = len(slow_plays)
    slider = page.locator("#sliders input").first
    before = float(slider.input_value())
    slider.focus()
    for _ in range(8):  # each move is its own world; the first replays while the others come
        page.keyboard.press("ArrowRight")
        page.wait_for_timeout(100)
    moved = time.monotonic()
    latest = (
        "(() => { const r = explorer.state.players[0], img = document.querySelector('#world-img');"
        " return r !== null && JSON.stringify(r.z) === JSON.stringify(explorer.state.z)"
        " && img.dataset.loaded === '1' && (img.dataset.src || '').includes('/decode.png?z=' + explorer.state.z.map(v => v.toFixed(3)).join(',')); })()"
    )
    try:
        page.wait_for_function(latest, timeout=max(WAIT_MS, 20_000))
    except Exception:  # playwright's TimeoutError
        pytest.fail("the page never showed the latest world's episodes: a stale play answered last")
    took = time.monotonic() - moved
    assert took <= 2 * one_play, f"the latest world's episodes after {took:.2f} s; one play takes {one_play:.2f} s"
    assert len(slow_plays) - replays <= 2  # superseded plays were never replayed
    assert float(slider.input_value()) - before == pytest.approx(8 * 0.05, abs=0.051)  # every move landed (the slider snaps to its 0.05 steps)


def text(page, selector: str) -> str:
    return page.text_content(selector) or ""


def test_every_view_names_what_it_shows(page):
    info = page.evaluate("explorer.state.run.envs.find(e => e.name === explorer.state.env)")
    metric = page.evaluate("explorer.state.metric")
    assert "principal axis 1" in text(page, "#map-xlabel") and "principal axis 2" in text(page, "#map-ylabel")
    assert page.locator("#map-xticks span").count() >= 2 and page.locator("#map-yticks span").count() >= 2
    colourbar = text(page, "#map-colourbar")
    assert metric in colourbar and "scale" in colourbar
    campaigns = page.evaluate("explorer.state.map.campaigns")
    assert all(name in text(page, "#map-campaigns") for name in campaigns)
    if info["failure"]:
        assert "fails" in text(page, "#map-failing-legend")
    share = page.evaluate("explorer.state.map.share")
    assert share and text(page, "#map-share") == share["line"] and "world's share of" in share["line"]  # the toy run has a random campaign
    page.select_option("#map-scale", "linear")
    assert page.get_attribute("#map-canvas", "data-scale") == "linear" and "linear" in text(page, "#map-colourbar")

    open_world(page, 0)
    legend = text(page, "#world-legend")
    key = info["key"]
    assert all(label in legend for label in key["colours"].values())
    assert all(style["label"] in legend for style in key["marks"].values())
    assert all(style["label"] in legend for style in key["outcomes"].values())
    assert all(name in legend for name in key["agents"])
    page.click("#play")
    page.wait_for_function(PLAYED, timeout=WAIT_MS)
    assert "episodes" in text(page, "#play-legend")

    if info["atlases"]:
        page.click("button[data-view='atlas']")
        page.wait_for_function("Number(document.querySelector('#atlas-canvas').dataset.cells) > 0", timeout=WAIT_MS)
        atlas = page.evaluate("explorer.state.atlas")
        assert atlas["descriptors"][0] in text(page, "#atlas-xlabel") and page.locator("#atlas-xticks span").count() >= 2
        assert atlas["metric"] in text(page, "#atlas-colourbar") and "worst" in text(page, "#atlas-colourbar")
        box = page.locator("#atlas-canvas").bounding_box()
        cell, (cols, rows) = atlas["cells"][0], atlas["size"]
        page.mouse.move(box["x"] + (cell["x"] + 0.5) * box["width"] / cols, box["y"] + (rows - cell["y"] - 0.5) * box["height"] / rows)
        page.wait_for_selector("#atlas-hover:not([hidden])")
        assert f"world {cell['world']}" in text(page, "#atlas-hover-text")

    if info["failure"]:
        page.click("button[data-view='failures']")
        page.wait_for_selector("#failures-table img", timeout=WAIT_MS)
        head = text(page, "#failures-table tr")
        assert "severity" in head and "there" in head  # each failing world's metrics, and its nearest passing world's
        assert "Severity:" in text(page, "#failures-help")


NEWCOMER_SCREEN = (1400, 950)  # a laptop's browser window: what a newcomer sees without scrolling


def test_a_newcomer_reads_what_metrics_and_campaigns_are_and_sees_the_episode_colours(browser, explorer_url):
    """Each metric's meaning (the spec's ``Metrics.meanings``) on the metric select and in the Map legend; each campaign
    in words beside its id (Map legend, Failures table); the per-episode colour key on screen after a play, unscrolled."""
    env = os.environ.get("WORLDAGENT_EXPLORER_ENV", "")
    with opened(browser, explorer_url + (f"#env={env}" if env else ""), NEWCOMER_SCREEN) as page:
        info = page.evaluate("explorer.state.run.envs.find(e => e.name === explorer.state.env)")
        metric = page.evaluate("explorer.state.metric")
        meaning = info["meanings"][metric]
        assert page.get_attribute("#map-metric", "title") == f"{metric}: {meaning}" and meaning in text(page, "#map-meaning")
        other = next(m for m in info["metrics"] if m != metric and m in info["meanings"])
        page.select_option("#map-metric", other)  # the tooltip and the legend follow the chosen metric
        assert info["meanings"][other] in page.get_attribute("#map-metric", "title") and info["meanings"][other] in text(page, "#map-meaning")
        legend = text(page, "#map-campaigns")
        for campaign in page.evaluate("explorer.state.map.campaigns"):
            words = info["campaign_words"][campaign]
            assert words != campaign and f"{words} {campaign}" in legend  # the words, then the id

        open_world(page, 0)
        page.fill("#episodes", page.get_attribute("#episodes", "max"))  # the longest key a play makes
        page.click("#play")
        page.wait_for_function(PLAYED, timeout=WAIT_MS)
        if len(info["key"]["agents"]) <= 1:  # one agent: a colour per episode (several: a colour per agent, in the env's key)
            assert page.locator("#play-legend .row").count() == int(page.input_value("#episodes"))
        rows = page.locator("#world-legend .row, #play-legend .row")
        assert page.evaluate("window.scrollY") == 0
        for k in range(rows.count()):  # every colour of the key, with its label, inside the window
            box = rows.nth(k).bounding_box()
            assert (
                box["x"] >= 0 and box["y"] >= 0 and box["x"] + box["width"] <= NEWCOMER_SCREEN[0] and box["y"] + box["height"] <= NEWCOMER_SCREEN[1]
            ), box

        if info["failure"]:
            page.click("button[data-view='failures']")
            page.wait_for_selector("#failures-table img", timeout=WAIT_MS)
            found = page.evaluate("explorer.state.run.envs.find(e => e.name === explorer.state.env).campaign_words")
            first = text(page, "#failures-table tr:nth-child(2) td.campaign")
            assert any(first == f"{words} {name}" for name, words in found.items()), first


def status_text(page) -> str:
    return text(page, "#status")


def test_a_superseded_play_leaves_no_status(page, slow_plays):
    """A play's status line belongs to its world and to the World view: a world opened or a view changed meanwhile
    takes it away, and the superseded play's answer writes none."""
    open_world(page, 0)
    page.click("#play")
    page.wait_for_function("/playing|compiling/.test(document.querySelector('#status').textContent)")
    open_world(page, 1)  # the play of world 0 is still running
    assert "play" not in status_text(page) and "compil" not in status_text(page)
    page.wait_for_timeout(int(1.5 * PLAY_DELAY * 1000))  # its answer has come back (and was dropped)
    assert page.evaluate("explorer.state.stats.dropped") >= 1
    assert "play" not in status_text(page), status_text(page)
    page.click("#play")
    page.wait_for_function("/playing|compiling/.test(document.querySelector('#status').textContent)")
    page.click("button[data-view='map']")  # the play goes on; the Map view says its own line
    worlds = page.evaluate("explorer.state.run.envs.find(e => e.name === explorer.state.env).worlds")
    assert status_text(page) == f"toy: {worlds} stored evaluations"
    page.wait_for_function(PLAYED, timeout=WAIT_MS)
    assert status_text(page) == f"toy: {worlds} stored evaluations"


SLOW_DIFF = "diff-homing-random-s1"  # its answers take DIFF_DELAY s: an earlier request for it answers after a later one
DIFF_DELAY = 0.8


@pytest.fixture
def slow_diffs(monkeypatch):
    """The Diff view's answers for ``SLOW_DIFF`` come ``DIFF_DELAY`` s late (the server runs in this process)."""
    import worldagent.explore.session as explorer_session

    view = explorer_session.diff_view

    def slow(session, campaign, event, limit):
        if campaign == SLOW_DIFF:
            time.sleep(DIFF_DELAY)
        return view(session, campaign, event, limit)

    monkeypatch.setattr(explorer_session, "diff_view", slow)


def shown_diff(page) -> dict:
    """What the Diff view shows: the select's campaign, the summary's, the answer kept, the table's worlds."""
    return page.evaluate(
        "({ chosen: document.querySelector('#diff-campaign').value, summary: document.querySelector('#diff-summary').textContent,"
        " kept: explorer.state.diff && explorer.state.diff.campaign,"
        " worlds: [...document.querySelectorAll('#diff-table tr td:nth-child(2) img')].map(i => Number(i.dataset.world)) })"
    )


def test_quick_diff_campaign_switches_end_on_the_chosen_campaigns_table(diff_page, slow_diffs):
    page = diff_page
    campaigns = page.evaluate("explorer.state.run.envs.find(e => e.name === 'toy').diffs")
    assert len(campaigns) == 2 and SLOW_DIFF == campaigns[1]
    page.click("button[data-view='diff']")
    page.wait_for_function(f"document.querySelector('#diff-summary').textContent.startsWith('{campaigns[0]}:')")
    for k in range(8):  # the last but one is the slow campaign: its answer comes after the last one's
        page.select_option("#diff-campaign", campaigns[(k + 1) % 2])
        page.wait_for_timeout(100)
    page.wait_for_timeout(int(1.5 * DIFF_DELAY * 1000))  # every answer is back
    shown = shown_diff(page)
    expected = page.evaluate(f"fetch('/api/toy/diff?limit=20&campaign={campaigns[0]}').then(r => r.json())")
    assert shown["chosen"] == shown["kept"] == campaigns[0] and shown["summary"].startswith(f"{campaigns[0]}: {expected['regressed']} of ")
    assert shown["worlds"] == [row["index"] for row in expected["rows"]] and shown["worlds"]
    assert "A: scripted homing, B: scripted random" in shown["summary"]  # A and B named


def test_switching_env_on_the_diff_view_leaves_none_of_its_table(diff_page, slow_diffs):
    page = diff_page
    page.click("button[data-view='diff']")
    page.wait_for_selector("#diff-table img")
    page.select_option("#diff-campaign", SLOW_DIFF)  # still on its way when the env changes
    page.select_option("#env", "toy2")
    page.wait_for_function("explorer.state.env === 'toy2' && explorer.state.map !== null && explorer.state.view === 'map'")
    page.wait_for_timeout(int(1.5 * DIFF_DELAY * 1000))  # toy's late answer is back
    shown = shown_diff(page)
    assert shown == {"chosen": "", "summary": "", "kept": None, "worlds": []}
    assert page.is_hidden("#view-diff") and page.is_hidden("#diff-tab") and page.is_visible("#view-map")  # toy2 has no diff
    assert status_text(page).startswith("toy2: ")
    page.select_option("#env", "toy")
    page.wait_for_function("explorer.state.env === 'toy' && explorer.state.map !== null")
    assert page.is_visible("#diff-tab")


def test_a_diff_written_while_serving_shows_after_a_reload(browser, toy_spec, fresh_toy_run, add_diff):
    """`worldagent diff --out` into a run the explorer serves: a reload shows its Diff tab, campaign and A and B (no restart)."""
    with serving(fresh_toy_run) as url, opened(browser, url) as page:
        assert page.is_hidden("#diff-tab")  # no diff yet
        add_diff(toy_spec, fresh_toy_run, {"diff-late-s0": (("homing", "random"), 2)})
        page.reload()
        page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
        assert page.is_visible("#diff-tab")
        page.click("button[data-view='diff']")
        page.wait_for_function("document.querySelector('#diff-summary').textContent.startsWith('diff-late-s0:')")
        assert "A: scripted homing, B: scripted random" in page.text_content("#diff-summary")
        assert page.query_selector_all("#diff-table img")  # the regressed worlds' pictures
