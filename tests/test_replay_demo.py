"""The demo replayed, in its own processes (slow): the replay of a recording is the recording
again, sample for sample and spacing for spacing, and a recording cut by SIGKILL replays
(in-process replays: tests/test_replay.py)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
from pathlib import Path
from typing import Any

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.publishers.recover import count_complete
from missing_link.topics import Update

from .helpers import ML, ml, wait_for
from .test_replay import _sifs_in, read_bag, values


# ---- the demo, in its own processes (slow) -----------------------------------------------------
def run_replay(bag: Path, *args: str) -> tuple[subprocess.Popen[str], list[str]]:
    p = subprocess.Popen([*ML, "replay", str(bag), *args], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)  # fmt: skip
    assert p.stdout is not None
    urls = []
    for _ in range(2):
        line = p.stdout.readline()
        assert line.startswith("LISTENING "), (line, p.stderr.read() if p.stderr else "")
        urls.append(line.split()[1])
    return p, urls


def record_replay(bag: Path, out: Path, *args: str) -> tuple[Path, str, list[int], int]:
    """Replay the demo's recording in a process of its own, record it with a daemon running
    the demo's application (encoder -> servo), until the replay says it is done: the new
    recording, what the replay said, the commands the bus took, and how many it refused (the
    board down: a daemon whose handshake lost a reply on a busy machine connects again)."""
    from missing_link.cli.rig import COUNTS_PER_STEP, ENCODER_TOPIC, SERVO_CMD

    p, urls = run_replay(bag, *args)
    steered: list[int] = []
    refused: list[KeyError] = []
    lines: list[str] = []
    try:
        cfg = Config(boards=[BoardSpec(u) for u in urls], publishers=["bus", "mcap"],
                     publisher_options={"mcap": {"path": str(out), "prefix": "again"}})  # fmt: skip
        with Daemon(cfg) as d:

            def steer(u: Update) -> None:  # the demo's application, unchanged (cli/rig.py)
                count = u.values[0]
                if count is not None:
                    value = max(-127, min(127, int(count) // COUNTS_PER_STEP))
                    try:
                        d.send(SERVO_CMD, value)
                    except KeyError as e:  # (no command topic while the board is down)
                        refused.append(e)
                        return
                    steered.append(value)

            d.subscribe(ENCODER_TOPIC, steer)
            assert p.stderr is not None
            reader = threading.Thread(target=lambda: lines.extend(p.stderr or []), daemon=True)
            reader.start()
            assert wait_for(lambda: any("finished" in ln for ln in lines), 60), lines
            # (the last SIFs through the pty and the daemon: as many as the replay sent)
            (done,) = [ln for ln in lines if "finished" in ln]
            sent = sum(int(n) for n in re.findall(r" (\d+)[,;]", done.split("sent:")[1]))
            assert wait_for(lambda: _sifs_in(d) >= sent, 30), (sent, _sifs_in(d), d.status())
    finally:
        p.send_signal(signal.SIGINT)
        p.wait(10)
        reader.join(5)
    (again,) = out.glob("again_*")
    return again, "".join(lines), steered, len(refused)


def sample_bounds(bag: dict[str, list[tuple[int, Any]]], topic: str) -> list[int]:
    """Each sample's hard clock bound on ``topic`` (ns; -1: none), as the daemon published it
    (``Update.bound_ns``, kept in the board's stamps: docs/recording.md): the truth of its
    newest measurement, which its log time is, lies within it.  An all-N/A sample is logged just
    after the one before it (sample_path.py): it has that one's bound."""
    board = topic.split("/")[1]
    bounds = [int(b) for _t, m in bag[f"/{board}/stamps"]
              for i, b in zip(m.topic, m.bound_ns, strict=True)
              if m.topics[i] == topic]  # fmt: skip
    assert len(bounds) == len(bag[topic]), (topic, len(bounds), len(bag[topic]))
    for k, (_t, m) in enumerate(bag[topic]):
        if k and not any(t.sec or t.nanosec for t in m.times):
            bounds[k] = bounds[k - 1]
    return bounds


def spacing(orig: list[tuple[int, int]], new: list[tuple[int, int]]) -> tuple[int, int, int]:
    """Consecutive samples' host-time spacing, original vs replay, each sample as (log time,
    its bound): (worst excess of |difference| over its allowance ns, pairs compared, pairs
    without a clock map).  Each recording's two samples are each within their bound of the
    truth, and the truth's spacing is the boards' stamps' in both: the allowance is the four
    bounds.  A sample's bound is the published map's, not the estimate's in the clock record:
    the published map slews towards a new estimate at most 500 ppm faster (docs/timesync.md),
    so after a start whose first estimate was off by a few ms on a busy machine it stays that
    far off for seconds (measured: 5.6 ms 1.5 s in, beside busy processes, against an estimate
    bound of 0.19 ms), and the daemon sets a sample it maps after its own receipt to the
    receipt (``future_clamps``): one sample then moves against its neighbours by up to its bound."""
    worst, n, unmapped = -(2**63), 0, 0
    for k in range(1, len(orig)):
        bounds = (orig[k][1], orig[k - 1][1], new[k][1], new[k - 1][1])
        if min(bounds) < 0:
            unmapped += 1  # (no map yet: a receive time, no bound to hold it to)
            continue
        diff = abs((new[k][0] - new[k - 1][0]) - (orig[k][0] - orig[k - 1][0]))
        worst = max(worst, diff - sum(bounds))
        n += 1
    return worst, n, unmapped


@pytest.mark.slow
def test_the_demo_replayed_is_the_demo(tmp_path: Path) -> None:
    r = subprocess.run([*ML, "demo", "--duration", "4", "--record", str(tmp_path / "demo")],
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    (bag,) = (tmp_path / "demo").glob("demo_*")
    original = read_bag(bag)
    before = values(original)
    again_bag, said, steered, refused = record_replay(bag, tmp_path / "x1")
    again = read_bag(again_bag)
    after = values(again)
    assert set(after) == set(before) and len(before) == 4
    for topic, rows in before.items():
        assert after[topic] == rows, topic  # the same count, the same values, in order
        orig_t = [t for t, _m in original[topic]]
        new_t = [t for t, _m in again[topic]]
        orig_s = list(zip(orig_t, sample_bounds(original, topic), strict=True))
        new_s = list(zip(new_t, sample_bounds(again, topic), strict=True))
        worst, pairs, unmapped = spacing(orig_s, new_s)
        assert pairs > 0 and worst <= 0, (topic, worst, pairs, unmapped)
    # the application ran on the replay: its commands are in the new recording, and the board
    # took them
    assert [m.values[0] for _t, m in again["/board_a/servo/cmd"]] == steered
    measured = [m for _t, m in again["/board_a/quad"] if m.times[0].sec or m.times[0].nanosec]
    # (N/A: a zero stamp; the app skips those)
    assert len(steered) + refused == len(measured) and len(steered) > 0
    assert "command(s) taken (servo" in said and "0 command(s) taken" in said  # (board_b)
    # ten times as fast: the same counts and order
    fast_bag, said, _, _ = record_replay(bag, tmp_path / "x10", "--rate", "10")
    fast = values(read_bag(fast_bag))
    for topic, rows in before.items():
        assert fast[topic] == rows, topic


@pytest.mark.slow
def test_a_recording_cut_by_sigkill_replays(tmp_path: Path) -> None:
    p = subprocess.Popen([*ML, "demo", "--duration", "60", "--record", str(tmp_path / "cut")],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True)  # fmt: skip
    try:
        assert wait_for(lambda: any((tmp_path / "cut").glob("demo_*/*.mcap")), 30)
        (f,) = (tmp_path / "cut").glob("demo_*/*.mcap")
        # a few chunks complete on disk (a size alone can be a chunk still being written)
        assert wait_for(lambda: count_complete(f.parent) > 2000, 30)
    finally:
        os.killpg(p.pid, signal.SIGKILL)  # the demo and its two board processes
        p.wait(10)
    r = ml("recover", str(f.parent), "--out", str(tmp_path / "saved"))
    assert r.returncode == 0, r.stderr
    saved = read_bag(tmp_path / "saved")
    again_bag, said, _, _ = record_replay(tmp_path / "saved", tmp_path / "x")
    assert "without board stamps" not in said, said
    before, after = values(saved), values(read_bag(again_bag))
    assert set(before) == set(after)
    for topic, rows in before.items():
        assert after[topic] == rows, topic
