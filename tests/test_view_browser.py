"""The report and the viewer in a real browser (Debian's chromium, headless, software WebGL):
a screenshot of each shows the retrieved mesh where it projects, and the page logs no JavaScript
error. Skipped without chromium (scripts/setup-test-extras.sh installs it when root)."""

import socket
import threading
import time

import pytest

from jsrte.view.browser import HeadlessChromium, find_chromium, mesh_pixels
from jsrte.view.loading import find_fits, load_items
from view_fixtures import make_batch, make_fit, make_scan

pytestmark = pytest.mark.skipif(find_chromium() is None,
                                reason="chromium is not installed (scripts/setup-test-extras.sh installs it as root)")


@pytest.fixture(scope="module")
def browser():
    with HeadlessChromium(width=1100, height=760) as chromium:
        yield chromium


def wait_for_mesh(browser, box, *, min_pixels, timeout=60.0):
    """Screenshots until the mesh's colour covers ``min_pixels`` of ``box``: (count, centroid, png)."""
    started = time.monotonic()
    while True:
        png = browser.screenshot()
        count, centre = mesh_pixels(png, box)
        if count >= min_pixels or time.monotonic() - started > timeout:
            return count, centre, png


def test_report_draws_the_mesh_and_logs_no_error(tmp_path, browser):
    from jsrte.view.report import write_report

    out = make_batch(tmp_path, 2)
    (out / "s1" / "shape.ply").write_text("broken")  # shown as missing; the page still works
    write_report(load_items(find_fits(out)), tmp_path / "report.html", title="two spheres")
    browser.open((tmp_path / "report.html").as_uri(), timeout=60,
                 until="document.body.dataset.ready === '1' && document.querySelector('#plot canvas')")
    box = browser.rect("#plot")
    count, centre, png = wait_for_mesh(browser, box, min_pixels=0.02 * box[2] * box[3])
    (tmp_path / "report.png").write_bytes(png)
    assert count >= 0.02 * box[2] * box[3], f"the mesh covers {count} pixels of the 3D view"
    assert 0.25 < centre[0] < 0.75 and 0.2 < centre[1] < 0.8  # where the camera looks: the object's centre
    assert browser.evaluate("document.querySelectorAll('#fits .problem').length") == 1
    browser.evaluate("document.getElementById('next').click()")  # the second fit: its mesh is missing
    time.sleep(1.0)
    assert mesh_pixels(browser.screenshot(), box)[0] < 0.002 * box[2] * box[3]
    assert browser.errors() == []


def test_viewer_draws_the_mesh_and_logs_no_error(tmp_path, browser):
    from jsrte.view.server import serve

    scan = make_scan(tmp_path / "scans", "chair")
    scan.with_suffix(".json").unlink()  # no true mesh drawn over the retrieved one (the floor: from fit.json's up)
    folder = make_fit(tmp_path / "fit", scan)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    stop, ready = threading.Event(), threading.Event()
    thread = threading.Thread(target=serve, args=(find_fits(folder),), daemon=True,
                              kwargs={"port": port, "say": lambda _: ready.set(), "warn": print, "stop": stop})
    thread.start()
    try:
        assert ready.wait(60)
        browser.open(f"http://127.0.0.1:{port}/", until="document.querySelector('canvas')", timeout=60)
        box = (0, 0, browser.width - 340, browser.height)  # the 3D view, left of the GUI panel
        count, centre, png = wait_for_mesh(browser, box, min_pixels=0.02 * box[2] * box[3])
        (tmp_path / "viewer.png").write_bytes(png)
        assert count >= 0.02 * box[2] * box[3], f"the mesh covers {count} pixels of the 3D view"
        assert 0.25 < centre[0] < 0.75 and 0.2 < centre[1] < 0.8
        assert browser.errors() == []
    finally:
        stop.set()
        thread.join(20)
