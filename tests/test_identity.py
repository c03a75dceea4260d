"""Boards that say who they are (issue 36.1, docs/hardware.md "Identity"): ``board.id`` and
``fw.hash`` on every runtime - the CPython virtual board, the MicroPython firmware under the real
MicroPython (node), the AVR firmware in simavr - read as properties; the daemon's status,
``/diagnostics`` and the recording show them; the config names a board by its id whatever URL
it comes on; two boards that state one id are both shown, with a warning."""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from missing_link.board.identity import FirmwareHash, tree_hash
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config, parse_config
from missing_link.deploy.boardfile import load_board_file
from missing_link.deploy.check import FlashError, verify
from missing_link.deploy.flash import firmware_hash as staged_hash
from missing_link.deploy.flash import flash, micropython_files
from missing_link.errors import ConfigError
from missing_link.host.board import Board
from missing_link.publishers.base import Publisher
from missing_link.ros.board_record import BoardDescription
from missing_link.virtual import make_sim, start_board_thread
from missing_link.virtual.server import BoardServer

from .helpers import AvrSim, FirmwareSim, wait_for
from .serial_board import SerialBoard

ROOT = Path(__file__).resolve().parent.parent
BOARD_PKG = ROOT / "src" / "missing_link" / "board"
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"


# ---- the property on each runtime -------------------------------------------------------------
def test_the_hash_is_over_the_files_in_the_order_of_their_paths() -> None:
    """fw.hash: path NUL size NUL bytes for each file, sorted by path, first 16 hex digits."""
    files = {"b.py": b"print(2)\n", "a.py": b"x = 1\n", "drivers/c.py": b""}
    want = hashlib.sha256()
    for path in sorted(files):
        want.update(f"{path}\0{len(files[path])}\0".encode() + files[path])
    for order in (sorted(files), sorted(files, reverse=True)):
        h = FirmwareHash()
        for path in order:
            h.add(path, len(files[path]), [files[path][:3], files[path][3:]])
        assert h.digest() == want.hexdigest()[:16]
    short = FirmwareHash()
    short.add("a.py", 99, [b"x"])
    with pytest.raises(ValueError, match=r"a\.py: 1 bytes read, 99 expected"):
        short.digest()


def test_a_virtual_board_is_known_by_its_seed_and_runs_this_runtime() -> None:
    a, b = make_sim("thesis", seed=1), make_sim("thesis", seed=2)
    assert a.properties["board.id"] == "sim-thesis-1" != b.properties["board.id"]
    assert a.properties["fw.hash"] == tree_hash(str(BOARD_PKG)) == b.properties["fw.hash"]
    assert a.properties["fw.version"]
    # the 2014 firmware (emulated) states neither: the host knows it by board.serial
    assert "board.id" not in make_sim("original").properties


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_boards_state_their_chips_id_and_the_hash_of_their_files() -> None:
    """Two simulated chips (host.mjs --seed) have their own machine.unique_id(); fw.hash is the
    hash of the files the board has, computed by the board under MicroPython."""
    sims = [FirmwareSim(RIG, args=["--seed", str(k)]) for k in (1, 2)]
    try:
        props = []
        for sim in sims:
            board = Board.open(sim.url, timeout=3.0)
            props.append(dict(board.properties))
            board.close()
        ids = [hashlib.sha256(b"missing-link sim board %d" % k).digest()[:8].hex() for k in (1, 2)]
        assert [p["board.id"] for p in props] == ids  # the chip's, in hex
        assert [p["board.serial"] for p in props] == ids  # (the board file names no serial)
        # (the runtime's files and the board file it runs: board/identity.py)
        assert props[0]["fw.hash"] == props[1]["fw.hash"] == tree_hash(str(BOARD_PKG), str(RIG))
    finally:
        for sim in sims:
            sim.close()


