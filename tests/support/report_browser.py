"""Open a report in headless Chromium and check it: console errors, decoded images, a screenshot.

Chromium is driven over the DevTools protocol (CDP) with a small standard
library WebSocket client (RFC 6455: handshake, masked client frames,
fragmented server messages), so no browser automation package is needed:

1. start ``chromium --headless --no-sandbox --disable-gpu --remote-debugging-port=0``
   with a throw-away profile, read the port from ``DevToolsActivePort``;
2. create a page, enable ``Runtime``/``Log``/``Page`` events, navigate to the file
   and wait for ``Page.loadEventFired``;
3. collect ``console.error``/``console.assert`` calls, uncaught exceptions and
   error log entries (e.g. images that failed to load), read the report's
   ``#rigslim-check`` marker (images with ``naturalWidth > 0``), and capture
   a full-page PNG screenshot.

Command line (writes the screenshot used in docs/reports.md)::

    PYTHONPATH=tests python -m support.report_browser out/report.html --screenshot docs/images/report.png --width 1100
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import socket
import struct
import subprocess
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from rigslim.errors import RigslimError

#: Flags of every launch (the issue's set plus the DevTools port).
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--disable-dev-shm-usage", "--hide-scrollbars", "--mute-audio"]


class BrowserUnavailable(RigslimError):
    """No Chromium binary, or it did not start."""


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome binary (``RIGSLIM_CHROMIUM`` first), or None."""
    env = os.environ.get("RIGSLIM_CHROMIUM")
    if env:
        return env
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


class WebSocket:
    """A minimal blocking WebSocket client (text messages only), enough for CDP."""

    def __init__(self, url: str, timeout: float = 30.0):
        assert url.startswith("ws://")
        hostport, _, path = url[5:].partition("/")
        host, _, port = hostport.partition(":")
        self.sock = socket.create_connection((host, int(port or 80)), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET /{path} HTTP/1.1\r\nHost: {hostport}\r\nUpgrade: websocket\r\n"
                           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                           "Sec-WebSocket-Version: 13\r\n\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise ConnectionError("WebSocket handshake: connection closed")
            head += chunk
        status, _, rest = head.partition(b"\r\n\r\n")
        if b" 101 " not in status.split(b"\r\n")[0]:
            raise ConnectionError(f"WebSocket handshake refused: {status.splitlines()[0]!r}")
        self.buffer = rest

    def _read(self, n: int) -> bytes:
        while len(self.buffer) < n:
            chunk = self.sock.recv(max(65536, n - len(self.buffer)))
            if not chunk:
                raise ConnectionError("WebSocket closed")
            self.buffer += chunk
        out, self.buffer = self.buffer[:n], self.buffer[n:]
        return out

    def _send_frame(self, opcode: int, payload: bytes) -> None:
        n = len(payload)
        head = bytes([0x80 | opcode])
        if n < 126:
            head += bytes([0x80 | n])
        elif n < 1 << 16:
            head += bytes([0x80 | 126]) + struct.pack(">H", n)
        else:
            head += bytes([0x80 | 127]) + struct.pack(">Q", n)
        mask = os.urandom(4)
        body = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.sock.sendall(head + mask + body)

    def send(self, text: str) -> None:
        self._send_frame(0x1, text.encode())

    def recv(self) -> str:
        """The next complete text message (answers pings, joins fragments)."""
        parts = []
        while True:
            b0, b1 = self._read(2)
            opcode, n = b0 & 0x0F, b1 & 0x7F
            if n == 126:
                n = struct.unpack(">H", self._read(2))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._read(8))[0]
            mask = self._read(4) if b1 & 0x80 else None
            payload = self._read(n)
            if mask:
                payload = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
            if opcode == 0x9:
                self._send_frame(0xA, payload)
                continue
            if opcode == 0x8:
                raise ConnectionError("WebSocket closed by the browser")
            if opcode in (0x0, 0x1, 0x2):
                parts.append(payload)
                if b0 & 0x80:
                    return b"".join(parts).decode("utf-8", errors="replace")

    def close(self) -> None:
        try:
            self._send_frame(0x8, b"")
        except OSError:
            pass
        self.sock.close()


