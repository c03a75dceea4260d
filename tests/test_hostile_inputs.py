"""Files given as input are input (issue 34): key and token files are read capped and only when
regular (``/dev/zero`` never ends, a FIFO blocks), a TOML file nested thousands deep, a board
file whose ``link.kind`` is a list and two boards of one name are one-line errors, exit 2
(docs/cli.md), never a RecursionError or TypeError traceback."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from missing_link.daemon.config import load_config
from missing_link.deploy.boardfile import load_board_file
from missing_link.descriptors import load_descriptor_file
from missing_link.errors import BadURL, ConfigError, DescriptorError
from missing_link.publishers.web import parse_options
from missing_link.transport.signed import load_key

from .helpers import ml

DEEP = "a = " + "[" * 5000 + "]" * 5000 + "\n"


def test_key_and_token_files_are_regular_and_capped(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # (nobody writes: a plain read would block for ever)
    big = tmp_path / "big"
    big.write_bytes(b"0" * 2**20)
    big.chmod(0o600)
    for path, why in (("/dev/zero", "not a regular file"), (str(fifo), "not a regular file"),
                      (str(big), "at most")):  # fmt: skip
        with pytest.raises(BadURL, match=f"signing key {path}: .*{why}"):
            load_key(path)
    with pytest.raises(ConfigError, match="token_file /dev/zero: cannot read: not a regular"):
        parse_options({"token_file": "/dev/zero"})
    with pytest.raises(ConfigError, match=r"token_file .*fifo: cannot read: not a regular"):
        parse_options({"token_file": str(fifo)})


def test_deep_toml_is_a_config_error(tmp_path: Path) -> None:
    cfg = tmp_path / "deep.toml"
    cfg.write_text(DEEP)
    with pytest.raises(ConfigError, match=r"deep\.toml: not valid TOML: nested too deeply"):
        load_config(str(cfg))
    with pytest.raises(DescriptorError, match="nested too deeply"):
        load_descriptor_file(str(cfg))


@pytest.mark.slow  # (a process of its own)
def test_deep_toml_is_one_line_and_exit_2(tmp_path: Path) -> None:
    cfg = tmp_path / "deep.toml"
    cfg.write_text(DEEP)
    got = ml("run", "--config", str(cfg), "--duration", "0.1")
    assert got.returncode == 2 and got.stderr.splitlines() == [
        f"missing-link: error: {cfg}: not valid TOML: nested too deeply"
    ], got.stderr


def test_two_boards_of_one_name_are_refused(tmp_path: Path) -> None:
    cfg = tmp_path / "dup.toml"
    cfg.write_text('[[board]]\nurl = "tcp://127.0.0.1:1"\nname = "a"\n'
                   '[[board]]\nurl = "tcp://127.0.0.1:2"\nname = "a"\n')  # fmt: skip
    with pytest.raises(ConfigError, match=r"\[\[board\]\] #2.name: 'a': another \[\[board\]\]"):
        load_config(str(cfg))


def test_a_link_kind_that_is_not_a_name_is_a_config_error(tmp_path: Path) -> None:
    f = tmp_path / "b.py"
    f.write_text('BOARD = {"name": "b", "mcu": "rp2040", "link": {"kind": ["usb"]}, '
                 '"transducers": []}\n')  # fmt: skip
    with pytest.raises(ConfigError, match="link must be"):
        load_board_file(f)


@pytest.mark.slow  # (a process of its own)
def test_replay_prints_no_escape_from_a_recording(tmp_path: Path) -> None:
    """A recording is anyone's file: a board named with terminal escapes (a title, colours, a
    line forged after ``\\r``) reaches the terminal of ``replay`` cleaned."""
    import signal
    import subprocess

    from missing_link.descriptors import parse_transds
    from missing_link.publishers.mcap import McapPublisher
    from missing_link.ros.board_record import BoardDescription
    from missing_link.topics import Topic, Update

    from .helpers import ML

    name = "evil\x1b]0;TITLE\x07\x1b[31mRED\x1b[0m\rforged: all good\x1b[K"
    (t,) = parse_transds("transds/1\nx,0,p,M,1,int32_t,-1\n")
    topic = Topic.for_transducer("/evil/x", name, t, "missing_link_msgs")
    pub = McapPublisher({"path": str(tmp_path), "chunk_s": 3600})
    pub.add_topic(topic)
    info = {"board.name": name, "j2a.version": "2"}
    pub.board_description(BoardDescription.of(name, "tcp://x", ["a2jGetMapping", "a2jMany"],
                                              info, [t], ["/evil/x"]))  # fmt: skip
    for i in range(20):
        pub.publish(Update.build(topic=topic, board_us=[i * 1000], host_ns=[10**18 + i * 10**6],
                                 values=[i], seq=i, lost=0, recv_ns=i))  # fmt: skip
    pub.close()
    p = subprocess.Popen([*ML, "replay", str(pub.bags[0]), "--listen", "tcp://127.0.0.1:0"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    assert p.stderr is not None
    try:
        first = p.stderr.readline()  # (the board's line, then a SIGTERM ends it)
        p.send_signal(signal.SIGTERM)
        _out, rest = p.communicate(timeout=30)
    finally:
        p.kill()
    err = first + rest
    assert b"forged: all good" in err and b"samples" in first, err
    assert not any(c < 32 and c != 10 for c in err), err
