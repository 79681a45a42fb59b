"""Headless Chromium driven over WebDriver, to look at Rerun's web viewer as a person would.

Debian's ``chromium`` and ``chromium-driver`` (``tools/install_chromium.sh``
installs them) render the web viewer with software WebGL. The driver speaks
plain HTTP and JSON, so no browser package is needed on the Python side. The
Chromium flags are the ones known to work on a machine without a network:
without the background-networking flags Chromium keeps trying to reach hosts
it cannot resolve.
"""

from __future__ import annotations

import base64
import json
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

CHROME_FLAGS = (
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-unsafe-swiftshader",  # software WebGL for the viewer's canvas
    "--use-angle=swiftshader",
)


class BrowserError(Exception):
    """Chromium or its driver is missing or did not answer; one line for a person."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def wait_port(port: int, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not port_open(port):
        if time.monotonic() > deadline:
            raise BrowserError(f"{what} did not open port {port} in {timeout_s:.0f} s")
        time.sleep(0.1)


class Browser:
    """One headless Chromium window of a fixed size, behind chromedriver on loopback."""

    def __init__(self, width_px: int = 1600, height_px: int = 1000) -> None:
        driver = shutil.which("chromedriver")
        chrome = shutil.which("chromium")
        if driver is None or chrome is None:
            raise BrowserError("chromium and chromedriver are needed: bash tools/install_chromium.sh")
        self.port = free_port()
        self._profile = tempfile.TemporaryDirectory(prefix="dica-chromium-")
        self._driver = subprocess.Popen(
            [driver, f"--port={self.port}"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        try:
            wait_port(self.port, 20.0, "chromedriver")
            args = [*CHROME_FLAGS, f"--user-data-dir={self._profile.name}"]
            args.append(f"--window-size={width_px},{height_px}")
            caps = {"browserName": "chrome", "goog:chromeOptions": {"binary": chrome, "args": args}}
            answer = self._call("POST", "/session", {"capabilities": {"alwaysMatch": caps}})
            self.session = answer["sessionId"]
            timeouts = {"script": 300_000, "pageLoad": 300_000}
            self._call("POST", f"/session/{self.session}/timeouts", timeouts)
        except BaseException:
            self._stop_driver()
            raise

    def _call(self, method: str, path: str, body: dict | None = None) -> dict:
        data = json.dumps(body).encode() if body is not None else None
        req = urllib.request.Request(
            f"http://127.0.0.1:{self.port}{path}",
            data=data,
            method=method,
            headers={"Content-Type": "application/json"},
        )
        try:
            with urllib.request.urlopen(req, timeout=330) as resp:
                out = json.loads(resp.read())
        except urllib.error.HTTPError as e:
            out = json.loads(e.read() or b"{}")
        except OSError as e:
            raise BrowserError(f"chromedriver: {e}") from None
        value = out.get("value")
        if isinstance(value, dict) and "error" in value:
            raise BrowserError(f"chromedriver: {value['error']}: {value.get('message', '')[:200]}")
        return out if path == "/session" and "sessionId" in out else (value or {})

    def open(self, url: str) -> None:
        self._call("POST", f"/session/{self.session}/url", {"url": url})

    def run_js(self, script: str) -> object:
        return self._call(
            "POST", f"/session/{self.session}/execute/sync", {"script": script, "args": []}
        )

    def screenshot(self) -> bytes:
        """The window as PNG bytes."""
        b64 = self._call("GET", f"/session/{self.session}/screenshot")
        return base64.b64decode(b64)  # type: ignore[arg-type]

    def save_screenshot(self, path: Path) -> None:
        path.write_bytes(self.screenshot())

    def close(self) -> None:
        try:
            self._call("DELETE", f"/session/{self.session}")
        except BrowserError:
            pass
        self._stop_driver()

    def _stop_driver(self) -> None:
        if self._driver.poll() is None:
            self._driver.terminate()
            try:
                self._driver.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._driver.kill()
                self._driver.wait()
        self._profile.cleanup()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _pointer(x: int, y: int) -> list[dict]:
    return [
        {"type": "pointerMove", "duration": 0, "x": x, "y": y, "origin": "viewport"},
        {"type": "pointerDown", "button": 0},
        {"type": "pointerUp", "button": 0},
    ]
