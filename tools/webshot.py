"""Rerun's web viewer in headless Chromium, driven over WebDriver, as a person would see it.

Debian's ``chromium`` and ``chromium-driver`` (``tools/install_chromium.sh``
installs them) render the viewer with software WebGL. The driver speaks plain
HTTP and JSON, so no browser package is needed on the Python side. The
Chromium flags are the ones known to work on a machine without a network:
without the background-networking flags Chromium keeps trying to reach hosts
it cannot resolve.

"Loaded" is read from the viewer itself: its state (``WebHandle.viewer_state``,
a protobuf) holds each timeline's range, and the recording is fully in once the
range reaches the file's last time. The page answers only between frames, so a
busy viewer also answers late.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc

from dica.tools.view import rerun_binary, viewer_command, web_url

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
)
TIMELINE = "sim_time"


class BrowserError(Exception):
    """Chromium, its driver or the viewer is missing or did not answer; one line."""


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
            raise BrowserError(
                "chromium and chromedriver are needed: bash tools/install_chromium.sh"
            )
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
            timeouts = {"script": 600_000, "pageLoad": 600_000}
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
            with urllib.request.urlopen(req, timeout=630) as resp:
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

    def click(self, x: int, y: int, times: int = 1) -> None:
        acts: list[dict] = [
            {"type": "pointerMove", "duration": 0, "x": x, "y": y, "origin": "viewport"}
        ]
        for _ in range(times):
            acts += [{"type": "pointerDown", "button": 0}, {"type": "pointerUp", "button": 0}]
            acts += [{"type": "pause", "duration": 150}]
        source = {"type": "pointer", "id": "mouse", "parameters": {"pointerType": "mouse"}}
        self._call(
            "POST", f"/session/{self.session}/actions", {"actions": [{**source, "actions": acts}]}
        )

    def move_to(self, x: int, y: int) -> None:
        acts = [{"type": "pointerMove", "duration": 0, "x": x, "y": y, "origin": "viewport"}]
        source = {"type": "pointer", "id": "mouse", "parameters": {"pointerType": "mouse"}}
        self._call(
            "POST", f"/session/{self.session}/actions", {"actions": [{**source, "actions": acts}]}
        )

    def type_keys(self, text: str, select_all: bool = False) -> None:
        """Type ``text`` (``\\n`` is Enter), after Ctrl-A when ``select_all``."""
        keys: list[dict] = []
        if select_all:
            keys += [{"type": "keyDown", "value": "\ue009"}, {"type": "keyDown", "value": "a"}]
            keys += [{"type": "keyUp", "value": "a"}, {"type": "keyUp", "value": "\ue009"}]
        for ch in text:
            v = "\ue007" if ch == "\n" else ch
            keys += [{"type": "keyDown", "value": v}, {"type": "keyUp", "value": v}]
        self._call(
            "POST",
            f"/session/{self.session}/actions",
            {"actions": [{"type": "key", "id": "keyboard", "actions": keys}]},
        )

    def screenshot(self) -> bytes:
        """The window as PNG bytes (taken once the page has drawn a frame)."""
        b64 = self._call("GET", f"/session/{self.session}/screenshot")
        return base64.b64decode(b64)  # type: ignore[arg-type]

    def close(self) -> None:
        with contextlib.suppress(BrowserError):
            self._call("DELETE", f"/session/{self.session}")
        self._stop_driver()

    def _stop_driver(self) -> None:
        if self._driver.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self._driver.pid, signal.SIGTERM)
            try:
                self._driver.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(self._driver.pid, signal.SIGKILL)
                self._driver.wait()
        self._profile.cleanup()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# -- the Rerun web viewer -------------------------------------------------------------
def last_time_ns(rrd: Path) -> int:
    """The last ``sim_time`` in a recording [ns]."""
    from rerun.chunk import RrdReader

    end = 0
    for chunk in RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        if TIMELINE in batch.schema.names and batch.num_rows:
            end = max(end, pc.max(batch.column(TIMELINE).cast(pa.int64())).as_py())
    return end


def recording_id(rrd: Path) -> str:
    from rerun.chunk import RrdReader

    return RrdReader(rrd).recordings()[0].recording_id


def _varint(b: bytes, i: int) -> tuple[int, int]:
    v = shift = 0
    while True:
        x = b[i]
        i += 1
        v |= (x & 0x7F) << shift
        shift += 7
        if x < 0x80:
            return v, i


def _fields(b: bytes) -> list[tuple[int, int | bytes]]:
    """One level of a protobuf message: (field number, varint or bytes)."""
    out: list[tuple[int, int | bytes]] = []
    i = 0
    while i < len(b):
        key, i = _varint(b, i)
        field, kind = key >> 3, key & 7
        if kind == 0:
            value, i = _varint(b, i)
            out.append((field, value))
        elif kind == 2:
            n, i = _varint(b, i)
            out.append((field, b[i : i + n]))
            i += n
        elif kind in (1, 5):
            i += 8 if kind == 1 else 4
        else:
            raise ValueError(f"protobuf wire type {kind}")
    return out


def loaded_until_ns(state: bytes, timeline: str = TIMELINE) -> int | None:
    """The end of ``timeline``'s range in the viewer's state: how far it has loaded.

    The layout (viewer 0.41): field 3 is the active recording; in it, each
    field 2 is a timeline with its name (1.1), kind (2) and range (3: min 1, max 2).
    """
    for field, rec in _fields(state):
        if field != 3 or not isinstance(rec, bytes):
            continue
        for sub, tl in _fields(rec):
            if sub != 2 or not isinstance(tl, bytes):
                continue
            parts = dict(_fields(tl))
            name = parts.get(1)
            if isinstance(name, bytes) and timeline.encode() in name:
                rng = parts.get(3)
                if isinstance(rng, bytes):
                    bounds = dict(_fields(rng))
                    return int(bounds.get(2, bounds.get(1, 0)))  # type: ignore[arg-type]
    return None


class Viewer:
    """``rerun --serve-web`` on 127.0.0.1 for some .rrd files, stopped as a process group."""

    def __init__(self, files: list[Path]) -> None:
        self.port, self.grpc_port = free_port(), free_port()
        cmd = viewer_command(files, True, self.port, self.grpc_port)
        self.proc = subprocess.Popen(
            cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
        )
        try:
            wait_port(self.port, 60.0, "the web viewer")
        except BrowserError:
            self.close()
            raise
        self.url = web_url(self.port, self.grpc_port)
        self.source = f"rerun+http://127.0.0.1:{self.grpc_port}/proxy"

    def close(self) -> None:
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()

    def __enter__(self) -> Viewer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def wait_loaded(browser: Browser, end_ns: int, timeout_s: float) -> float:
    """Seconds (from now) until the viewer has the recording up to ``end_ns`` and has
    drawn a frame of it; BrowserError after ``timeout_s``."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        raw = browser.run_js(
            "return window._handle ? Array.from(window._handle.viewer_state()) : null"
        )
        if raw:
            got = loaded_until_ns(bytes(raw))  # type: ignore[arg-type]
            if got is not None and got >= end_ns:
                browser.screenshot()  # returns once a frame with the data is drawn
                return time.monotonic() - t0
        time.sleep(0.25)
    raise BrowserError(f"the viewer did not show the whole recording in {timeout_s:.0f} s")


def set_time(browser: Browser, t_s: float) -> None:
    """Move the time cursor by typing into the time box at the window's bottom right."""
    w, h = browser.run_js("return [window.innerWidth, window.innerHeight]")  # type: ignore[misc]
    browser.click(int(w) - 120, int(h) - 14, times=2)
    time.sleep(0.5)
    browser.type_keys(f"{t_s:g}s\n", select_all=True)
    time.sleep(1.0)


def show_blueprint(viewer: Viewer, rrd: Path, blueprint) -> None:
    """Make ``blueprint`` the active layout of the recording the viewer shows."""
    import rerun as rr

    rec = rr.RecordingStream("dica", recording_id=recording_id(rrd), send_properties=False)
    rec.connect_grpc(viewer.source)
    rec.send_blueprint(blueprint, make_active=True)
    rec.flush()
    rec.disconnect()


__all__ = [
    "Browser",
    "BrowserError",
    "Viewer",
    "last_time_ns",
    "loaded_until_ns",
    "rerun_binary",
    "set_time",
    "show_blueprint",
    "wait_loaded",
]
