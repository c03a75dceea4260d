"""The web console in a real browser: Playwright driving Debian's Chromium (scripts/system-deps.sh)
against ``missing-link run --web`` with the demo's two boards, each in a process of its own.

Both boards appear within 5 s, values change, a rate set on the page (keyboard only) reaches the
board (read back with ``missing-link config``), actuator controls exist only where commands are
on and the server refuses a forged command where they are off, and a board whose process is
stopped shows as lost within ``link_timeout + 1 s``.  The screenshots docs/web.md shows are taken
here: ``ML_WEB_SCREENSHOTS=docs pytest tests/test_web_browser.py`` writes them into docs/.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from missing_link.daemon.config import BoardSpec
from missing_link.testing import wait_for
from missing_link.virtual.process import start_board_process, stop_process
from missing_link.world.datasheets import DLPF_DEFAULT, FIGURES, G, imu_sigmas

from .helpers import ML, ml

pytestmark = pytest.mark.slow

CHROMIUM = "/usr/bin/chromium"
FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]  # fmt: skip
LINK_TIMEOUT = BoardSpec.link_timeout  # (the default: the config below does not change it)
RIG = Path(__file__).resolve().parent.parent / "examples" / "boards" / "thesis-rig.py"


@contextmanager
def daemon(
    tmp: Path, boards: dict[str, str], web: str = "", more: str = ""
) -> Iterator[tuple[str, dict[str, str]]]:
    """``missing-link run`` of ``boards`` (name -> sim) with the console on a free loopback port
    (``web``: more of its [web] table; ``more``: more of the configuration, e.g. ``[[board]]``
    tables) and a recording; its URL and the environment that reaches its control endpoint."""
    procs, urls = [], []
    env = {**os.environ, "MISSING_LINK_CONTROL": str(tmp / "control.sock")}
    config = tmp / "daemon.toml"
    config.write_text(
        f'[daemon]\npublishers = ["bus", "mcap", "web"]\n[mcap]\npath = "{tmp / "rec"}"\n'
        f"[web]\nport = 0\n{web}\n{more}\n"
    )
    daemon_proc = None
    try:
        for name, sim in boards.items():
            if sim.endswith(".py"):  # (a board file: its parts simulated from their datasheets)
                proc, url = board_file_process(sim)
            else:
                proc, url = start_board_process(sim, 0, "tcp://127.0.0.1:0", name=name)
            procs.append(proc)
            urls.append(url)
        cmd = [*ML, "run", *urls, "--config", str(config)]
        daemon_proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, env=env)
        lines: list[str] = []
        found = threading.Event()

        def drain() -> None:  # (read all of stderr: a full pipe would stop the daemon)
            assert daemon_proc is not None and daemon_proc.stderr is not None
            for line in daemon_proc.stderr:
                lines.append(line)
                if " web at " in line:
                    found.set()

        threading.Thread(target=drain, daemon=True).start()
        assert found.wait(30), "".join(lines)
        url = next(m.group(1) for x in lines if (m := re.search(r" web at (\S+)", x)))
        env["ML_BOARD_PIDS"] = ",".join(f"{n}={p.pid}" for n, p in zip(boards, procs, strict=True))
        yield url, env
    finally:
        if daemon_proc is not None:
            daemon_proc.terminate()
            daemon_proc.wait(15)
        for p in procs:
            os.kill(p.pid, signal.SIGCONT)
            stop_process(p)


def board_file_process(path: str) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen([*ML, "board", "--file", path, "--listen", "tcp://127.0.0.1:0"],
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.startswith("LISTENING "), line
    return proc, line.split()[1]


def board_pid(env: dict[str, str], name: str) -> int:
    return int(dict(x.split("=") for x in env["ML_BOARD_PIDS"].split(","))[name])


@pytest.fixture(scope="module")
def browser(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    assert Path(CHROMIUM).exists(), "chromium is installed by scripts/system-deps.sh"
    profile = tmp_path_factory.mktemp("chromium-profile")  # (new and empty)
    with sync_playwright() as p:
        ctx = p.chromium.launch_persistent_context(
            str(profile), executable_path=CHROMIUM, args=FLAGS, headless=True,
            viewport={"width": 1200, "height": 900}, reduced_motion="reduce",
            ignore_https_errors=True,  # (the TLS test's certificate is from a CA of its own)
        )  # fmt: skip
        yield ctx
        ctx.close()


@pytest.fixture(scope="module")
def shots(tmp_path_factory: pytest.TempPathFactory) -> Path:
    where = os.environ.get("ML_WEB_SCREENSHOTS")
    return Path(where) if where else tmp_path_factory.mktemp("screenshots")


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, dict[str, str]]]:
    tmp = tmp_path_factory.mktemp("rig")
    with daemon(tmp, {"board_a": "encoder_servo", "board_b": "rangers"}) as got:
        yield got


@pytest.fixture(scope="module")
def page(browser: Any, rig: tuple[str, dict[str, str]]) -> Iterator[Any]:
    page = browser.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.started = time.monotonic()  # type: ignore[attr-defined]
    page.goto(rig[0])
    yield page
    assert not errors, errors
    page.close()


def board(page: Any, name: str) -> Any:
    return page.get_by_role("region", name=name, exact=True)


def test_both_boards_appear_within_5_s_and_values_change(page: Any, shots: Path) -> None:
    from playwright.sync_api import expect

    for name in ("board_a", "board_b"):
        expect(page.get_by_role("heading", name=name, level=2)).to_be_visible(timeout=5000)
        expect(board(page, name).locator(".state")).to_have_text("up", timeout=5000)
    assert time.monotonic() - page.started < 5.0
    quad = board(page, "board_a").get_by_role("article").filter(has_text="quad")
    value = quad.locator(".value").first
    expect(value).to_have_text(re.compile(r"^-?[\d.]+ rad · -?\d+ counts$"))  # (SI, and counts)
    first = value.text_content()
    expect(value).not_to_have_text(first, timeout=5000)
    expect(quad.get_by_role("img", name="quad angle (rad): the last 30 s")).to_be_visible()
    expect(page.locator("#recording-state")).to_contain_text("recording to")
    page.wait_for_timeout(3000)  # (some seconds on the plots)
    page.screenshot(path=str(shots / "web-console.png"))


def test_a_rate_set_with_the_keyboard_reaches_the_board(
    page: Any, rig: tuple[str, dict[str, str]], shots: Path
) -> None:
    from playwright.sync_api import expect

    b = board(page, "board_b")
    snap = b.aria_snapshot()
    for line in ('heading "board_b"', 'spinbutton "dist_ir.rate_hz"', 'button "Apply"',
                 'button "Save"', 'button "Reset"', 'checkbox "dist_ir.enabled"'):  # fmt: skip
        assert line in snap, snap
    field = b.get_by_label("dist_ir.rate_hz", exact=True)
    field.focus()
    page.keyboard.press("Control+A")
    page.keyboard.type("5")
    page.keyboard.press("Enter")  # (the form's submit: Apply)
    expect(b.get_by_role("status").filter(has_text="applied")).to_contain_text(
        "dist_ir.rate_hz = 5"
    )
    out = ml("config", "board_b", env=rig[1], timeout=30)
    assert out.returncode == 0, out.stderr
    assert re.search(r"^dist_ir\.rate_hz = 5$", out.stdout, re.M), out.stdout
    # the buttons follow the fields in the focus order
    b.locator("table.config input:not([disabled]), table.config select").last.focus()
    for name in ("Apply", "Save", "Reset"):
        page.keyboard.press("Tab")
        expect(b.get_by_role("button", name=name)).to_be_focused()
    b.locator("form[aria-label='board_b configuration']").screenshot(
        path=str(shots / "web-config.png")
    )


def test_actuator_controls_in_si_with_their_range(page: Any) -> None:
    """A servo's angle in rad, within its range (a slider and a number), its degrees beside;
    before, a raw int8 (typing 60 gave 42.52 deg)."""
    from playwright.sync_api import expect

    a = board(page, "board_a")
    form = a.locator("form.actuator")
    expect(form).to_contain_text("-1.571..1.571 rad (-90..90 °)")
    field = a.get_by_label("servo command", exact=True)
    field.fill("0.5")
    expect(form).to_contain_text("28.65 °")  # (what 0.5 rad is, before it is sent)
    field.press("Enter")
    expect(form.get_by_role("status")).to_have_text("sent")
    servo = a.get_by_role("article").filter(has_text="servo").locator(".value")
    # 0.5 rad = 28.65 deg, the nearest the int8 takes is 40 x 0.708661 = 28.35 deg: from the board
    expect(servo).to_have_text("0.4947 rad · 28.35 °")
    slider = a.get_by_role("slider", name="servo command (slider)")
    assert (slider.get_attribute("min"), slider.get_attribute("max"))[0].startswith("-1.570")
    slider.fill("-1")  # (let go of the slider: the servo goes there, one raw step at most off)
    expect(servo).to_have_text("-1.002 rad · -57.4 °")  # -81 x 0.708661 deg
    assert field.input_value() == slider.input_value()  # (the number follows the slider)


@pytest.fixture
def rig_page(browser: Any, tmp_path: Path) -> Iterator[Any]:
    """The thesis rig's board file, on a daemon and a page of its own, for one test (the
    timings of the demo's boards are not to share the machine with it)."""
    with daemon(tmp_path, {"rig": str(RIG)}) as (url, _env):
        page = browser.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url)
        yield page
        assert not errors, errors
        page.close()