@pytest.mark.slow
@pytest.mark.micropython
def test_flash_computes_the_hash_the_flashed_board_states(tmp_path: Path) -> None:
    """``flash`` with the real mpremote into MicroPython's own REPL and filesystem
    (tests/serial_board.py), over a board flashed before with a driver this board file does not
    use: that file is gone, and the firmware booted from the flashed files (host.mjs --lib)
    states the fw.hash flash computed before copying; the check after flashing compares it (a
    board that runs other files is refused)."""
    flash_dir = tmp_path / "flash"
    stale = flash_dir / "lib" / "mlboard" / "drivers" / "stale.py"
    stale.parent.mkdir(parents=True)
    stale.write_text("x = 1\n")
    bf = load_board_file(RIG)
    want = staged_hash(micropython_files(bf))
    assert want != tree_hash(str(BOARD_PKG))  # (only the drivers it uses: other files)
    board = SerialBoard(flash_dir)
    said: list[str] = []
    try:
        assert flash(bf, board.port, check=False, say=said.append) == 0
        assert board.wait_gone(30) and board.was_reset
    finally:
        board.close()
    assert not stale.exists()
    lib = flash_dir / "lib" / "mlboard"
    assert tree_hash(str(lib), str(flash_dir / "board.py")) == want
    sim = FirmwareSim(RIG, args=["--lib", str(lib)])
    try:
        said_ok = verify(sim.url, bf, expect={"fw.hash": want})
        assert f"fw.hash {want}" in said_ok and "board.id " in said_ok
        with pytest.raises(FlashError, match=r"the board says fw.hash '[0-9a-f]{16}', "):
            verify(sim.url, bf, timeout=3.0, expect={"fw.hash": "0" * 16})
    finally:
        sim.close()


@pytest.mark.slow
# ---- AVR: the id in the EEPROM, stamped at flash time ------------------------------------------
@pytest.mark.avr
def test_avr_id_goes_into_the_eeprom_and_survives_a_reflash(
    avr_build: Path, tmp_path: Path
) -> None:
    """The image stamped with an id (flash --id), run in simavr with an EEPROM kept across
    power cycles: board.id reads back as stamped; a re-flash of the program (stamped with a
    fresh random id, not forced) keeps it; a forced one replaces it; fw.hash is the image's,
    the same for the same program whatever id it carries."""
    from missing_link.deploy.avrgen import FW_HASH_PLACEHOLDER
    from missing_link.deploy.avrstamp import ID_PLACEHOLDER, firmware_hash, image_of, stamp

    unstamped = avr_build / "uno_rig" / "firmware.unstamped.elf"
    eeprom = tmp_path / "eeprom.bin"

    def flashed(board_id: str | None, force: bool) -> tuple[str, dict[str, str]]:
        elf = tmp_path / f"firmware-{board_id}-{force}.elf"
        fw_hash, _ident = stamp(unstamped, elf, board_id, force)
        sim = AvrSim(avr_build, elf, eeprom=eeprom)
        try:
            board = Board.open(sim.url, timeout=2.0)
            props = dict(board.properties)
            board.close()
        finally:
            sim.power_off()  # (the EEPROM is written to its file)
        return fw_hash, props

    h1, first = flashed("rig-0001", force=False)  # a new board: its EEPROM has no id
    assert first["board.id"] == first["board.serial"] == "rig-0001"
    assert first["fw.hash"] == h1
    h2, again = flashed(None, force=False)  # re-flashed, a fresh random default id
    assert again["board.id"] == "rig-0001" and again["fw.hash"] == h2 == h1
    assert again["clock.epoch"] != first["clock.epoch"]  # (another boot, the same board)
    _h3, forced = flashed("rig-0002", force=True)  # flash --id: the board takes it
    assert forced["board.id"] == "rig-0002"
    # anyone can check an image: its placeholders back in place, hashed
    image = image_of(tmp_path / "firmware-rig-0002-True.elf")
    at = image.index(b"MLID")
    image = image[:at] + ID_PLACEHOLDER + image[at + len(ID_PLACEHOLDER) :]
    assert firmware_hash(image.replace(h1.encode(), FW_HASH_PLACEHOLDER.encode())) == h1


@pytest.mark.slow
@pytest.mark.avr
def test_avr_properties_are_parsed_by_the_host_byte_for_byte(uno_rig: AvrSim) -> None:
    """The properties blob of the AVR firmware, read raw: every key once, board.id in it."""
    board = Board.open(uno_rig.url, timeout=2.0)
    raw = board.read_many("a2jGetProperties")
    board.close()
    fields = raw.split(b"\0")[:-1]
    keys = fields[0::2]
    assert keys == [b"j2a.version", b"board.name", b"board.model", b"board.serial", b"board.id",
                    b"clock.epoch", b"clock.res_us", b"fw.version", b"fw.hash"]  # fmt: skip
    props = dict(zip(fields[0::2], fields[1::2], strict=True))
    assert props[b"board.id"].startswith(b"avr-") and len(props[b"board.id"]) == 16
    assert len(props[b"fw.hash"]) == 16 and int(props[b"fw.hash"], 16) >= 0


