"""A screenshot of a view, taken by headless Chromium (Debian's `chromium` package) driven
through its DevTools protocol: open the page, wait until the scene has been drawn, close
the browser's own notices, capture the window.  The tests use it to check what a browser
shows (pixel checks), and the docs' pictures come from it.  Nothing here serves a view."""

from __future__ import annotations

import base64
import contextlib
import json
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "chrome")
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",  # WebGL in software: no GPU needed
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--remote-debugging-address=127.0.0.1",
)
# viser's notices (e.g. "Software WebGL rendering detected") closed before the capture
CLOSE_NOTICES = "document.querySelectorAll('.mantine-Notification-closeButton').forEach(b => b.click())"


def find_chromium() -> str | None:
    """The path of a Chromium (or Chrome) executable, or None."""
    for name in CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    return None


class _Page:
    """One page's DevTools connection: `call` sends a command and waits for its answer."""

    def __init__(self, ws_url: str) -> None:
        from websockets.sync.client import connect

        self.ws = connect(ws_url, max_size=None, open_timeout=30)
        self.next_id = 0

    def call(self, method: str, timeout: float = 60.0, **params: object) -> dict:
        self.next_id += 1
        mine = self.next_id
        self.ws.send(json.dumps({"id": mine, "method": method, "params": params}))
        end = time.monotonic() + timeout
        while True:
            reply = json.loads(self.ws.recv(timeout=max(0.1, end - time.monotonic())))
            if reply.get("id") == mine:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})

    def evaluate(self, expression: str) -> object:
        out = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return out.get("result", {}).get("value")

    def close(self) -> None:
        self.ws.close()


def _steady_capture(page: _Page, end: float, every: float = 2.0, still: float = 0.5) -> bytes:
    """Capture the window until two captures `every` seconds apart differ by less than `still`
    (mean absolute difference of 0-255 values: the scene's fade-in is over; it takes many
    frames, and software WebGL draws few a second), or until `end`; the last capture."""
    import io

    import numpy as np
    from PIL import Image

    def grab() -> tuple[bytes, np.ndarray]:
        png = base64.b64decode(page.call("Page.captureScreenshot", format="png")["data"])
        return png, np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.float32)

    png, last = grab()
    while time.monotonic() < end:
        time.sleep(every)
        png, now = grab()
        if float(np.abs(now - last).mean()) < still:
            break
        last = now
    return png


def screenshot(
    url: str,
    out: str | Path,
    size: tuple[int, int] = (1200, 800),
    settle: float = 4.0,
    timeout: float = 120.0,
    chromium: str | None = None,
) -> Path:
    """Open `url` in headless Chromium at `size` (width, height), wait until the page has a
    WebGL canvas, `settle` seconds more, and until the picture holds still, and write a PNG
    of the window to `out`."""
    exe = chromium or find_chromium()
    if exe is None:
        raise FileNotFoundError("no chromium found (Debian: apt install chromium)")
    profile = tempfile.mkdtemp(prefix="lmjx-chromium-")
    port_file = Path(profile) / "DevToolsActivePort"
    proc = subprocess.Popen(
        [exe, *FLAGS, "--remote-debugging-port=0", f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}",
         "about:blank"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        end = time.monotonic() + timeout
        while not port_file.exists() or len(port_file.read_text().split()) < 2:
            if proc.poll() is not None or time.monotonic() > end:
                raise RuntimeError(f"{exe} did not start (exit status {proc.poll()})")
            time.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
            pages = [t for t in json.loads(r.read()) if t.get("type") == "page"]
        page = _Page(pages[0]["webSocketDebuggerUrl"])
        try:
            page.call("Emulation.setDeviceMetricsOverride", width=size[0], height=size[1], deviceScaleFactor=1,
                      mobile=False)  # fmt: skip
            page.call("Page.navigate", url=url)
            while not page.evaluate("!!document.querySelector('canvas') && document.readyState === 'complete'"):
                if time.monotonic() > end:
                    raise RuntimeError(f"{url} drew nothing within {timeout:g} s")
                time.sleep(0.25)
            time.sleep(settle)
            page.evaluate(CLOSE_NOTICES)
            png = _steady_capture(page, end)
        finally:
            page.close()
        Path(out).write_bytes(png)
        return Path(out)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        with contextlib.suppress(OSError):
            shutil.rmtree(profile, ignore_errors=True)