@dataclass
class PageCheck:
    """What the browser saw.

    Attributes
    ----------
    console_errors : list of str
        ``console.error``/``assert`` messages, uncaught exceptions and error log entries.
    images_total, images_decoded : int
        ``<img>`` elements, and those with ``complete && naturalWidth > 0``.
    marker : dict
        The report's own ``#rigslim-check`` attributes (images decoded, script errors).
    screenshot : bytes
        Full-page PNG.
    title : str
    """

    console_errors: list = field(default_factory=list)
    images_total: int = 0
    images_decoded: int = 0
    marker: dict = field(default_factory=dict)
    screenshot: bytes = b""
    title: str = ""


class _CDP:
    def __init__(self, ws: WebSocket):
        self.ws = ws
        self.next_id = 0
        self.events: list[dict] = []

    def call(self, method: str, params: dict | None = None, session: str | None = None, timeout: float = 60.0):
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        self.ws.send(json.dumps(msg))
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            reply = json.loads(self.ws.recv())
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error'].get('message')}")
                return reply.get("result", {})
            self.events.append(reply)
        raise TimeoutError(method)

    def wait_event(self, method: str, timeout: float = 60.0) -> dict:
        for i, e in enumerate(self.events):
            if e.get("method") == method:
                return self.events.pop(i)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            e = json.loads(self.ws.recv())
            if e.get("method") == method:
                return e
            self.events.append(e)
        raise TimeoutError(method)


def _errors_of(events: list[dict]) -> list[str]:
    out = []
    for e in events:
        m, p = e.get("method"), e.get("params", {})
        if m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            out.append("console." + p["type"] + ": " + " ".join(str(a.get("value", a.get("description", "")))
                                                                 for a in p.get("args", [])))
        elif m == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            out.append("exception: " + str(d.get("exception", {}).get("description") or d.get("text")))
        elif m == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            out.append("log: " + str(p["entry"].get("text")))
    return out


@contextmanager
def devtools_page(*, flags: list[str] | None = None, timeout: float = 60.0, chromium: str | None = None):
    """Headless Chromium with a fresh profile; yields ``(cdp, session)`` for one blank page, closes it after.

    Parameters
    ----------
    flags : list of str, optional
        Chromium's command-line flags (default :data:`CHROMIUM_FLAGS`); the
        profile folder, the DevTools port and the blank first page are added.
    timeout : float
        Seconds to wait for Chromium to start.

    Raises
    ------
    BrowserUnavailable
        When no Chromium is installed (``tools/setup-chromium.sh``) or it does not start.
    """
    binary = chromium or find_chromium()
    if not binary:
        raise BrowserUnavailable("no chromium binary", field="chromium",
                                 fix="run tools/setup-chromium.sh (Debian package 'chromium')")
    with tempfile.TemporaryDirectory(prefix="rigslim-chromium-") as profile:
        log = open(Path(profile) / "stderr.log", "wb")
        proc = subprocess.Popen([binary, *(CHROMIUM_FLAGS if flags is None else flags), f"--user-data-dir={profile}",
                                 "--remote-debugging-port=0", "about:blank"],
                                stdout=subprocess.DEVNULL, stderr=log)
        ws = None
        try:
            port_file = Path(profile) / "DevToolsActivePort"
            end = time.monotonic() + timeout
            while not (port_file.exists() and len(port_file.read_text().split()) >= 2):
                if proc.poll() is not None or time.monotonic() > end:
                    raise BrowserUnavailable(f"chromium did not start (exit {proc.poll()})", source=binary,
                                             field="DevToolsActivePort",
                                             fix="run it by hand with --headless to see why")
                time.sleep(0.05)
            port, ws_path = port_file.read_text().split()[:2]
            ws = WebSocket(f"ws://127.0.0.1:{port}{ws_path}", timeout=timeout)
            cdp = _CDP(ws)
            target = cdp.call("Target.createTarget", {"url": "about:blank"})["targetId"]
            session = cdp.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
            yield cdp, session
        finally:
            if ws is not None:
                try:
                    ws.send(json.dumps({"id": 10 ** 6, "method": "Browser.close"}))
                except OSError:
                    pass
                ws.close()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            log.close()


