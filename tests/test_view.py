"""``sagfree view``: the groom page renders in a real headless browser (Debian's Chromium, WebGL by
SwiftShader) without console errors and offline, with the three states, the bodies, the colour bar,
legend toggles and picking by index; and the command line writes it."""
import io
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sagfree
from sagfree.cli import main
from sagfree.contract.result import failed_result
from sagfree.formulation.simulation import equilibrium
from sagfree.reports.view import RESOLUTION, write_view
from sagfree.scenes.npz import save_parameters, save_strands

CHROMIUM = Path("/usr/bin/chromium")
#: headless without a GPU: WebGL through SwiftShader; nothing in the background may reach the network
CHROMIUM_ARGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
                 "--disable-background-networking", "--disable-component-update", "--no-first-run",
                 "--disable-sync", "--disable-dev-shm-usage"]
SPHERE = "sphere:0,0,0,0.1"  # the head groom() roots its strands on
MISSING = 1  # the strand whose parameters are withheld


def sync_playwright_or_skip():
    """playwright's sync API; skip without it or without /usr/bin/chromium, except on CI (fail)."""
    missing = []
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        missing.append("playwright (pip install playwright)")
    if not CHROMIUM.exists():
        missing.append(f"Debian's chromium at {CHROMIUM} (apt-get install chromium)")
    if missing:
        message = "the browser test needs " + " and ".join(missing)
        if os.environ.get("CI"):
            pytest.fail(message + "; CI must run it")
        pytest.skip(message)
    return sync_playwright


def page_data(path: Path) -> dict:
    found = re.search(r'<script type="application/json" id="sagfree-data">(.*?)</script>', path.read_text(), re.S)
    return json.loads(found.group(1).replace("<\\/", "</"))


@pytest.fixture(scope="module")
def groom():
    strands = sagfree.scenes.groom(3, 20, seed=0)
    results = sagfree.optimize(strands, jobs=1, bodies=[SPHERE])
    assert all(r.status == "converged" for r in results)
    return strands, results


@pytest.fixture(scope="module")
def view(groom, tmp_path_factory):
    """The page of 3 strands on a sphere (strand MISSING without parameters), loaded in Chromium:
    (path, page, console messages, page errors, requests)."""
    sync_playwright = sync_playwright_or_skip()
    strands, results = groom
    parameters = [None if k == MISSING else r.p for k, r in enumerate(results)]
    status = ["failed" if k == MISSING else r.status for k, r in enumerate(results)]
    path = write_view(tmp_path_factory.mktemp("view") / "groom.html", strands, parameters, {"bodies": [SPHERE]},
                      status, title="three strands", jobs=1)
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1100, "height": 800})
        console, errors, requests = [], [], []
        page.on("console", lambda message: console.append((message.type, message.text)))
        page.on("pageerror", lambda error: errors.append(str(error)))
        page.on("request", lambda request: requests.append(request.url))
        page.goto(path.as_uri())
        page.wait_for_function("window.sagfreeView && window.sagfreeView.ready", timeout=60_000)
        yield path, page, console, errors, requests
        browser.close()


def plot_pixels(page) -> np.ndarray:
    from PIL import Image

    shot = page.locator("#plot").screenshot()
    return np.asarray(Image.open(io.BytesIO(shot)).convert("RGB"), dtype=float)


def test_page_is_self_contained(view):
    path, _, _, _, requests = view
    text = path.read_text()
    assert not re.search(r"<(script|link)\b[^>]*\b(src|href)\s*=\s*[\"']?\s*(https?:)?//", text, re.I)
    assert len(re.findall(r"<script\b", text)) == 3  # plotly.js, the data, the page's code: all inline
    assert requests == [path.as_uri()]  # the page asked for nothing else: no network


def test_page_renders_without_console_errors(view):
    _, page, console, errors, _ = view
    assert errors == []
    assert [text for kind, text in console if kind == "error"] == []
    assert page.evaluate("!!document.getElementById('plot')._fullLayout.scene._scene.glplot")
    pixels = plot_pixels(page)
    assert pixels.std() > 10  # not a blank canvas


def test_states_bodies_and_colour_bar(view, groom):
    _, page, _, _, _ = view
    traces = page.evaluate("window.sagfreeView.traces")
    full = page.evaluate("document.getElementById('plot')._fullData.map(t => [t.type, t.name, t.visible])")
    for state in ("groomed", "naive", "optimized", "failed", "picked"):
        assert full[traces[state]][0] == "scatter3d"
    assert full[traces["optimized"]][2] is True and "no parameters: 1 strand" in full[traces["failed"]][1]
    assert [full[k][0] for k in traces["bodies"]] == ["mesh3d"]
    # one trace per state: every strand in it, a gap after each
    strands = groom[0]
    x = page.evaluate(f"document.getElementById('plot').data[{traces['groomed']}].x")
    assert len(x) == sum(s.n_vertices + 1 for s in strands) and x.count(None) == len(strands)
    x = page.evaluate(f"document.getElementById('plot').data[{traces['optimized']}].x")
    assert len(x) == sum(s.n_vertices + 1 for k, s in enumerate(strands) if k != MISSING)
    title = page.evaluate("Array.from(document.querySelectorAll('.colorbar .cbtitle')).map(e => e.textContent)")
    assert len(title) == 1 and "bend stiffness multiplier" in title[0]


