"""What ``missing-link replay`` holds in memory (issue 43.10): its peak RSS (the process's own
VmHWM) while it reads a recording, for recordings of a few sizes: whole, with one sample record
lost early on (its stamps kept), and with board stamps only in their first seconds (before,
what followed a lost sample or came without stamps was held whole: 7.8 MB made 202 MB).
The recordings are a real one (the demo's two virtual boards and one at 1,000 samples a second,
recorded by a daemon for a few seconds) written again end to end until they reach the size.
The reference, measured in the same run on the same files: ``--reference DIR``, another source
tree's replay (its own .venv's Python if it has one, else this one's with DIR/src first), and
the replay of the seed recording itself.

    .venv/bin/python bench/bench_replay.py [--sizes 7.8,23] [--settle 15] [--reference DIR]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import Writer

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.ros.board_record import STAMPS_TYPE
from missing_link.virtual import make_sim, start_board_thread


def seed_recording(out: Path, seconds: float) -> Path:
    """The demo's two boards and a board of 1,000 samples a second, recorded by a daemon."""
    sims = [make_sim("encoder_servo", seed=3), make_sim("rangers", seed=3),
            make_sim("rate", seed=3, name="fast", rate_hz=1000.0)]  # fmt: skip
    servers = [start_board_thread(rt, "tcp://127.0.0.1:0")[0] for rt in sims]
    cfg = Config(boards=[BoardSpec(s.url) for s in servers], publishers=["bus", "mcap"],
                 publisher_options={"mcap": {"path": str(out), "prefix": "seed"}})  # fmt: skip
    try:
        with Daemon(cfg) as d:
            assert d.wait_until_up(10)
            time.sleep(seconds)
    finally:
        for s in servers:
            s.stop()
    (bag,) = out.glob("seed_*")
    (file,) = bag.glob("*.mcap")
    return file


#: how a grown recording differs from its seed's copies
KINDS = {
    "whole": "every sample with its board stamps",
    "one lost": "one sample record lost (its stamps kept), early on",
    "no stamps": "board stamps in the first copy only",
    "bare": "samples and board records only (no ROS views), stamps in the first copy only",
}


def grown(seed: Path, dest: Path, mb: float, kind: str) -> Path:
    """``seed``'s records written again, each copy after the one before, until ``dest`` holds
    about ``mb`` MB, changed as ``kind`` says (KINDS)."""
    with seed.open("rb") as f:
        records = list(make_reader(f).iter_messages(log_time_order=False))  # (file order)
    first = min(m.log_time for _s, _c, m in records)
    span = max(m.log_time for _s, _c, m in records) - first + 1_000_000
    with dest.open("wb") as out:
        w = Writer(out)
        w.start("ros2", "bench")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        k, lost = 0, kind != "one lost"
        while out.tell() < mb * 1e6:
            for s, c, m in records:
                if s is None or (s.name == STAMPS_TYPE and k and kind in ("no stamps", "bare")):
                    continue
                if kind == "bare" and not s.name.startswith("missing_link_msgs/"):
                    continue  # (what a recording of samples only would hold: many more a MB)
                if not lost and c.topic == "/fast/signal":
                    lost = True  # (a sample the recorder never wrote, say)
                    continue
                if s.name not in schemas:
                    schemas[s.name] = w.register_schema(s.name, s.encoding, s.data)
                if c.topic not in channels:
                    channels[c.topic] = w.register_channel(
                        c.topic, c.message_encoding, schemas[s.name], c.metadata
                    )
                t = m.log_time + k * span
                w.add_message(channels[c.topic], log_time=t, data=m.data, publish_time=t)
            k += 1
        w.finish()
    return dest


def python_of(tree: Path | None) -> tuple[str, dict[str, str]]:
    """The Python that runs ``tree``'s replay (None: this tree's) and its environment."""
    env = dict(os.environ)
    if tree is None:
        return sys.executable, env
    own = tree / ".venv" / "bin" / "python"
    if own.exists():
        return str(own), env
    env["PYTHONPATH"] = str(tree / "src")
    return sys.executable, env


def peak_rss(file: Path, settle: float, tree: Path | None, most: float = 600.0) -> float:
    """The replay's peak RSS (MB) while it reads ``file`` (no host: its feeders read ahead as
    far as they may): once it has read the recording through and started its boards, until
    its RSS has not grown for ``settle`` s (at most ``most`` s)."""
    python, env = python_of(tree)
    p = subprocess.Popen(
        [python, "-m", "missing_link", "replay", str(file), "--listen", "tcp://127.0.0.1:0"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    serving = threading.Event()

    def watch() -> None:
        assert p.stderr is not None
        for line in p.stderr:
            if "s of recording" in line:
                serving.set()

    threading.Thread(target=watch, daemon=True).start()
    peak, grew = 0.0, time.monotonic()
    try:
        end = time.monotonic() + most
        while time.monotonic() < end and p.poll() is None:
            for line in Path(f"/proc/{p.pid}/status").read_text().splitlines():
                if line.startswith("VmHWM:"):
                    now = int(line.split()[1]) / 1024
                    if now > peak:
                        peak, grew = now, time.monotonic()
            if serving.is_set() and time.monotonic() - grew > settle:
                break
            time.sleep(0.1)
    finally:
        p.terminate()
        p.wait(10)
    return peak


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="7.8,23", help="MB, comma-separated")
    ap.add_argument("--settle", type=float, default=15.0, help="s without growth that end one")
    ap.add_argument("--seed-s", type=float, default=3.0, help="s of the seed recording")
    ap.add_argument("--reference", type=Path, help="another source tree, measured beside")
    a = ap.parse_args()
    ref = a.reference.resolve() if a.reference else None
    rows: list[tuple[str, str, float, float | None]] = []

    def measure(f: Path, what: str, stamps: str) -> None:
        now = peak_rss(f, a.settle, None)
        rows.append((what, stamps, now, peak_rss(f, a.settle, ref) if ref else None))
        print(rows[-1], file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory() as tmp:
        seed = seed_recording(Path(tmp), a.seed_s)
        measure(seed, f"the seed, {seed.stat().st_size / 1e6:.1f} MB", KINDS["whole"])
        for mb in (float(x) for x in a.sizes.split(",")):
            for kind, what in KINDS.items():
                f = grown(seed, Path(tmp) / f"r{mb}-{kind}.mcap", mb, kind)
                measure(f, f"{f.stat().st_size / 1e6:.1f} MB", what)
                f.unlink()
    print(f"replay's peak RSS, MB (reference: {ref or 'none'})")
    print("| recording | its samples | this tree | reference |")
    print("|---|---|---|---|")
    for what, stamps, now, then in rows:
        print(f"| {what} | {stamps} | {now:.0f} | {'-' if then is None else f'{then:.0f}'} |")


if __name__ == "__main__":
    main()
