"""``missing-link update`` on MicroPython boards: the firmware under the real MicroPython 1.27
(node), started from its flash directory as a board starts (``missing-link board --file
examples/boards/rover.py --runtime micropython --flash DIR``), updated over its TCP link, on its
own or through a daemon, signed or not: a rate changed (the new hash in ``info``, the new rate
on the topic), a firmware that raises at start (exit 1, back on the old hash), a link cut
halfway (the old firmware still runs), what is refused, and the daemon's other boards going on
publishing meanwhile."""

from __future__ import annotations

import itertools
import json
import os
import random
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from missing_link import connect
from missing_link.daemon import Config, Daemon
from missing_link.daemon.config import BoardSpec
from missing_link.deploy.boardfile import load_board_file
from missing_link.deploy.update import micropython_image
from missing_link.host.board import Board
from missing_link.host.board_log import LogLine
from missing_link.topics import Update

from .helpers import board_process, ml, period_seen_us, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.micropython]

ROOT = Path(__file__).resolve().parent.parent
ROVER = ROOT / "examples" / "boards" / "rover.py"
WIFI = ROOT / "examples" / "boards" / "esp32-wifi.py"


@pytest.fixture
def env(tmp_path: Path) -> dict[str, str]:
    """No daemon of anybody else's: the control endpoint is the test's own."""
    return {**os.environ, "MISSING_LINK_CONTROL": str(tmp_path / "control.sock")}


def variant(tmp_path: Path, name: str, src: Path, *edits: tuple[str, str], tail: str = "") -> Path:
    text = src.read_text()
    for old, new in edits:
        assert old in text
        text = text.replace(old, new)
    p = tmp_path / f"{name}.py"
    p.write_text(text + tail)
    return p


SLOW_COMPASS = ('"bus": "i2c0", "rate_hz": 50}', '"bus": "i2c0", "rate_hz": 20}')


@pytest.fixture
def rover(tmp_path: Path) -> Iterator[str]:
    with board_process(
        "--file", str(ROVER), "--runtime", "micropython", "--flash", str(tmp_path / "flash")
    ) as url:
        yield url


def fw_hash(url: str) -> str:
    with Board.open(url, timeout=3.0, describe=False) as b:
        return b.properties["fw.hash"]


def compass_interval_ms(url: str, n: int = 30) -> float:
    """The time between the compass's samples, on the board's own clock: read from its slots
    (helpers.period_seen_us), not the median interval, which the sonar's echo wait bends (its
    rangings hold the loop 26 ms: every other 20 Hz sample late, then one on time)."""
    got: list[int] = []
    with connect(url, wait=20) as d:
        d.subscribe("/rover/compass", lambda u: got.append(u.board_us[0]), queue=0)
        assert wait_for(lambda: len(got) > n, 30)
    return period_seen_us(got) / 1000


def test_an_update_that_changes_a_rate(tmp_path: Path, rover: str, env: dict[str, str]) -> None:
    slow = variant(tmp_path, "rover-slow", ROVER, SLOW_COMPASS)
    old, new = fw_hash(rover), micropython_image(load_board_file(slow)).fw_hash
    assert old == micropython_image(load_board_file(ROVER)).fw_hash != new
    assert compass_interval_ms(rover) < 30  # 50 Hz
    r = ml("update", rover, str(slow), "--json", env=env)
    assert r.returncode == 0, r.stdout + r.stderr
    out = json.loads(r.stdout)
    assert (out["state"], out["old_hash"], out["new_hash"], out["slot"]) == (
        "updated",
        old,
        new,
        "a",
    )
    assert out["bytes"] == len(micropython_image(load_board_file(slow)).data)
    assert "update: sending" in r.stderr and "100%" in r.stderr  # the progress bar
    info = ml("info", rover, "--json", env=env)
    assert json.loads(info.stdout)["properties"]["fw.hash"] == new
    assert compass_interval_ms(rover) > 40  # 20 Hz now
    r = ml("update", rover, str(ROVER), env=env)  # and back (into the other slot)
    assert r.returncode == 0 and f"-> 0.2.0 {old}" in r.stdout and "slot b" in r.stdout, r.stdout


def test_an_update_over_a_serial_port(tmp_path: Path, env: dict[str, str]) -> None:
    """The board on a serial port (USB CDC: a pty here), which it leaves when it restarts and
    comes back on: the update over it, the new rate on the topic."""
    slow = variant(tmp_path, "rover-slow", ROVER, SLOW_COMPASS)
    new = micropython_image(load_board_file(slow)).fw_hash
    with board_process("--file", str(ROVER), "--runtime", "micropython",
                       "--flash", str(tmp_path / "flash"), "--listen", "pty") as url:  # fmt: skip
        assert url.startswith("serial://")
        r = ml("update", url, str(slow), env=env)
        assert r.returncode == 0, r.stdout + r.stderr
        assert f"-> 0.2.0 {new}" in r.stdout and "slot a" in r.stdout, r.stdout
        assert fw_hash(url) == new
        assert compass_interval_ms(url) > 40  # 20 Hz now


