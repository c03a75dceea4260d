"""``recover`` on hostile files (publishers/recover.py): a bad schema costs its own channel, not
what was salvaged; a zstd bomb is stopped by a size cap; every failure is one line with exit 2.
What was salvaged is read back with the ``mcap`` package's reader, which shares nothing with
the writer (rosbags) or the salvaging reader's code paths past the record parser."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import pytest
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Header, Message, Schema
from rosbags.typesys import Stores, get_typestore

from missing_link.publishers.recover import MAX_CHUNK, RecoverError, recover_bag

MAGIC = b"\x89MCAP0\r\n"
STRING = "string data\n"
TS = get_typestore(Stores.ROS2_JAZZY)


def cdr(text: str) -> bytes:
    msg = TS.types["std_msgs/msg/String"](data=text)
    return bytes(TS.serialize_cdr(msg, "std_msgs/msg/String"))


def records(*recs: object) -> bytes:
    b = RecordBuilder()
    for r in recs:
        r.write(b)  # type: ignore[attr-defined]
    return b.end()


def schema(sid: int, name: str, data: bytes) -> Schema:
    return Schema(id=sid, name=name, encoding="ros2msg", data=data)


def channel(cid: int, sid: int, topic: str) -> Channel:
    return Channel(id=cid, schema_id=sid, topic=topic, message_encoding="cdr", metadata={})


def message(cid: int, seq: int, data: bytes) -> Message:
    return Message(channel_id=cid, sequence=seq, log_time=1_000 + seq, publish_time=1_000 + seq,
                   data=data)  # fmt: skip


def mcap_file(path: Path, *recs: object, tail: bytes = b"") -> Path:
    """A recording that died: magic, header, the records, no summary, no footer."""
    path.write_bytes(MAGIC + records(Header(profile="ros2", library="test"), *recs) + tail)
    return path


def good(first: int, n: int) -> list[Message]:
    return [message(1, k, cdr(f"good {k}")) for k in range(first, first + n)]


def read_back(bag: Path) -> list[tuple[str, bytes]]:
    (f,) = bag.glob("*.mcap")
    with open(f, "rb") as stream:
        return [(ch.topic, m.data) for _s, ch, m in make_reader(stream).iter_messages()]


def test_a_bad_schema_loses_its_own_channel_only(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    src = mcap_file(
        tmp_path / "died.mcap",
        schema(1, "std_msgs/msg/String", STRING.encode()),
        channel(1, 1, "/good"),
        *good(0, 5),
        schema(2, "evil/msg/X", b"this is \x1b[2J not ! a msg {{{"),
        channel(2, 2, "/bad"),
        message(2, 0, b"x"),
        schema(3, "evil/msg/Y", b"\xff\xfe not utf-8"),
        channel(3, 3, "/worse"),
        message(3, 0, b"y"),
        channel(4, 99, "/no_schema"),  # a channel whose schema never came
        message(4, 0, b"z"),
        message(7, 0, b"w"),  # a message whose channel never came
        *good(5, 5),
        message(2, 1, b"x"),
    )
    with caplog.at_level(logging.WARNING):
        dest, count = recover_bag(src, tmp_path / "out")
    assert count == 10
    assert read_back(dest) == [("/good", cdr(f"good {k}")) for k in range(10)]
    said = [r.getMessage() for r in caplog.records]
    assert any("2 message(s) of /bad" in m for m in said), said
    assert any("1 message(s) of /worse" in m for m in said), said
    assert all("\x1b" not in m for m in said)


def bomb(size: int = 2**30) -> bytes:
    """``size`` zero bytes, zstd-compressed: 1 GiB is ~32 KB."""
    z = zstandard.ZstdCompressor(level=3).compressobj()
    piece = bytes(2**20)
    return b"".join([*(z.compress(piece) for _ in range(size // len(piece))), z.flush()])


def zstd_chunk(data: bytes, claimed: int) -> Chunk:
    return Chunk(compression="zstd", data=data, message_start_time=0, message_end_time=0,
                 uncompressed_crc=0, uncompressed_size=claimed)  # fmt: skip


#: ``missing-link ARGS`` that writes its own peak RSS (KiB) to the file ``sys.argv[1]`` as it
#: exits: VmHWM, its own address space's high-water mark.  Not the ru_maxrss of wait4 (or its
#: own getrusage): exec keeps the high-water mark of the address space it replaced, the test
#: process's (shared by vfork, copied by fork), so that figure is pytest's peak when it is larger.
PEAK_AT_EXIT = """
import atexit, runpy, sys
out = sys.argv.pop(1)
def peak():
    with open("/proc/self/status") as f:
        kib = [line.split()[1] for line in f if line.startswith("VmHWM:")][0]
    with open(out, "w") as f:
        f.write(kib)