def check_page(path, *, width: int = 1200, height: int = 900, timeout: float = 60.0,
               chromium: str | None = None) -> PageCheck:
    """Load an HTML file in headless Chromium and report errors, images and a screenshot.

    Raises
    ------
    BrowserUnavailable
        When no Chromium is installed (``tools/setup-chromium.sh``) or it does not start.
    """
    url = Path(path).resolve().as_uri()
    with devtools_page(flags=[*CHROMIUM_FLAGS, f"--window-size={width},{height}"], timeout=timeout,
                       chromium=chromium) as (cdp, session):
        for domain in ("Runtime", "Log", "Page"):
            cdp.call(f"{domain}.enable", session=session)
        cdp.call("Emulation.setDeviceMetricsOverride", {"width": width, "height": height,
                                                         "deviceScaleFactor": 1, "mobile": False},
                 session=session)
        cdp.call("Page.navigate", {"url": url}, session=session)
        cdp.wait_event("Page.loadEventFired", timeout=timeout)
        probe = ("JSON.stringify({title: document.title, total: document.images.length,"
                 " decoded: Array.prototype.filter.call(document.images, function(i){"
                 " return i.complete && i.naturalWidth > 0; }).length,"
                 " marker: (function(e){ if (!e) return {}; var o = {};"
                 " for (var a of e.attributes) o[a.name] = a.value; o.text = e.textContent; return o; })"
                 "(document.getElementById('rigslim-check'))})")
        value = json.loads(cdp.call("Runtime.evaluate", {"expression": probe, "returnByValue": True},
                                    session=session)["result"]["value"])
        metrics = cdp.call("Page.getLayoutMetrics", session=session)
        size = metrics.get("cssContentSize") or metrics.get("contentSize")
        shot = cdp.call("Page.captureScreenshot", {
            "format": "png", "captureBeyondViewport": True,
            "clip": {"x": 0, "y": 0, "width": max(width, size["width"]), "height": size["height"], "scale": 1}},
            session=session)
        # let late events (errors after load) arrive
        cdp.call("Runtime.evaluate", {"expression": "1"}, session=session)
        return PageCheck(console_errors=_errors_of(cdp.events), images_total=int(value["total"]),
                         images_decoded=int(value["decoded"]), marker=value["marker"],
                         screenshot=base64.b64decode(shot["data"]), title=value["title"])


def main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="PYTHONPATH=tests python -m support.report_browser",
                                     description="check a report in headless Chromium; save a screenshot")
    parser.add_argument("html")
    parser.add_argument("--screenshot", metavar="PNG")
    parser.add_argument("--width", type=int, default=1200, help="viewport width in CSS pixels")
    parser.add_argument("--shrink", type=int, default=0, metavar="PX",
                        help="scale the saved screenshot down to this width (palette PNG, for docs)")
    parser.add_argument("--crop-height", type=int, default=0, metavar="PX",
                        help="keep only the top of the page, this many CSS pixels (before --shrink)")
    args = parser.parse_args(argv)
    check = check_page(args.html, width=args.width)
    print(f"title: {check.title}")
    print(f"images decoded: {check.images_decoded} of {check.images_total}")
    print(f"console errors: {len(check.console_errors)}")
    for e in check.console_errors:
        print(f"  {e}")
    if args.screenshot:
        from rigslim.io.atomic import atomic_path

        data = check.screenshot
        if args.shrink or args.crop_height:
            import io

            from PIL import Image

            img = Image.open(io.BytesIO(data)).convert("RGB")
            if args.crop_height and img.height > args.crop_height:
                img = img.crop((0, 0, img.width, args.crop_height))
            if args.shrink and img.width > args.shrink:
                img = img.resize((args.shrink, round(img.height * args.shrink / img.width)), Image.LANCZOS)
            buf = io.BytesIO()
            img.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(buf, format="PNG", optimize=True)
            data = buf.getvalue()
        with atomic_path(args.screenshot) as tmp:
            Path(tmp).write_bytes(data)
            mask = os.umask(0)
            os.umask(mask)
            os.chmod(tmp, 0o666 & ~mask)
        print(f"screenshot written to {args.screenshot} ({len(data)} bytes)")
    return 0 if not check.console_errors and check.images_decoded == check.images_total else 1


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
