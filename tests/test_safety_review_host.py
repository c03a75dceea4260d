"""What an adversarial review of the safety paths found on the host's side, fixed:

* after goodbye nothing more reaches the board: not a timed command sent from the clock map's
  answer, not ``Daemon.call`` or ``trigger_at`` while the session waits for the goodbye's answer;
* the ``[daemon] commands`` allow-list sees through an a2jAt of an a2jAt;
* ``Firmware.run()`` (the loop a device runs) makes every armed actuator safe whatever stops
  it, its waits and deadlines included;
* a board that dials in stating another's id and epoch (both public) does not take its session;
* a board file whose files share a name (key_file = config_file, ...) is refused.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from missing_link import open_board
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config, parse_config
from missing_link.daemon.control.allowlist import CommandRefused, called_function
from missing_link.daemon.intake.dialin import DialIns
from missing_link.daemon.listen_spec import parse_listen
from missing_link.daemon.session.link import Mailbox
from missing_link.daemon.session.status import SessionState
from missing_link.deploy.boardfile import check_board, load_board_file
from missing_link.errors import ConfigError, MissingLinkError
from missing_link.host.board import Board
from missing_link.transport import open_transport
from missing_link.virtual import make_sim, start_board_thread
from missing_link.virtual.boardfile import BoardFileBoard
from missing_link.virtual.server import BoardServer
from missing_link.virtual.world import machine

from .helpers import wait_for
from .test_dial import FakeBoard, FakeSession

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"
#: what moves the board or changes what it does: recorded in the order the board sees them
COMMANDS = ("a2j_set_servo", "a2jAt", "setTrigger", "setTriggerAt", "a2jGoodbye", "a2jConfigSet")


def _recording(rt: Any, slow: dict[str, threading.Event] | None = None) -> list[str]:
    """Wrap the board's command functions so that it notes each call as it takes it; a
    function named in ``slow`` first sets its event, then takes 0.5 s (a slow or signed link's
    round trip: the window the review opened)."""
    seen: list[str] = []
    for name in COMMANDS:
        i = rt.index[name]
        n, kind, handler = rt.functions[i]

        def wrapped(payload: bytes, _h: Any = handler, _n: str = n) -> Any:
            seen.append(_n)
            if slow is not None and _n in slow:
                slow[_n].set()
                time.sleep(0.5)
            return _h(payload)

        rt.functions[i] = (n, kind, wrapped)
    return seen


def _servo(rt: Any) -> Any:
    return next(t for t in rt.transducers if t.name == "servo").driver


def test_once_the_board_was_told_goodbye_no_call_reaches_it() -> None:
    """Between the goodbye and the close the session is still up: Daemon.call, trigger_at and
    configure went through there, and the board acted on them after its goodbye."""
    rt = make_sim("thesis", seed=5, name="thesis")
    seen = _recording(rt)
    server, thread = start_board_thread(rt, "memory://goodbye-window")
    d = Daemon(Config(boards=[BoardSpec(server.url)])).start()
    go = threading.Event()
    try:
        assert d.wait_until_up(10)
        s = d.sessions[0]
        disconnect = s._disconnect

        def held() -> None:  # the supervisor, slow to get round to closing
            go.wait(10)
            disconnect()

        s._disconnect = held  # type: ignore[method-assign]
        s.request_stop()  # goodbye: the board makes everything safe
        assert wait_for(lambda: seen == ["a2jGoodbye"], 5) and s.state == SessionState.UP
        with pytest.raises(MissingLinkError, match="told goodbye"):
            d.call("thesis", "a2j_set_servo", struct.pack("<b", 40), timeout=2.0)
        with pytest.raises(MissingLinkError):
            d.trigger_at(time.time_ns() + 500_000_000, ["thesis"])
        with pytest.raises(MissingLinkError, match="told goodbye"):
            d.configure("thesis", {"servo.safe": "limp"})
        go.set()
        d.stop()
        assert seen == ["a2jGoodbye"] and _servo(rt).commands == 0, seen
    finally:
        go.set()
        d.stop()
        server.stop()
        thread.join(5)


def test_a_timed_command_whose_map_is_answered_after_goodbye_is_not_sent() -> None:
    """actuators.py sent the a2jAt from the a2jHostMap answer's callback: a daemon stopped
    while the map was on its way said goodbye, then sent it, and the servo moved after.  The
    board holds the map's answer until the goodbye has gone out (events, not sleeps: the order
    is the test's, whatever the machine's load)."""
    rt = make_sim("thesis", seed=5, name="thesis")
    seen = _recording(rt)
    k = rt.index["a2jHostMap"]
    name, kind, handler = rt.functions[k]
    hold, asked, release = threading.Event(), threading.Event(), threading.Event()

    def held_map(payload: bytes) -> Any:
        if hold.is_set():
            asked.set()
            release.wait(10)  # (the board answers once the goodbye is out)
        return handler(payload)

    rt.functions[k] = (name, kind, held_map)
    server, thread = start_board_thread(rt, "memory://goodbye-race")
    d = Daemon(Config(boards=[BoardSpec(server.url)])).start()
    refused: list[BaseException] = []
    stopper = threading.Thread(target=d.stop)
    try:
        assert d.wait_until_up(10)
        d.send("/thesis/servo/cmd", -60, at_ns=time.time_ns() + 200_000_000)
        assert wait_for(lambda: _servo(rt).commands == 1, 5)
        hold.set()
        seen.clear()

        def late() -> None:
            try:
                d.send("/thesis/servo/cmd", 60, at_ns=time.time_ns() + 450_000_000)
            except (MissingLinkError, TimeoutError) as e:
                refused.append(e)

        sender = threading.Thread(target=late)
        sender.start()
        assert asked.wait(10)  # the map is on its way
        session = d.sessions[0]
        board = session.board
        stopper.start()
        assert wait_for(lambda: session.farewell.said(board), 10)  # goodbye sent
        release.set()
        sender.join(10)
        stopper.join(10)
        with open_board(server.url) as after:  # (the board took all of the last link's frames
            after.call("a2jEcho")  # before it took this one)
        assert seen == ["a2jGoodbye"], seen  # (before: then an a2jAt, queued after goodbye)
        assert _servo(rt).commands == 1 and refused
    finally:
        release.set()
        if stopper.is_alive():
            stopper.join(10)
        d.stop()
        server.stop()
        thread.join(5)


def test_the_allow_list_sees_through_an_a2jat_of_an_a2jat() -> None:
    functions = ["a2jAt", "servo", "a2jEcho"]
    inner = struct.pack("<qB", 2, 1) + b"\x28"
    nested = struct.pack("<qB", 1, 0) + struct.pack("<qB", 1, 0) + inner
    assert called_function("a2jAt", nested, functions) == "servo"
    assert called_function("a2jAt", struct.pack("<qB", 1, 0), functions) == "a2jAt"
    assert called_function("a2jAt", b"\x01", functions) == "a2jAt"
    rt = make_sim("thesis", seed=5, name="thesis")
    server, thread = start_board_thread(rt, "memory://nested-at")
    try:
        with Daemon(Config(boards=[BoardSpec(server.url)], commands=["/nothing"])) as d:
            assert d.wait_until_up(10)
            b = d.sessions[0].board
            assert b is not None
            now = time.time_ns()
            inner = struct.pack("<qB", now + 1_500_000_000, b.index["a2j_set_servo"]) + b"\x28"
            outer = struct.pack("<qB", now + 500_000_000, b.index["a2jAt"]) + inner
            with pytest.raises(CommandRefused):  # (before: sent, and the servo moved)
                d.call("thesis", "a2jAt", outer)
            assert d.commands.refused == {"api": 1}
    finally:
        server.stop()
        thread.join(5)


# ---- Firmware.run(): the whole loop under the failsafe ------------------------------------------


@pytest.fixture
def world() -> Iterator[None]:
    """The simulated world of one board file (one per process), emptied after the test."""
    assert not machine.WORLD.devices, "the simulated world is taken"
    yield
    machine.WORLD.__init__()  # type: ignore[misc]  # (in place: the world's modules hold it)


def _running_rig(tmp_path: Path) -> tuple[BoardFileBoard, threading.Thread, list[BaseException]]:
    """The rig's firmware in Firmware.run() (as on a device), its servo at -60 with safe =
    limp; what stopped it goes to the list."""
    vb = BoardFileBoard(load_board_file(RIG).board, "tcp://127.0.0.1:0", tmp_path)
    died: list[BaseException] = []

    def serve() -> None:
        try:
            vb.serve_forever()
        except BaseException as e:  # noqa: BLE001 - what the test looks at
            died.append(e)

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    b = Board(open_transport(vb.url), timeout=5.0)
    b.handshake()
    b.configure({"servo.safe": "limp"})
    b.call_ok("a2j_set_servo", struct.pack("<b", -60))
    b.close()
    assert machine.WORLD.pulse_us(15) == 1217
    return vb, t, died


def _boom(what: str) -> Callable[..., Any]:
    def boom(*_args: Any) -> Any:
        raise OSError(what)

    return boom


@pytest.mark.parametrize("where", ["a driver's deadline", "the link's wait"])
def test_whatever_stops_the_firmware_loop_makes_the_actuators_safe_first(
    tmp_path: Path, where: str, world: None
) -> None:
    """run() called rt.next_deadline_us() and link.wait() outside step()'s guard: an error
    there left the firmware stopped with the servo still pulsing."""
    vb, t, died = _running_rig(tmp_path)
    fw = vb.firmware
    if where == "a driver's deadline":
        imu = next(x for x in fw.runtime.transducers if x.name == "imu")
        imu._due = _boom("a driver bug in next_due_us")
    else:
        fw.link.wait = _boom("the link's poll failed")  # type: ignore[method-assign]
    t.join(10)
    assert died and isinstance(died[0], OSError), died  # the firmware stopped ...
    assert machine.WORLD.pulse_us(15) == 0  # ... its servo safe (limp) first
    assert fw.runtime.failsafe.trips == 1


# ---- dial-in: an id and an epoch are claims, not proof ------------------------------------------


def _serve(server: BoardServer) -> threading.Thread:
    t = threading.Thread(target=server.serve_forever, daemon=True)
    t.start()
    return t


def test_a_live_link_that_answers_is_never_replaced_by_a_claim() -> None:
    made: list[FakeSession] = []

    def add(spec: BoardSpec, box: Mailbox) -> Any:
        made.append(FakeSession(spec, box))
        return made[-1]

    cfg = parse_config({"boards": {"left": {"id": "b1"}}})
    d = DialIns(cfg, parse_listen("tcp://127.0.0.1:0"), add)
    try:
        first = FakeBoard("e1")
        assert d.hand_over(first) is None  # type: ignore[arg-type]
        made[0].connect()
        claim = FakeBoard("e1")  # its id and its epoch; the old link answers the probe
        assert d.hand_over(claim) is None  # type: ignore[arg-type]
        assert first.alive and made[0].board is first  # (before: closed, its session handed over)
        assert len(made) == 2 and made[1].box.waiting is claim  # a second board of the id
        first.answers = False  # the old link is dead now: the same boot dialing again
        again = FakeBoard("e1")
        assert d.hand_over(again) is None  # type: ignore[arg-type]
        assert not first.alive and made[0].box.waiting is again and len(made) == 2
    finally:
        d.stop()


@pytest.mark.slow
def test_a_board_that_states_another_boards_id_and_epoch_does_not_take_its_session() -> None:
    cfg = parse_config({"boards": {"arm": {"id": "sim-thesis-4"}}})
    cfg.listen = "tcp://127.0.0.1:0"
    with Daemon(cfg) as d:
        assert d.dialins is not None
        url = f"tcp://127.0.0.1:{d.dialins.listener.port}"
        victim_rt = make_sim("thesis", seed=4)
        victim = BoardServer(victim_rt, url, dial=True)
        threads = [_serve(victim)]
        impostor = None
        try:
            assert wait_for(lambda: bool(d.sessions) and d.wait_until_up(0.1))
            st = d.status()[0]  # what anyone watching sees: the id and the epoch
            imp_rt = make_sim("thesis", seed=99, epoch=st["clock_epoch"])
            imp_rt.set_property("board.id", st["board_id"])
            impostor = BoardServer(imp_rt, url, dial=True)
            threads.append(_serve(impostor))
            # the victim's link answers the probe: the impostor is a second board of that id
            assert wait_for(lambda: len(d.sessions) == 2 and d.wait_until_up(0.1), 20)
            arm = d.session("arm")
            # (before: handed to the impostor)
            assert arm.connects == 1 and arm.state == SessionState.UP
            other = next(s for s in d.sessions if s is not arm)
            assert other.name == "arm_2" and "sim-thesis-4" in "; ".join(other._warnings_now())
            d.call("arm", "a2j_set_servo", struct.pack("<b", 40))
            assert _servo(victim_rt).commands == 1 and _servo(imp_rt).commands == 0
        finally:
            victim.stop()
            if impostor is not None:
                impostor.stop()
            for t in threads:
                t.join(5)


# ---- board files: every file of the board its own ---------------------------------------------


def _board(link: dict[str, Any], **more: Any) -> dict[str, Any]:
    servo = {"name": "servo", "id": 3, "driver": "servo", "pin": 15, "call": "a2j_set_servo"}
    return {"name": "wifi", "mcu": "esp32", "link": link, "transducers": [servo], **more}


@pytest.mark.parametrize(
    "link,more",
    [
        ({"key_file": "mlconfig.bin"}, {}),  # the config file's default name
        ({"key_file": "k.bin", "boot_file": "k.bin"}, {}),
        ({"key_file": "k.bin"}, {"config_file": "k.bin"}),
        ({"key_file": "mlconfig.bin.tmp"}, {}),  # config --save writes there first
        ({"key_file": "mlboots.txt"}, {}),  # the boot counter's default name
        ({"key_file": "k.bin", "replay_file": "k.bin.tmp"}, {}),
    ],
)
def test_a_board_file_whose_files_share_a_name_is_refused(
    link: dict[str, Any], more: dict[str, Any]
) -> None:
    with pytest.raises(ConfigError, match="each file on the board must have a name of its own"):
        check_board(_board({"kind": "tcp", "port": 5000, **link}, **more), "b.py")


def test_a_board_file_with_files_of_their_own_is_taken() -> None:
    link = {"kind": "tcp", "port": 5000, "key_file": "mlkey.bin", "boot_file": "b.txt"}
    check_board(_board(link, config_file="c.bin"), "b.py")
    check_board(_board({"kind": "usb"}, config_file="mlboots.txt"), "b.py")  # (no boot file)