def test_a_firmware_that_raises_at_start_goes_back(
    tmp_path: Path, rover: str, env: dict[str, str]
) -> None:
    boom = variant(tmp_path, "rover-boom", ROVER, SLOW_COMPASS, tail="raise ValueError('boom')\n")
    old = fw_hash(rover)
    t0 = time.monotonic()
    r = ml("update", rover, str(boom), env=env)
    took = time.monotonic() - t0
    assert r.returncode == 1, r.stdout + r.stderr
    assert "went back" in r.stdout and "raised ValueError: boom" in r.stdout, r.stdout
    assert f"it runs 0.2.0 {old}" in r.stdout
    assert fw_hash(rover) == old
    assert took < 30, took  # (the bound: a restart, another, and a handshake)
    r = ml("update", rover, str(ROVER).replace("rover.py", "rover.py"), env=env)
    assert r.returncode == 0, r.stdout + r.stderr  # (it takes updates again: not on trial)


class CutProxy:
    """A TCP proxy to ``url`` that stops moving bytes (both ways, the connection left open, as
    a cable pulled or a network gone) once ``cut_after`` bytes went to the board."""

    def __init__(self, url: str, cut_after: int) -> None:
        host, port = url.removeprefix("tcp://").split(":")
        self.target = (host, int(port))
        self.cut_after = cut_after
        self.sent = 0
        self.server = socket.create_server(("127.0.0.1", 0))
        self.url = f"tcp://127.0.0.1:{self.server.getsockname()[1]}"
        self.cut = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        conn, _ = self.server.accept()
        board = socket.create_connection(self.target)
        threading.Thread(target=self._pump, args=(board, conn, False), daemon=True).start()
        self._pump(conn, board, True)

    def _pump(self, src: socket.socket, dst: socket.socket, to_board: bool) -> None:
        while not self.cut.is_set():
            data = src.recv(4096)
            if not data:
                return
            if to_board:
                room = self.cut_after - self.sent
                data = data[: max(0, room)]
                self.sent += len(data)
                if self.sent >= self.cut_after:
                    self.cut.set()
            if data:
                dst.sendall(data)

    def close(self) -> None:
        self.server.close()


