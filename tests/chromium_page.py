"""A headless Chromium for the viewer's browser tests, driven over the DevTools protocol
through a pipe (``--remote-debugging-pipe``: the browser reads commands on its fd 3 and
writes replies and events on its fd 4, each a JSON message ended by a NUL byte), so no
port, no websocket library and no Playwright are needed.

- :func:`find_chromium`: the browser binary (``chromium``, ``chromium-browser``,
  ``google-chrome``), or None.
- :class:`Chromium`: ``with Chromium(binary) as browser: page = browser.open(url)``;
  the page's network is switched off (offline, and every request is logged), it can
  ``evaluate`` JavaScript, ``wait_for`` a condition and take a ``screenshot``.

Also a small command line (``python tests/chromium_page.py PAGE.html [OUT.png]``): opens
the page, prints its open time and requests, writes a screenshot.
"""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """The first Chromium-family browser on PATH, or None."""
    for name in CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    return None


class BrowserError(RuntimeError):
    """The browser failed, or answered a command with an error."""


class Chromium:
    """One headless browser process and its DevTools pipe."""

    def __init__(self, binary: str, width: int = 1280, height: int = 900, timeout: float = 60.0):
        self.binary, self.width, self.height, self.timeout = binary, width, height, timeout
        self.proc = None
        self._next = 0
        self._buffer = b""
        self.events: list[dict] = []

    def __enter__(self) -> "Chromium":
        self.profile = tempfile.mkdtemp(prefix="geosynth-chromium-")
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()

        def fds():  # in the child: its fd 3 reads our commands, its fd 4 writes its replies
            read, write = os.dup(to_browser_r), os.dup(from_browser_w)  # neither may be 3 or 4 while moved
            while read in (3, 4) or write in (3, 4):
                read, write = os.dup(read), os.dup(write)
            os.dup2(read, 3)
            os.dup2(write, 4)

        args = [self.binary, "--headless=new", "--remote-debugging-pipe", f"--user-data-dir={self.profile}",
                "--no-first-run", "--no-default-browser-check", "--disable-extensions", "--disable-gpu-sandbox",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--disable-features=Translate,MediaRouter,OptimizationHints", "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader", "--mute-audio", "--hide-scrollbars",
                f"--window-size={self.width},{self.height}", "about:blank"]
        if os.geteuid() == 0:
            args.insert(1, "--no-sandbox")  # Chromium refuses to run as root with its sandbox
        self.proc = subprocess.Popen(args, preexec_fn=fds, pass_fds=(3, 4),
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        os.close(to_browser_r)
        os.close(from_browser_w)
        return self

    def __exit__(self, *exc) -> None:
        try:
            if self.proc and self.proc.poll() is None:
                try:
                    self.send("Browser.close", timeout=5)
                except (BrowserError, OSError):
                    pass
                try:
                    self.proc.wait(5)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(5)
        finally:
            for fd in (self._to_browser, self._from_browser):
                try:
                    os.close(fd)
                except OSError:
                    pass
            if self.proc and self.proc.stderr:
                self.proc.stderr.close()
            shutil.rmtree(self.profile, ignore_errors=True)

    # ------------------------------------------------------------ the protocol

    def _read_message(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BrowserError("the browser did not answer in time")
            ready, _, _ = select.select([self._from_browser], [], [], left)
            if not ready:
                continue
            chunk = os.read(self._from_browser, 1 << 20)
            if not chunk:
                err = self.proc.stderr.read().decode(errors="replace")[-2000:] if self.proc.poll() is not None else ""
                raise BrowserError(f"the browser closed its pipe: {err.strip()}")
            self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def send(self, method: str, params: dict | None = None, session: str | None = None,
             timeout: float | None = None) -> dict:
        """Send one command, return its result; events that arrive meanwhile are kept."""
        self._next += 1
        msg = {"id": self._next, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._to_browser, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + (timeout or self.timeout)
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == self._next:
                if "error" in reply:
                    raise BrowserError(f"{method}: {reply['error'].get('message')}")
                return reply.get("result", {})
            if "method" in reply:
                self.events.append(reply)

    def pump(self, seconds: float) -> None:
        """Collect the events that arrive within ``seconds``."""
        deadline = time.monotonic() + seconds
        while True:
            try:
                self.events.append(self._read_message(deadline))
            except BrowserError as exc:
                if "in time" in str(exc):
                    return
                raise

    def open(self, url: str) -> "Page":
        """A new tab with the network off (offline; every request logged), at ``url``."""
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        page = Page(self, session)
        self.send("Network.enable", session=session)
        self.send("Network.emulateNetworkConditions", {"offline": True, "latency": 0, "downloadThroughput": -1,
                                                       "uploadThroughput": -1}, session=session)
        self.send("Page.enable", session=session)
        self.send("Runtime.enable", session=session)
        self.send("Emulation.setDeviceMetricsOverride", {"width": self.width, "height": self.height,
                                                         "deviceScaleFactor": 1, "mobile": False}, session=session)
        page.started = time.monotonic()
        self.send("Page.navigate", {"url": url}, session=session)
        return page


class Page:
    """One tab of :class:`Chromium`."""

    def __init__(self, browser: Chromium, session: str):
        self.browser, self.session = browser, session
        self.started = 0.0

    def evaluate(self, expression: str):
        result = self.browser.send("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                        "awaitPromise": True}, session=self.session)
        if "exceptionDetails" in result:
            raise BrowserError(f"{expression}: {result['exceptionDetails'].get('text')} "
                               f"{result['exceptionDetails'].get('exception', {}).get('description', '')}")
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 30.0, step: float = 0.05):
        """Poll ``expression`` until it is truthy; returns its value (BrowserError after timeout)."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                value = self.evaluate(expression)
            except BrowserError:
                value = None  # the document may not be there yet
            if value:
                return value
            if time.monotonic() > deadline:
                raise BrowserError(f"timed out after {timeout:g} s waiting for {expression}")
            time.sleep(step)

    def screenshot(self, clip: dict | None = None) -> bytes:
        """A PNG of the viewport, or of ``clip`` ({x, y, width, height} in CSS pixels)."""
        params = {"format": "png"}
        if clip:
            params["clip"] = dict(clip, scale=1)
        return base64.b64decode(self.browser.send("Page.captureScreenshot", params, session=self.session)["data"])

    def requests(self) -> list[str]:
        """The URLs this tab asked for (every Network.requestWillBeSent), the page itself included."""
        return [e["params"]["request"]["url"] for e in self.browser.events
                if e.get("method") == "Network.requestWillBeSent" and e.get("sessionId") == self.session]

    def console_errors(self) -> list[str]:
        out = []
        for e in self.browser.events:
            if e.get("sessionId") != self.session:
                continue
            if e.get("method") == "Runtime.exceptionThrown":
                out.append(e["params"]["exceptionDetails"].get("text", "exception"))
            elif e.get("method") == "Runtime.consoleAPICalled" and e["params"].get("type") == "error":
                out.append(" ".join(str(a.get("value", a.get("description", ""))) for a in e["params"]["args"]))
        return out


def main(argv: list[str]) -> int:
    """Open a page, print its open time and requests, and write a screenshot."""
    if not argv:
        print("usage: python tests/chromium_page.py PAGE.html [OUT.png]", file=sys.stderr)
        return 2
    binary = find_chromium()
    if binary is None:
        print("no Chromium found (chromium, chromium-browser, google-chrome)", file=sys.stderr)
        return 2
    url = Path(argv[0]).resolve().as_uri()
    with Chromium(binary) as browser:
        t0 = time.monotonic()
        page = browser.open(url)
        page.wait_for("window.__geosynthTest && (window.__geosynthTest.ready || window.__geosynthTest.error)", 60)
        wall = time.monotonic() - t0
        state = page.evaluate("JSON.stringify({openMs: __geosynthTest.openMs, marks: __geosynthTest.marks, error: __geosynthTest.error})")
        print(f"{url}: {state}; wall time to both first frames {wall:.2f} s")
        browser.pump(0.3)
        print("requests:", page.requests())
        print("console errors:", page.console_errors())
        if len(argv) > 1:
            Path(argv[1]).write_bytes(page.screenshot())
            print("screenshot:", argv[1])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