# ---- the daemon: status, /diagnostics, recording; names by id ----------------------------------
class Seen(Publisher):
    """Records what the daemon hands a publisher: descriptions and /diagnostics rows."""

    name = "seen"

    def __init__(self) -> None:
        super().__init__()
        self.descriptions: list[BoardDescription] = []
        self.rows: list[dict[str, Any]] = []

    def board_description(self, record: BoardDescription) -> None:
        self.descriptions.append(record)

    def diagnostics(self, status: list[dict[str, Any]], now_ns: int) -> None:
        self.rows = status


@pytest.fixture
def boards() -> Iterator[list[BoardServer]]:
    servers = [start_board_thread(make_sim("thesis", seed=k))[0] for k in (1, 2)]
    yield servers
    for s in servers:
        s.stop()


def test_status_diagnostics_and_the_recording_show_who_the_board_is(
    boards: list[BoardServer],
) -> None:
    seen = Seen()
    cfg = Config(boards=[BoardSpec(boards[0].url)], diagnostics_period=0.05)
    with Daemon(cfg, extra_publishers=[seen]) as d:
        assert d.wait_until_up(10), d.status()
        st = d.status()[0]
        assert st["board_id"] == "sim-thesis-1" and st["serial"] == "sim-thesis-1"
        assert st["fw_hash"] == tree_hash(str(BOARD_PKG)) and st["fw_version"] == "0.1.0"
        assert st["address"] == boards[0].url
        keys = list(st)
        assert keys[keys.index("clock_epoch") + 1 :][:4] == ["board_id", "fw_version",
                                                              "fw_hash", "address"]  # fmt: skip
        assert wait_for(lambda: any(r.get("board_id") == "sim-thesis-1" for r in seen.rows), 5)
        (described,) = seen.descriptions
        props = dict(described.properties)
        assert props["board.id"] == "sim-thesis-1" and props["fw.hash"] == st["fw_hash"]


def test_the_config_names_a_board_by_its_id_whatever_url_it_comes_on(
    boards: list[BoardServer],
) -> None:
    """``[boards.left] id = "sim-thesis-2"``: the board on whatever URL publishes as ``left``,
    its keys from ``[boards.left.config]`` applied; the other keeps its board.name."""
    doc = {"boards": {"left": {"id": "sim-thesis-2", "config": {"dist_ir.rate_hz": 5}}}}
    for order in (boards, boards[::-1]):  # (the same boards on each other's ports: by id)
        cfg = parse_config(doc)
        cfg.boards = [BoardSpec(s.url) for s in order]
        with Daemon(cfg) as d:
            assert d.wait_until_up(10), d.status()
            names = {s["board_id"]: s["board"] for s in d.status()}
            assert names == {"sim-thesis-2": "left", "sim-thesis-1": "thesis"}
            assert d.board_config("left")["dist_ir.rate_hz"] == 5.0
            assert "/left/dist_ir" in d.bus.topics and "/thesis/dist_ir" in d.bus.topics


def test_two_boards_that_state_one_id_are_both_shown_with_a_warning() -> None:
    twins = [start_board_thread(make_sim("thesis", seed=7))[0] for _ in range(2)]
    try:
        cfg = Config(boards=[BoardSpec(s.url) for s in twins])
        with Daemon(cfg) as d:
            assert d.wait_until_up(10), d.status()
            st = d.status()
            assert sorted(s["board"] for s in st) == ["thesis", "thesis_2"]
            for s, other in ((st[0], st[1]), (st[1], st[0])):
                assert s["level"] == 1, s["message"]
                said = "board.id 'sim-thesis-7' is stated by another connected board too"
                assert said in s["warnings"]
                assert other["url"] in s["warnings"]
            d.remove_board(twins[1].url)  # one goes: the other's warning goes with it
            assert wait_for(lambda: "stated by" not in d.status()[0]["warnings"], 5)
    finally:
        for server in twins:
            server.stop()


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ({"boards": {"a": {"id": 5}}}, "boards.a.id: a board.id"),
        ({"boards": {"a": {"id": "has space"}}}, "boards.a.id: a board.id"),
        ({"boards": {"a": {"id": "x"}, "b": {"id": "x"}}}, "'x' is the id of boards.a already"),
        (
            {"boards": {"a": {"serial": "x"}}},
            "has two tables, config and ros ([boards.NAME.config]), and an id",
        ),
    ],
)
def test_ids_in_the_config_are_checked(doc: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        parse_config(doc, "robot.toml")


def test_a_board_without_id_is_known_by_its_serial() -> None:
    from missing_link.daemon.session.status import Identity

    assert Identity.of({"board.serial": "S1"}, "u").board_id == "S1"
    assert Identity.of({"board.serial": "S1", "board.id": "I1"}, "u").board_id == "I1"