def test_legend_toggles_a_state_off_the_canvas(view):
    _, page, _, _, _ = view
    naive = page.evaluate("window.sagfreeView.traces.naive")
    toggle = page.locator(".legend .traces", has_text="naive static droop").locator(".legendtoggle")
    before = plot_pixels(page)
    toggle.click()
    page.wait_for_function(f"document.getElementById('plot')._fullData[{naive}].visible === 'legendonly'")
    page.wait_for_timeout(300)
    hidden = plot_pixels(page)
    toggle.click()
    page.wait_for_function(f"document.getElementById('plot')._fullData[{naive}].visible === true")
    # the WebGL canvas drew the naive droop: hiding it changes pixels outside the legend
    changed = np.abs(before - hidden).sum(axis=2) > 60
    changed[:250, :400] = False  # the legend's own entry greys out
    assert changed.sum() > 50


def test_picking_a_strand_by_index_highlights_it(view, groom):
    _, page, console, errors, _ = view
    strands, results = groom
    picked = page.evaluate("window.sagfreeView.traces.picked")
    for k in (2, MISSING):
        page.fill("#pick", str(k))
        page.press("#pick", "Enter")
        page.wait_for_function(f"document.getElementById('plot').data[{picked}].x.length === "
                               f"{strands[k].n_vertices}")
        data = page.evaluate(f"(t => [t.x, t.y, t.z])(document.getElementById('plot').data[{picked}])")
        if k == MISSING:  # no parameters: its groomed shape
            expected = strands[k].points
        else:  # its optimized static state
            expected = equilibrium(sagfree.Problem(strands[k], bodies=[SPHERE]), results[k].p).positions
        np.testing.assert_allclose(np.array(data).T, expected, rtol=0, atol=RESOLUTION)
        info = page.inner_text("#info")
        assert info.startswith(f"strand {k}:")
        if k == MISSING:
            assert "failed (no optimized state)" in info and "no parameters" in info
        else:
            shown = float(re.search(r"max bend multiplier ([0-9.]+)", info).group(1))
            top = results[k].physical["bend_modulus"].max() / strands[k].youngs_modulus
            assert "converged" in info and shown == pytest.approx(top, rel=1e-3)
    assert not page.evaluate("window.sagfreeView.pick(3)")  # out of range: said, nothing picked
    assert "indices run from 0 to 2" in page.inner_text("#info")
    # a click on a vertex picks its strand (plotly's click event: trace and point number)
    groomed = page.evaluate("window.sagfreeView.traces.groomed")
    point = strands[0].n_vertices + 1 + 4  # strand 1's vertex 4: after strand 0 and its gap
    page.evaluate(f"document.getElementById('plot').emit('plotly_click', "
                  f"{{points: [{{curveNumber: {groomed}, pointNumber: {point}}}]}})")
    assert page.inner_text("#info").startswith("strand 1:")
    assert errors == [] and [text for kind, text in console if kind == "error"] == []


def run_cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "sagfree.cli", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


def test_view_command_optimizes_and_writes_the_page(tmp_path):
    run = run_cli("view", "horizontal", "-o", "x.html", "--jobs", "1", "--quiet", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "wrote x.html" in run.stdout
    data = page_data(tmp_path / "x.html")
    assert data["counts"] == [30] and data["hasOptimized"] == [1] and data["status"] == ["converged"]
    assert 4.5 < data["maxMultiplier"][0] < 4.8  # the horizontal strand's root stiffening (DESIGN 8)
    assert data["naiveSag"][0] > 0.9 and data["optimizedSag"][0] < 1e-6


def test_view_command_with_parameters_file(tmp_path):
    run = run_cli("optimize", "horizontal", "-o", "p.npz", "--jobs", "1", "--quiet", "--stiffness", "strand",
                  cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    run = run_cli("view", "horizontal", "--params", "p.npz", "--jobs", "1", "--quiet", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    data = page_data(tmp_path / "horizontal.view.html")  # the default name, in the current directory
    assert "stiffness='strand'" in data["colourTitle"] and data["hasOptimized"] == [1]
    assert len(set(data["multiplier"])) == 1 and data["multiplier"][0] > 4  # one multiplier per strand


def test_view_command_refuses_bad_input(tmp_path, capsys):
    assert main(["view", str(tmp_path / "nothing.hair")]) == 2
    assert "sagfree view: error" in capsys.readouterr().err
    save_strands(tmp_path / "two.npz", [sagfree.scenes.horizontal(n=12)] * 2)
    save_parameters(tmp_path / "p.npz", [sagfree.scenes.horizontal(n=12)], [failed_result("asc", "none")],
                    "asc", {})
    assert main(["view", str(tmp_path / "two.npz"), "--params", str(tmp_path / "p.npz"), "--quiet"]) == 2
    assert "parameters are for 1 strands" in capsys.readouterr().err
