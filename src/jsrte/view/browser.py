"""Headless Chromium over the DevTools protocol: open a page, wait, screenshot it, and collect
the JavaScript errors it logged. Used by the tests and benchmarks of the viewer and the report.

Debian's ``chromium`` package is enough (``apt-get install chromium``); WebGL is drawn in
software (SwiftShader). The protocol is spoken over a websocket with the ``websockets``
package (a dependency of ``viser``).
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from jsrte.errors import JsrteError

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """Path of a Chromium (or Chrome) executable on PATH, or None."""
    return next((path for name in CHROMIUM_NAMES if (path := shutil.which(name))), None)


@dataclass
class PageErrors:
    """What a page logged as errors: uncaught exceptions, console.error calls, error log entries."""

    messages: list[str] = field(default_factory=list)


class HeadlessChromium:
    """One headless Chromium with one page, driven over the DevTools protocol.

    Use as a context manager; ``open`` a URL, ``evaluate`` JavaScript, ``screenshot``.
    """

    def __init__(self, *, width: int = 1200, height: int = 800, executable: str | None = None) -> None:
        self.width, self.height = width, height
        self.executable = executable or find_chromium()
        if self.executable is None:
            raise JsrteError("no chromium executable on PATH (apt-get install chromium)")
        self._next_id = 0
        self.events: list[dict[str, Any]] = []

    def __enter__(self) -> HeadlessChromium:
        self._profile = tempfile.TemporaryDirectory(prefix="jsrte-chromium-")
        args = [self.executable, "--headless", "--remote-debugging-port=0", f"--user-data-dir={self._profile.name}",
                f"--window-size={self.width},{self.height}", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                "--ignore-gpu-blocklist", "--no-first-run", "--no-default-browser-check", "--disable-extensions",
                "--hide-scrollbars", "--mute-audio", "about:blank"]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            args.insert(1, "--no-sandbox")  # Chromium refuses to run as root with its sandbox
        self._process = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            self._connect()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def pid(self) -> int:
        """The browser's process id (its renderer and GPU processes are its children)."""
        return self._process.pid

    def close(self) -> None:
        """Stop the browser and remove its profile."""
        socket = getattr(self, "_socket", None)
        if socket is not None:
            socket.close()
        if self._process.poll() is None:
            self._process.terminate()
            try:
                self._process.wait(10)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        self._profile.cleanup()

    def _connect(self, timeout: float = 30.0) -> None:
        from websockets.sync.client import connect

        port_file = Path(self._profile.name) / "DevToolsActivePort"
        deadline = time.monotonic() + timeout
        while not (port_file.is_file() and port_file.read_text().strip()):
            if self._process.poll() is not None or time.monotonic() > deadline:
                raise JsrteError("chromium did not start (no DevTools port)")
            time.sleep(0.05)
        port = int(port_file.read_text().split()[0])
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as response:
            pages = [t for t in json.loads(response.read()) if t.get("type") == "page"]
        self._socket = connect(pages[0]["webSocketDebuggerUrl"], max_size=None, open_timeout=10)
        for domain in ("Page", "Runtime", "Log"):
            self.call(f"{domain}.enable")
        self.call("Emulation.setDeviceMetricsOverride",
                  {"width": self.width, "height": self.height, "deviceScaleFactor": 1, "mobile": False})

    # -- protocol -------------------------------------------------------------------------------
    def call(self, method: str, params: dict | None = None, timeout: float = 60.0) -> dict[str, Any]:
        """Send one command and return its result; events arriving meanwhile are kept in ``events``."""
        self._next_id += 1
        self._socket.send(json.dumps({"id": self._next_id, "method": method, "params": params or {}}))
        deadline = time.monotonic() + timeout
        while True:
            message = json.loads(self._socket.recv(timeout=max(deadline - time.monotonic(), 0.01)))
            if message.get("id") == self._next_id:
                if "error" in message:
                    raise JsrteError(f"chromium: {method} failed: {message['error'].get('message')}")
                return message.get("result", {})
            if "method" in message:
                self.events.append(message)

    def evaluate(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page (awaited if it is a promise)."""
        result = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                "awaitPromise": True})
        return result.get("result", {}).get("value")

    def open(self, url: str, *, until: str = "document.readyState === 'complete'", timeout: float = 30.0) -> float:
        """Navigate to ``url`` and wait until the JavaScript ``until`` is true; returns the seconds taken."""
        started = time.monotonic()
        self.call("Page.navigate", {"url": url})
        self.wait_for(until, timeout=timeout, started=started)
        return time.monotonic() - started

    def wait_for(self, condition: str, *, timeout: float = 30.0, started: float | None = None) -> None:
        """Poll the JavaScript ``condition`` until it is true; ``JsrteError`` after ``timeout`` seconds."""
        started = time.monotonic() if started is None else started
        while not self.evaluate(f"Boolean({condition})"):
            if time.monotonic() - started > timeout:
                raise JsrteError(f"chromium: waited {timeout:.0f} s for {condition}")
            time.sleep(0.1)

    def screenshot(self) -> bytes:
        """PNG bytes of the page as drawn now."""
        return base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"})["data"])

    def rect(self, selector: str) -> tuple[int, int, int, int] | None:
        """(left, top, width, height) in CSS pixels of the first element matching ``selector``."""
        box = self.evaluate(f"(() => {{ const e = document.querySelector({json.dumps(selector)}); if (!e) return null;"
                            " const r = e.getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; })()")
        return None if box is None else tuple(int(round(v)) for v in box)

    def errors(self) -> list[str]:
        """Every error the page logged so far: uncaught exceptions, console.error, error log entries."""
        self.evaluate("0")  # flush the events sent so far
        found = []
        for event in self.events:
            method, params = event["method"], event.get("params", {})
            if method == "Runtime.exceptionThrown":
                details = params.get("exceptionDetails", {})
                found.append(details.get("exception", {}).get("description") or details.get("text", "exception"))
            elif method == "Runtime.consoleAPICalled" and params.get("type") == "error":
                found.append(" ".join(str(a.get("value", a.get("description", ""))) for a in params.get("args", [])))
            elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
                entry = params["entry"]
                found.append(f"{entry.get('source')}: {entry.get('text')} {entry.get('url', '')}".strip())
        return found


def mesh_pixels(png: bytes, box: tuple[int, int, int, int] | None = None) -> tuple[int, tuple[float, float] | None]:
    """Pixels showing the retrieved mesh's orange (any shade) in a screenshot, within ``box``
    (left, top, width, height; default the whole image): their count and their centroid (x, y)
    as fractions of the box (None when there are none)."""
    import io

    import numpy as np
    from PIL import Image

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int32)
    if box is not None:
        left, top, width, height = box
        rgb = rgb[top:top + height, left:left + width]
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    orange = (r > 90) & (g > 0.35 * r) & (g < 0.78 * r) & (b < 0.6 * g)
    ys, xs = np.nonzero(orange)
    if len(xs) == 0:
        return 0, None
    return len(xs), (float(xs.mean()) / rgb.shape[1], float(ys.mean()) / rgb.shape[0])