def test_every_channel_named_one_plot_per_quantity(rig_page: Any, shots: Path) -> None:
    """The thesis rig's board file: the IMU's seven channels named, in SI and in the unit the
    part is sold in, one plot per quantity (before: one "imu (SI)" plot of ch0..ch6); its wheel
    in rad and counts (its board file declares counts_per_rev); time axes in seconds before now;
    an actuator's plot drawn in steps."""
    from playwright.sync_api import expect

    rig = board(rig_page, "rig")
    expect(rig.locator(".state")).to_have_text("up", timeout=10000)
    imu = rig.get_by_role("article").filter(has_text="MPU-6050")
    expect(imu.locator("dl.channels dt")).to_have_text(["ax", "ay", "az", "temperature", "gx",
                                                         "gy", "gz"])  # fmt: skip
    az = imu.locator(".value").nth(2)
    shown = r"^(\d+(?:\.\d+)?) m/s² · (\d+(?:\.\d+)?) g$"  # (four significant digits each)
    expect(az).to_have_text(re.compile(shown))
    m = re.match(shown, az.inner_text())
    assert m, az.inner_text()
    si, in_g = m.groups()
    assert all(len(v.replace(".", "").lstrip("0")) <= 4 for v in (si, in_g)), (si, in_g)
    # at rest in the default world: g, give or take six of the datasheet's noise sigmas
    sigma = imu_sigmas(FIGURES["imu"], DLPF_DEFAULT)[0]
    assert abs(float(si) - G) <= 6 * sigma, si
    assert abs(float(in_g) - float(si) / G) <= 6e-4  # the same value (each rounded to 4)
    expect(imu.locator(".value").nth(4)).to_contain_text(" rad/s · ")
    expect(imu.locator(".value").nth(4)).to_contain_text(" °/s")
    expect(imu.locator("figcaption")).to_have_text(["acceleration (m/s²)", "temperature (°C)",
                                                     "angular velocity (rad/s)"])  # fmt: skip
    wheel = rig.get_by_role("article").filter(has_text="quadrature").locator(".value")
    expect(wheel).to_have_text(re.compile(r"^-?[\d.]+ rad · -?\d+ counts$"))
    ticks = rig_page.evaluate("timeAxis().values({scales: {x: {max: 1000}}}, "
                          "[970, 975, 980, 985, 990, 995, 1000])")  # fmt: skip
    assert ticks == ["-30 s", "-25 s", "-20 s", "-15 s", "-10 s", "-5 s", "now"]
    # (polled from here: Playwright's wait_for_function evaluates a string again in the page,
    # which the console's CSP, script-src 'self', refuses once the first try was not yet true)
    every_plot = "[...S.topics.values()].every(t => t.plots.every(p => p.plot))"
    assert wait_for(lambda: rig_page.evaluate(every_plot), 30)
    stepped = rig_page.evaluate(
        "[...S.topics.values()].map(t => [t.meta.name, t.meta.kind, "
        "t.plots.every(p => p.plot.series[1].stepped === true)])"
    )
    assert all(steps == (kind == "actuator") for _name, kind, steps in stepped), stepped
    field = rig.get_by_label("servo command", exact=True)
    servo = rig.get_by_role("article").filter(has_text="HS-645MG")
    for angle, shown in (("0.6", "0.6061 rad · 34.72 °"), ("-0.3", "-0.2968 rad · -17.01 °")):
        field.fill(angle)
        field.press("Enter")
        expect(servo.locator(".value")).to_have_text(shown)
        rig_page.wait_for_timeout(1500)  # (a step on its plot)
    imu.screenshot(path=str(shots / "web-imu.png"))
    servo.screenshot(path=str(shots / "web-servo.png"))
    rig.locator(".actuators").screenshot(path=str(shots / "web-actuators.png"))


