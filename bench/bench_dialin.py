"""What boards that dial in once and leave cost a daemon (issue 43.4): ``missing-link run --listen``
in a process of its own; N boards (virtual, each its own board.id, none named in the config)
dial it, eight at a time, each until its session is up (or it is refused), then leave.  The
daemon's threads, resident memory and CPU (its own /proc, over an idle window) with no board yet
(the reference, same run), right after the N have left, and once ``[daemon] dialin_expire`` has
passed.

    .venv/bin/python bench/bench_dialin.py [--ids 1000] [--expire 10] [--max 64]
    .venv/bin/python bench/bench_dialin.py --ids 1000 --daemon-src DIR   # another tree's daemon

``--daemon-src`` runs the daemon from another checkout's ``src`` (one before the bound: its
config has no dialin_expire or dialin_max, so none is given).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from missing_link.daemon.control.endpoint import ask
from missing_link.virtual import make_sim
from missing_link.virtual.server import BoardServer

TICK = os.sysconf("SC_CLK_TCK")


def proc_figures(pid: int, window: float) -> tuple[int, float, float]:
    """(threads, RSS MB, % of a core over ``window`` s) of process ``pid``."""

    def cpu() -> float:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / TICK  # utime + stime

    c0, t0 = cpu(), time.monotonic()
    time.sleep(window)
    c1, t1 = cpu(), time.monotonic()
    status = dict(
        line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
    )
    threads = int(status["Threads"])
    rss = int(status["VmRSS"].split()[0]) / 1024
    return threads, rss, (c1 - c0) / (t1 - t0) * 100


def start_daemon(
    tmp: Path, expire: float | None, cap: int | None, src: str | None
) -> tuple[subprocess.Popen[str], int, str]:
    """The daemon listening on a free loopback port, its control endpoint in ``tmp``."""
    control = str(tmp / "control.sock")
    bound = "".join(
        f"{k} = {v}\n" for k, v in (("dialin_expire", expire), ("dialin_max", cap)) if v is not None
    )
    cfg = tmp / "daemon.toml"
    cfg.write_text(f'[daemon]\nlisten = "tcp://127.0.0.1:0"\ncontrol = "{control}"\n{bound}')
    env = dict(os.environ)
    if src:
        env["PYTHONPATH"] = src
    p = subprocess.Popen(
        [sys.executable, "-m", "missing_link", "run", "--config", str(cfg)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert p.stderr is not None
    for line in p.stderr:  # ("missing-link: boards dial in at tcp://127.0.0.1:PORT ...")
        if "dial in at tcp://127.0.0.1:" in line:
            port = int(line.split("tcp://127.0.0.1:")[1].split()[0].rstrip(",)"))
            threading.Thread(target=p.stderr.read, daemon=True).start()  # (drained)
            return p, port, control
    raise RuntimeError("the daemon did not say where it listens")


def dial_once(port: int, control: str, k: int, deadline_s: float = 10.0) -> bool:
    """Board ``bench-k`` dials until its session is up (True), or is refused (False); then it
    leaves."""
    board_id = f"bench-{k}"
    rt = make_sim("rate", seed=k, name=f"b{k}", board_id=board_id)
    server = BoardServer(rt, f"tcp://127.0.0.1:{port}", dial=True)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    up = False
    try:
        end = time.monotonic() + deadline_s
        while time.monotonic() < end and not up:
            found = ask(control, {"op": "find", "board": f"dial://{board_id}"}, 5.0)
            up = found.get("state") == "up"
            time.sleep(0.01)
    finally:
        server.stop()
        thread.join(5)
    return up


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ids", type=int, default=1000)
    ap.add_argument("--expire", type=float, default=10.0, help="[daemon] dialin_expire (s)")
    ap.add_argument("--max", type=int, default=64, help="[daemon] dialin_max")
    ap.add_argument("--window", type=float, default=10.0, help="s of idle CPU measured")
    ap.add_argument("--daemon-src", help="run the daemon from this src (before the bound)")
    a = ap.parse_args()
    old = a.daemon_src is not None
    with tempfile.TemporaryDirectory() as tmp:
        p, port, control = start_daemon(
            Path(tmp), None if old else a.expire, None if old else a.max, a.daemon_src
        )
        try:
            time.sleep(2.0)
            ref = proc_figures(p.pid, a.window)
            t0 = time.monotonic()
            with ThreadPoolExecutor(8) as pool:  # (eight boards dialing at a time)
                up = sum(pool.map(lambda k: dial_once(port, control, k, 5.0), range(a.ids)))
            took = time.monotonic() - t0
            left = proc_figures(p.pid, a.window)
            rows = [
                ("listening, no board (reference)", ref),
                (f"{a.ids} ids dialed once and left", left),
            ]
            if not old:
                time.sleep(max(0.0, a.expire + 2.0 - a.window))
                rows.append(
                    (f"... and {a.expire:g} s later (dialin_expire)", proc_figures(p.pid, a.window))
                )
        finally:
            p.terminate()
            p.wait(10)
    print(f"{up} of {a.ids} boards were taken in ({took:.0f} s)")
    print("| daemon | threads | RSS MB | % of a core (idle) |")
    print("|---|---|---|---|")
    for what, (threads, rss, cpu) in rows:
        print(f"| {what} | {threads} | {rss:.0f} | {cpu:.1f} |")


if __name__ == "__main__":
    main()
