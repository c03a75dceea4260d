"""A firmware update in the web console, in a real browser (Playwright driving Debian's Chromium,
as tests/test_web_browser.py): ``missing-link run --web`` holds a MicroPython board (``missing-link
board --file examples/boards/rover.py --runtime micropython --flash DIR``) and ``missing-link
update rover BOARDFILE`` goes through the daemon.  The board's section shows the update with its
progress partway, then done with the old and new hash, the new hash among the board's facts and
the update's line in the board's log, which keeps the keyboard's focus while ticks arrive.

The link to the board goes through a proxy that stops passing bytes to the board a third of the
way through the image until the page has shown that progress: the test sees the bar partway on
any machine, however fast the transfer (the board goes on streaming meanwhile, so the daemon's
link stays up; the proxy lets go well within the update's 5 s per chunk: held 0.05 to 0.08 s
here).  The screenshot
docs/web.md shows is taken here: ``ML_WEB_SCREENSHOTS=docs pytest tests/test_web_update.py``.
"""

from __future__ import annotations

import re
import socket
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from missing_link.deploy.boardfile import load_board_file
from missing_link.deploy.update import micropython_image

from .helpers import ML, board_process
from .test_web_browser import board, browser, daemon, shots

pytestmark = [pytest.mark.slow, pytest.mark.micropython]

ROOT = Path(__file__).resolve().parent.parent
ROVER = ROOT / "examples" / "boards" / "rover.py"
_ = (browser, shots)  # (fixtures of test_web_browser.py, used here by name)


class HoldProxy:
    """A TCP proxy to ``url`` (a new connection to it for each one accepted: the board's link
    after its restart too).  Once ``arm(n)`` was called, the next ``n`` bytes to the board pass
    and then nothing more to it until ``let_go()``, whole reads at a time (a frame is not cut:
    the host sends one request and waits for its reply); the board's bytes always pass."""

    def __init__(self, url: str) -> None:
        host, port = url.removeprefix("tcp://").split(":")
        self.target = (host, int(port))
        self.server = socket.create_server(("127.0.0.1", 0))
        self.url = f"tcp://127.0.0.1:{self.server.getsockname()[1]}"
        self.budget: int | None = None
        self.held = threading.Event()
        self.go = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def arm(self, n: int) -> None:
        self.budget = n

    def let_go(self) -> None:
        self.go.set()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return  # (closed)
            to = socket.create_connection(self.target)
            threading.Thread(target=self._pump, args=(to, conn, False), daemon=True).start()
            threading.Thread(target=self._pump, args=(conn, to, True), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket, to_board: bool) -> None:
        try:
            while data := src.recv(65536):
                if to_board and self.budget is not None:
                    if self.budget <= 0 and not self.go.is_set():
                        self.held.set()
                        self.go.wait(60)
                    self.budget -= len(data)
                dst.sendall(data)
        except OSError:
            pass
        finally:
            dst.close()

    def close(self) -> None:
        self.go.set()
        self.server.close()


def test_a_firmware_update_through_the_daemon_in_the_page(
    browser: Any, shots: Path, tmp_path: Path
) -> None:
    from playwright.sync_api import expect

    slow = tmp_path / "rover-slow.py"
    slow.write_text(ROVER.read_text().replace('"rate_hz": 50}', '"rate_hz": 20}', 1))
    old = micropython_image(load_board_file(ROVER)).fw_hash
    image = micropython_image(load_board_file(slow))
    new, size = image.fw_hash, len(image.data)
    assert old != new
    flash = str(tmp_path / "flash")
    with board_process("--file", str(ROVER), "--runtime", "micropython", "--flash", flash) as url:
        proxy = HoldProxy(url)
        more = f'[[board]]\nname = "rover"\nurl = "{proxy.url}"\nhandshake_timeout = 20\n'
        try:
            with daemon(tmp_path, {}, more=more) as (web, env):
                page = browser.new_page()
                errors: list[str] = []
                page.on("pageerror", lambda e: errors.append(str(e)))
                page.goto(web)
                rover = board(page, "rover")
                expect(rover.locator(".state")).to_have_text("up", timeout=30000)
                expect(rover.get_by_role("definition").filter(has_text=old)).to_be_visible()
                assert rover.get_by_role("heading", name="Firmware update").count() == 0
                proxy.arm(size // 3)
                update = subprocess.Popen([*ML, "update", "rover", str(slow)], env=env,
                                          stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                          text=True)  # fmt: skip
                try:
                    assert proxy.held.wait(60), "the update never got a third of the way"
                    held = time.monotonic()
                    partway(rover, size)
                finally:
                    proxy.let_go()
                print(f"the image held {time.monotonic() - held:.2f} s (the chunk timeout: 5 s)")
                out, err = update.communicate(timeout=120)
                assert update.returncode == 0, out + err
                assert f"-> 0.2.0 {new}" in out, out
                finished(rover, size, old, new)
                rover.locator(".extra").screenshot(path=str(shots / "web-update.png"))
                keeps_focus(rover)
                page.close()
                assert not errors, errors
        finally:
            proxy.close()


def partway(rover: Any, size: int) -> None:
    """The update's section while the proxy holds the image partway (the board still up)."""
    from playwright.sync_api import expect

    expect(rover.get_by_role("heading", name="Firmware update")).to_be_visible(timeout=4000)
    bar = rover.get_by_role("progressbar", name="firmware update")
    expect(bar).to_have_attribute("max", str(size))
    expect(rover.locator(".update")).to_contain_text("sending")
    done = int(bar.get_attribute("value"))
    assert 0 < done < size, (done, size)
    expect(rover.locator(".state")).to_have_text("up")


def finished(rover: Any, size: int, old: str, new: str) -> None:
    """Done: the bar full, the old and new hash, the board's facts and log say so."""
    from playwright.sync_api import expect

    line = rover.locator(".update")
    expect(line).to_contain_text("done", timeout=10000)
    expect(line).to_contain_text(f"{old} → {new}")
    expect(rover.get_by_role("progressbar", name="firmware update")).to_have_attribute(
        "value", str(size)
    )
    expect(rover.get_by_role("definition").filter(has_text=new)).to_be_visible()
    expect(rover.locator(".state")).to_have_text("up")
    log = rover.locator("pre.log")
    expect(log).to_contain_text(re.compile(r"firmware rover: updated .* -> 0\.2\.0 " + new))


def keeps_focus(rover: Any) -> None:
    """The log (a focusable region: read with the keyboard) keeps the focus while ticks come."""
    from playwright.sync_api import expect

    log = rover.locator("pre.log")
    log.focus()
    samples = rover.locator("dl.facts dt:text-is('Samples') + dd")
    first = samples.text_content()
    expect(samples).not_to_have_text(first, timeout=5000)  # (ticks came: the status changed)
    expect(log).to_be_focused()