atexit.register(peak)
runpy.run_module("missing_link", run_name="__main__", alter_sys=True)
"""


def run_recover(*args: str, tmp: Path) -> tuple[int, str, int]:
    """``missing-link recover ARGS`` in a process of its own: exit code, stderr, peak RSS (KiB)."""
    peak = tmp / "peak_kib"
    p = subprocess.run(
        [sys.executable, "-c", PEAK_AT_EXIT, str(peak), "recover", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        timeout=300,
    )
    return p.returncode, p.stderr, int(peak.read_text())


@pytest.mark.slow
def test_a_zstd_bomb_is_stopped_by_the_size_cap(tmp_path: Path) -> None:
    """A 32 KB chunk that decompresses to a gigabyte: claimed (refused before any work) or
    hidden behind a small claim (stopped one byte past it); the messages around it are
    salvaged, and the process never holds the gigabyte."""
    boom = bomb()
    assert len(boom) < 64 * 1024
    inner = records(schema(1, "std_msgs/msg/String", STRING.encode()), channel(1, 1, "/good"))
    plain_inner = inner + records(*good(0, 3))
    src = mcap_file(
        tmp_path / "bomb.mcap",
        zstd_chunk(zstandard.ZstdCompressor().compress(plain_inner), len(plain_inner)),
        zstd_chunk(boom, 2**30),
        zstd_chunk(boom, 2**20),
        *good(3, 3),
    )
    code, err, peak_kib = run_recover(str(src), "--out", str(tmp_path / "out"), tmp=tmp_path)
    assert code == 0, err
    assert read_back(tmp_path / "out") == [("/good", cdr(f"good {k}")) for k in range(6)]
    assert "2 chunk(s) skipped" in err and "Traceback" not in err
    print("peak RSS of recover:", peak_kib, "KiB")
    assert peak_kib * 1024 < MAX_CHUNK + 300 * 2**20, peak_kib  # (never near the gigabyte)
    # a file that is nothing but a bomb: nothing to recover, one line, exit 2
    only = mcap_file(tmp_path / "only.mcap", zstd_chunk(boom, 2**30))
    code, err, _ = run_recover(str(only), "--out", str(tmp_path / "none"), tmp=tmp_path)
    errors = [x for x in err.splitlines() if x.startswith("missing-link: error:")]
    assert code == 2 and len(errors) == 1 and "nothing to recover" in errors[0], err
    assert "Traceback" not in err and not (tmp_path / "none").exists()


@pytest.mark.slow
@pytest.mark.parametrize(
    "content",
    [
        b"not an mcap file at all",
        MAGIC + b"\x03" + (2**63).to_bytes(8, "little") + b"huge claimed record",
        MAGIC + b"\x07" + (50).to_bytes(8, "little") + b"\xff" * 50,  # a chunk of nonsense
    ],
)
def test_hostile_files_are_one_line_and_exit_2(tmp_path: Path, content: bytes) -> None:
    f = tmp_path / "hostile.mcap"
    f.write_bytes(content)
    with pytest.raises(RecoverError):
        recover_bag(f, tmp_path / "a")
    code, err, _ = run_recover(str(f), "--out", str(tmp_path / "b"), tmp=tmp_path)
    assert code == 2 and "Traceback" not in err
    assert [x for x in err.splitlines() if x.startswith("missing-link: error:")] == [
        err.strip().splitlines()[-1]
    ]


def test_a_length_past_the_end_of_the_file_is_where_it_stops(tmp_path: Path) -> None:
    """A chunk whose records length says 2**62 (one damaged field): what came before is
    recovered, the rest is where the file stops, and no read asks for 2**62 bytes
    (MemoryError, a traceback); replay reads recordings the same way (complete_messages)."""
    import struct

    inner = records(schema(1, "std_msgs/msg/String", STRING.encode()), channel(1, 1, "/good"))
    inner += records(*good(0, 3))
    plain = Chunk(compression="", data=inner, message_start_time=0, message_end_time=0,
                  uncompressed_crc=0, uncompressed_size=len(inner))  # fmt: skip
    body = struct.pack("<QQQII", 0, 0, 10, 0, 0) + struct.pack("<Q", 2**62) + b"x" * 10
    src = mcap_file(
        tmp_path / "long.mcap", plain, tail=b"\x06" + struct.pack("<Q", len(body)) + body
    )
    dest, count = recover_bag(src, tmp_path / "out")
    assert count == 3
    assert read_back(dest) == [("/good", cdr(f"good {k}")) for k in range(3)]