def test_a_stopped_board_shows_as_lost(page: Any, rig: tuple[str, dict[str, str]],
                                      shots: Path) -> None:  # fmt: skip
    from playwright.sync_api import expect

    state = board(page, "board_b").locator(".state")
    expect(state).to_have_text("up")
    pid = board_pid(rig[1], "board_b")
    os.kill(pid, signal.SIGSTOP)
    stopped = time.monotonic()
    try:
        expect(state).to_contain_text("lost", timeout=(LINK_TIMEOUT + 1.0) * 1000)
        took = time.monotonic() - stopped
        board(page, "board_b").evaluate("e => e.scrollIntoView()")
        box = board(page, "board_b").bounding_box()
        page.screenshot(path=str(shots / "web-lost.png"), clip={**box, "height": 560})
    finally:
        os.kill(pid, signal.SIGCONT)
    print(f"board_b shown as lost {took:.2f} s after SIGSTOP (link_timeout {LINK_TIMEOUT} s)")
    assert took <= LINK_TIMEOUT + 1.0
    expect(state).to_have_text("up", timeout=15000)  # and back once it runs again


def test_without_commands_no_controls_and_a_forged_command_is_refused(
    browser: Any, tmp_path: Path
) -> None:
    from playwright.sync_api import expect

    with daemon(tmp_path, {"board_a": "encoder_servo"}, "commands = false") as (url, _env):
        page = browser.new_page()
        page.goto(url)
        a = board(page, "board_a")
        expect(a.locator(".state")).to_have_text("up", timeout=10000)
        expect(page.locator("#link")).to_contain_text("commands off")
        expect(a.get_by_role("heading", name="servo · HS-645MG")).to_be_visible()
        assert a.get_by_label("servo command").count() == 0
        assert page.get_by_role("button", name="Send").count() == 0
        reply = page.evaluate(FORGE)  # (the page's own origin: only the face's option stops it)
        assert reply["ok"] is False and "commands are off" in reply["text"], reply
        page.get_by_text("Publishers").click()
        refused = "web: ok, 0 dropped, 1 commands refused"
        expect(page.locator("#publishers")).to_contain_text(refused)
        page.wait_for_timeout(1000)
        expect(a.get_by_role("article").filter(has_text="servo").locator(".value")).to_have_text(
            "no value yet"
        )  # (the board never moved)
        page.close()