def test_a_link_cut_halfway_leaves_the_old_firmware(
    tmp_path: Path, rover: str, env: dict[str, str]
) -> None:
    old = fw_hash(rover)
    size = len(micropython_image(load_board_file(ROVER)).data)
    slow = variant(tmp_path, "rover-slow", ROVER, SLOW_COMPASS)
    proxy = CutProxy(rover, size // 2)
    try:
        r = ml("update", proxy.url, str(slow), env=env)
    finally:
        proxy.close()
    assert r.returncode == 1, r.stdout + r.stderr
    assert "the link failed after" in r.stderr and "nothing was switched" in r.stderr, r.stderr
    assert f"still runs 0.2.0 {old}" in r.stderr and r.stderr.count("\n") <= 12
    assert fw_hash(rover) == old  # (on a link of its own: the board is fine)
    r = ml("update", rover, str(slow), env=env)  # the slot it was staging into is reused
    assert r.returncode == 0 and "slot a" in r.stdout, r.stdout + r.stderr


def test_what_the_board_cannot_take_is_refused_before_a_byte(
    tmp_path: Path, rover: str, env: dict[str, str]
) -> None:
    old = fw_hash(rover)
    # (an ESP32's board file that fits its heap: the rover's own on an esp32 does not, and is
    # refused for that before the board is asked, test_fit.py)
    esp = variant(tmp_path, "rover-esp", ROVER.parent / "esp32-wifi.py",
                  ('"model": "esp32-wifi"', '"model": "pico-rover"'))  # fmt: skip
    other = variant(tmp_path, "other", ROVER, ('"model": "pico-rover"', '"model": "pico-arm"'))
    bad = variant(tmp_path, "bad", ROVER, ('"driver": "hbridge"', '"driver": "warp"'))
    cases = [
        (("update", rover, str(esp)), 1, "made for mcu 'rp2040', the board file says 'esp32'"),
        (("update", rover, str(other)), 1, "board.model 'pico-rover', the board file says"),
        (("update", rover, str(ROVER), "--id", "not-this-one"), 1, "not 'not-this-one' as named"),
        (("update", rover, str(bad)), 2, "warp"),
        (("update", "rover", str(ROVER)), 2, "no running daemon holds"),
        (("update", rover, str(ROVER), "--trial", "2"), 2, "--trial"),
    ]
    for args, code, why in cases:
        r = ml(*args, env=env)
        assert r.returncode == code and why in r.stderr, (args, r.returncode, r.stderr)
        assert r.stderr.strip().splitlines()[-1].startswith("missing-link: error: ")
        assert "Traceback" not in r.stderr
    assert fw_hash(rover) == old
    assert not (tmp_path / "flash" / "fw").exists()  # (nothing was begun)


def test_a_signed_board_is_updated_over_its_signed_link(
    tmp_path: Path, env: dict[str, str]
) -> None:
    """Over signed J2A (docs/signing.md), and an update that would drop the key is refused."""
    flash = tmp_path / "flash"
    flash.mkdir()
    key = flash / "mlkey.bin"
    key.write_text(random.randbytes(32).hex() + "\n")
    faster = variant(
        tmp_path, "wifi-2", WIFI, ('"mcu": "esp32",', '"mcu": "esp32", "fw_version": "0.2.1",')
    )
    unsigned = variant(tmp_path, "wifi-nokey", WIFI, (', "key_file": "mlkey.bin"', ""))
    with board_process(
        "--file", str(WIFI), "--runtime", "micropython", "--flash", str(flash)
    ) as url:
        signed = f"signed+{url}?key={key}"
        r = ml("update", signed, str(unsigned), env=env)
        assert r.returncode == 1 and "would make it take unsigned J2A" in r.stderr, r.stderr
        r = ml("update", signed, str(faster), env=env)
        assert r.returncode == 0 and "-> 0.2.1 " in r.stdout, r.stdout + r.stderr
        with Board.open(signed, timeout=3.0, describe=False) as b:
            assert b.properties["fw.version"] == "0.2.1"


def test_through_the_daemon_the_other_boards_go_on(
    tmp_path: Path, rover: str, serve: object
) -> None:
    """The daemon holds the rover and a second board; ``update rover`` goes through its control
    endpoint; the second board publishes all along, the rover comes back with the new hash,
    and the status, /diagnostics' source, and the board's log say so."""
    from missing_link.virtual import make_sim, start_board_thread

    other, thread = start_board_thread(make_sim("thesis", seed=7), "tcp://127.0.0.1:0")
    control = tmp_path / "control.sock"
    record = tmp_path / "rec"
    cfg = Config(boards=[BoardSpec(rover, handshake_timeout=20.0), BoardSpec(other.url)],
                 control=str(control), publishers=["bus", "mcap"],
                 publisher_options={"mcap": {"path": str(record)}},
                 diagnostics_period=0.2)  # fmt: skip
    slow = variant(tmp_path, "rover-slow", ROVER, SLOW_COMPASS)
    new = micropython_image(load_board_file(slow)).fw_hash
    stamps: list[float] = []
    lines: list[LogLine] = []
    try:
        with Daemon(cfg) as d:
            assert d.wait_until_up(30), d.status()
            d.subscribe("/thesis/quad", lambda u: stamps.append(time.monotonic()), queue=0)
            d.subscribe_logs(lines.append, "rover", queue=0)
            env = {**os.environ, "MISSING_LINK_CONTROL": str(control)}
            t0 = time.monotonic()
            r = ml("update", "rover", str(slow), env=env)
            t1 = time.monotonic()
            assert r.returncode == 0, r.stdout + r.stderr
            assert f"-> 0.2.0 {new}" in r.stdout and "update: sending" in r.stderr
            st = {s["board"]: s for s in d.status()}
            assert st["rover"]["fw_hash"] == new and st["rover"]["connects"] == 2
            assert st["rover"]["update"]["state"] == "done"
            assert st["rover"]["update"]["to"] == new
            assert st["thesis"]["connects"] == 1 and st["thesis"]["state"] == "up"
            during = [t for t in stamps if t0 <= t <= t1]
            gaps = [b - a for a, b in itertools.pairwise(during)]
            assert len(during) > 10 and max(gaps) < (t1 - t0) / 4, (len(during), max(gaps))
            assert wait_for(lambda: any("firmware rover: updated" in x.text for x in lines), 5)
            time.sleep(0.5)  # (a round of /diagnostics or two after it)
            mcap = d.publishers[1]
    finally:
        other.stop()
        thread.join(5)
    (bag,) = mcap.bags  # type: ignore[attr-defined]
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        diag = [c for c in reader.connections if c.topic == "/diagnostics"]
        rovers = [
            {kv.key: kv.value for kv in s.values}
            for _, _, raw in reader.messages(diag)
            for s in reader.deserialize(raw, diag[0].msgtype).status
            if s.name == "missing_link: rover"
        ]
    states = [r.get("update", "") for r in rovers]
    assert any("'sending'" in u for u in states), states  # (the steps as they went)
    assert "'done'" in states[-1] and new in states[-1] and rovers[-1]["fw_hash"] == new


_ = Update
