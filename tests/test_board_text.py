"""Every string a board controls is text on every output (issue 43.6): a board that refuses an
update with escape sequences (a new window title, a cleared screen, a forged success line
after ``\\r``) gets its words through, cleaned, and nothing else: in the CLI's one error line,
the daemon's log, ``/<board>/log`` in the recording and every face that shows the board's log
(the web console, ``/rosout``: they read the same ``LogLine``).  One mechanism, text.py's
``clean``, at the two doors every such string leaves by: an error's message
(``MissingLinkError.__str__``) and a log line (``LogLine``); the log handler cleans every line
again (logs.py).  Before, ``missing-link update`` printed the refusal raw and the same bytes
went into the recording."""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from missing_link.board.boot import Boot
from missing_link.board.runtime import BoardRuntime
from missing_link.board.update import UpdateReceiver
from missing_link.cli.main import main
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.errors import BoardError, MissingLinkError
from missing_link.host.board_log import LogLine

from .test_update import MODEL, ROVER, _slot

Serve = Callable[..., Any]
HOSTILE = (
    "\x1b]0;pwned\x07\x1b[2J\x1b[H\rupdate: done\x1b[32m, the board runs 9.9.9\x1b[0m\n\x9b31m"
)
#: what must never reach a terminal or a file: C0 and C1 controls, DEL
CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f-\x9f]")


class RefusingReceiver(UpdateReceiver):  # type: ignore[misc]
    """A board that refuses every update with words of its choosing."""

    def _begin(self, payload: bytes) -> tuple[int, bytes]:
        self.rt.log.line(30, "refused: " + HOSTILE)
        return 0xFF, HOSTILE.encode()


def test_an_error_and_a_log_line_are_text_whatever_they_are_made_of() -> None:
    e = BoardError("rover", "the board refused the update: " + HOSTILE)
    assert not CONTROL.search(str(e)) and "update: done, the board runs 9.9.9" in str(e)
    assert isinstance(e, MissingLinkError)
    line = LogLine(board="rover", level=30, text=HOSTILE, source="\x1b[2Jx")
    assert not CONTROL.search(line.text + line.source) and "update: done" in line.text


@pytest.fixture
def refusing(serve: Serve, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    flash = tmp_path / "flash"
    flash.mkdir()
    monkeypatch.chdir(flash)
    _slot(flash, "flash")
    rt = BoardRuntime("rover", MODEL, "s1", epoch="e")
    RefusingReceiver(rt, {"mcu": "rp2040"}, Boot("flash"))
    run = tmp_path / "run"
    run.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(run))
    monkeypatch.delenv("MISSING_LINK_CONTROL", raising=False)
    yield serve(rt).url


def test_an_update_refused_with_escape_sequences_is_text_everywhere(
    refusing: str, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    record = tmp_path / "rec"
    cfg = Config(
        boards=[BoardSpec(refusing)],
        publishers=["bus", "mcap"],
        publisher_options={"mcap": {"path": str(record)}},
        control=os.path.join(os.environ["XDG_RUNTIME_DIR"], "missing-link", "control.sock"),
    )
    lines: list[LogLine] = []
    with Daemon(cfg) as d:
        d.subscribe_logs(lines.append, queue=0)
        assert d.wait_until_up(10), d.failures()
        assert main(["update", "rover", str(ROVER)]) == 1
    out, err = capfd.readouterr()
    said = [x for x in err.splitlines() if x.startswith("missing-link: error:")]
    assert len(said) == 1 and "update: done, the board runs 9.9.9" in said[0], err
    assert not CONTROL.search(out + err.replace("\n", "")), repr(err)
    assert lines and all(not CONTROL.search(x.text) for x in lines), lines
    (bag,) = [p for p in record.iterdir() if p.is_dir()]
    (path,) = bag.glob("*.mcap")
    store = get_typestore(Stores.ROS2_JAZZY)
    texts = []
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic == "/rover/log":
                if schema.name not in store.types:
                    store.register(get_types_from_msg(schema.data.decode(), schema.name))
                texts.append(store.deserialize_cdr(message.data, schema.name).message)
    assert any("firmware update refused" in t and "update: done" in t for t in texts), texts
    assert all(not CONTROL.search(t) for t in texts), texts