FORGE = """async () => {
  const ws = new WebSocket("ws://" + location.host + "/ws");
  await new Promise((ok) => { ws.onopen = ok; });
  ws.send(JSON.stringify({op: "command", id: 99, topic: "/board_a/servo/cmd", value: 40}));
  return await new Promise((ok) => {
    ws.onmessage = (ev) => { const m = JSON.parse(ev.data); if (m.op === "reply") ok(m); };
  });
}"""


def test_a_token_console_asks_for_a_login_over_tls(browser: Any, tmp_path: Path) -> None:
    from playwright.sync_api import expect

    certs = tmp_path / "certs"
    script = Path(__file__).resolve().parent.parent / "examples" / "security" / "make-certs.sh"
    subprocess.run(["sh", str(script), str(certs)], check=True, capture_output=True, timeout=60)
    token = tmp_path / "token"
    subprocess.run([*ML, "key", "new", str(token)], check=True)
    web = f'cert = "{certs / "daemon.pem"}"\nkey = "{certs / "daemon.key"}"\n'
    web += f'token_file = "{token}"'
    with daemon(tmp_path, {"board_a": "encoder_servo"}, web) as (url, _env):
        assert url.startswith("https://127.0.0.1:")
        page = browser.new_page()
        page.goto(url)
        expect(page.get_by_role("heading", name="Log in")).to_be_visible()
        assert page.get_by_role("region", name="board_a").count() == 0
        field = page.get_by_label("Token")
        field.fill("not-the-token")
        field.press("Enter")
        expect(page.get_by_role("alert")).to_have_text("Wrong token.")
        field.fill(token.read_text().strip())
        field.press("Enter")
        expect(board(page, "board_a").locator(".state")).to_have_text("up", timeout=10000)
        assert page.evaluate("document.cookie") == ""  # (HttpOnly: no script reads the session)
        assert token.read_text().strip() not in page.url
        page.close()
