"""Viewer and report numbers (run by hand; needs Debian's chromium for the browser parts).

    PYTHONPATH=src python benchmarks/bench_view.py --folder /tmp/view-bench [--fits 30] [--figures docs/figures]

1. Builds ``--fits`` fit folders once (kept in ``--folder``; reruns reuse them): held-out chairs
   (evaluation seed set) scanned by the virtual scanner, each fitted with the ``smoke`` fit
   settings but meshes extracted at the default resolution (128, as the ``fast`` preset's), and
   written as ``jsrte fit`` writes them (fit.json, shape.ply, overlay.png).
2. ``jsrte view FIT``: seconds from starting the command to the server answering HTTP with the
   first fit's scene built (the command prints its URL only then), and to the first frame drawn
   in headless Chromium (the canvas shows the mesh's colour).
3. ``jsrte report FOLDER``: the file's size, and the seconds headless Chromium takes from
   navigating to it to the 3D view drawn.

With ``--figures DIR`` it also saves a screenshot of each (viewer.png, report.png) there.
"""

from __future__ import annotations

import argparse
import io
import os
import socket
import subprocess
import sys
import time
import urllib.request
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def build_fits(folder: Path, n: int) -> Path:
    """``folder/fits/<name>/`` for ``n`` virtual chair scans (kept between runs)."""
    from jsrte import presets
    from jsrte.experiments.scans import virtual_cases
    from jsrte.fit import fit
    from jsrte.fit.outputs import write_fit_outputs
    from jsrte.model.registry import resolve_model
    from jsrte.scans.io import load_scan

    fits = folder / "fits"
    todo = [i for i in range(n) if not (fits / f"chair_{i:03d}" / "fit.json").is_file()]
    if not todo:
        return fits
    presets.PRESETS["bench-view"] = replace(presets.SMOKE, name="bench-view",
                                            fit=replace(presets.SMOKE.fit, extract_resolution=128))
    model = resolve_model("chair")
    for i in todo:
        case = virtual_cases("chair", 1, folder / "scans", first=i)[0]
        started = time.perf_counter()
        result = fit(case.path, model=model, preset="bench-view")
        out = fits / case.name
        out.mkdir(parents=True, exist_ok=True)
        write_fit_outputs(result, out, query_points=load_scan(case.path).points, up=result.info.get("up"),
                          extra={"input": str(case.path.resolve())})
        print(f"fitted {case.name} in {time.perf_counter() - started:.1f} s", flush=True)
    return fits


def tree_cpu_seconds(root: int) -> float:
    """CPU seconds (user + system) used so far by process ``root`` and its descendants (Linux /proc).

    On this shared 2-core machine wall times stretch with the other jobs' load; CPU time does not,
    and is about what the wall time would be on an idle machine for a single-threaded start-up."""
    ticks = os.sysconf("SC_CLK_TCK")
    stats = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            stats[int(entry.name)] = (int(fields[1]), (int(fields[11]) + int(fields[12])) / ticks)
    tree, frontier = {root}, [root]
    while frontier:
        parent = frontier.pop()
        children = [pid for pid, (ppid, _) in stats.items() if ppid == parent and pid not in tree]
        tree.update(children)
        frontier += children
    return sum(stats[pid][1] for pid in tree if pid in stats)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def save_figure(png: bytes, path: Path, width: int) -> None:
    """A screenshot downscaled to ``width`` pixels and reduced to 256 colours (small for docs/)."""
    from PIL import Image

    image = Image.open(io.BytesIO(png)).convert("RGB")
    image.thumbnail((width, width))
    image.quantize(colors=256).save(path, optimize=True)
    print(f"saved {path} ({path.stat().st_size // 1024} KB)")


def measure_view(fit_folder: Path, figures: Path | None = None) -> dict[str, float]:
    """Seconds from starting ``jsrte view`` to HTTP with the scene built, and to the first frame drawn."""
    from jsrte.view.browser import HeadlessChromium, find_chromium, mesh_pixels

    port = free_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    started = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", "jsrte.cli", "view", str(fit_folder), "--port", str(port)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = process.stdout.readline()
        if "http://" not in line:
            raise SystemExit(f"jsrte view did not start: {line}{process.stderr.read()}")
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10) as response:
            response.read()
        served = time.perf_counter() - started
        numbers = {"view_served_s": served, "view_served_cpu_s": tree_cpu_seconds(process.pid)}
        if find_chromium():
            with HeadlessChromium(width=1000, height=700) as browser:
                browser.open(f"http://127.0.0.1:{port}/", until="document.querySelector('canvas')", timeout=60)
                while mesh_pixels(browser.screenshot())[0] < 500:
                    if time.perf_counter() - started > 60:
                        raise SystemExit("the viewer drew no mesh within 60 s")
                    time.sleep(0.1)
                numbers["view_first_frame_s"] = time.perf_counter() - started
                if figures is not None:
                    browser.evaluate("document.querySelectorAll('.mantine-Notification-closeButton')"
                                     ".forEach(b => b.click())")  # the 'software WebGL' notice
                    time.sleep(10.0)  # objects fade in over several (slow, software-drawn) frames
                    save_figure(browser.screenshot(), figures / "viewer.png", 900)
        return numbers
    finally:
        process.send_signal(2)
        process.wait(20)


def measure_report(fits: Path, folder: Path, figures: Path | None = None) -> dict[str, float]:
    """Size of ``jsrte report`` on the fits, seconds to write it and to draw it in headless Chromium."""
    from jsrte.view.browser import HeadlessChromium, find_chromium

    out = folder / "report.html"
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "jsrte.cli", "report", str(fits), "--out", str(out), "--overwrite"],
                   check=True, env=env)
    numbers = {"report_write_s": time.perf_counter() - started, "report_mb": out.stat().st_size / 1e6}
    if find_chromium():
        with HeadlessChromium(width=1200, height=1000) as browser:
            cpu = tree_cpu_seconds(browser.pid)
            numbers["report_open_s"] = browser.open(
                out.resolve().as_uri(), until="document.body.dataset.ready === '1' && "
                                               "document.querySelector('#plot canvas')", timeout=60)
            numbers["report_open_cpu_s"] = tree_cpu_seconds(browser.pid) - cpu
            numbers["report_js_errors"] = len(browser.errors())
            if figures is not None:
                time.sleep(2.0)
                save_figure(browser.screenshot(), figures / "report.png", 900)
    return numbers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--folder", type=Path, required=True)
    parser.add_argument("--fits", type=int, default=30)
    parser.add_argument("--figures", type=Path, help="Save viewer.png and report.png screenshots here.")
    args = parser.parse_args()
    fits = build_fits(args.folder, args.fits)
    first = sorted(p for p in fits.iterdir() if (p / "fit.json").is_file())[0]
    results = measure_view(first, args.figures) | measure_report(fits, args.folder, args.figures)
    for key, value in results.items():
        print(f"{key}: {value:.2f}")


if __name__ == "__main__":
    main()
