"""The daemon's configuration is input, not code: a wrong type anywhere is one line naming the
file, table and key; a publisher table takes only the keys its publisher reads (a typo is an
error, not an option silently left at its default); a descriptor file that is a device or huge is
refused before it is read; the control endpoint's directory is never created on the config's
say-so."""

from __future__ import annotations

import ast
import os
import subprocess
from pathlib import Path

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import Config, ConfigError, parse_config
from missing_link.daemon.paths import runtime_dir
from missing_link.errors import DescriptorError
from missing_link.publishers.registry import BUILTIN, OPTIONS

from .helpers import ml

ROOT = Path(__file__).resolve().parent.parent
PUBLISHERS = ROOT / "src" / "missing_link" / "publishers"


def run_config(tmp_path: Path, text: str) -> subprocess.CompletedProcess[str]:
    cfg = tmp_path / "ml.toml"
    cfg.write_text(text)
    return ml("run", "--config", str(cfg), "--duration", "1", timeout=60)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("text", "said"),
    [
        ("[zenoh]\ncomands = false\n", "[zenoh].comands: unknown key"),
        ("[mcap]\nrotate_megabytes = 5\n", "[mcap].rotate_megabytes: unknown key"),
        ('[console]\nrate_hz = "fast"\n', "[console].rate_hz: expected a number"),
        ("[mcap]\npath = 1\n", "[mcap].path: expected a string"),
        ('[foxglove]\nport = "8765"\n', "[foxglove].port: expected an integer"),
        ('[zenoh]\nconnect = "tcp/127.0.0.1:7447"\n', "[zenoh].connect: expected a list"),
        ("[zenoh]\ndomain = 999\n", "[zenoh].domain: 999 is outside 0..232"),
        ("remap = 1\n", "remap: must be a table"),
        ('[remap]\n"/a/b" = 1\n', "remap.'/a/b': expected a topic name"),
        ("board = [1]\n", "[[board]] #1: must be a table"),
        ('board = ["serial:///dev/ttyACM0"]\n', "[[board]] #1: must be a table"),
        ("[daemon]\npublishers = [1]\n", "unknown publisher 1"),
    ],
)
def test_a_wrong_config_is_one_line_exit_2(tmp_path: Path, text: str, said: str) -> None:
    if not text.startswith("board"):  # (top-level keys come before the first table)
        text += '[[board]]\nurl = "tcp://127.0.0.1:9"\n'
    r = run_config(tmp_path, text)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert said in r.stderr and str(tmp_path / "ml.toml") in r.stderr, r.stderr


def test_publisher_options_given_in_code_are_checked_too() -> None:
    """``Config(publisher_options=...)`` never passes through the file's parser: starting the
    publisher checks its options as well."""
    with pytest.raises(ConfigError, match=r"\[console\]\.rate: unknown key"):
        Daemon(Config(publishers=["console"], publisher_options={"console": {"rate": 2}}))
    with pytest.raises(ConfigError, match=r"\[console\]\.rate_hz: expected a number"):
        Daemon(Config(publishers=["console"], publisher_options={"console": {"rate_hz": "2"}}))


def _keys_read(module: Path) -> set[str]:
    """The option keys a publisher's source reads: ``opts.get("key"...)``, ``opts["key"]`` and
    ``_option(opts, "key", ...)``."""
    keys = set()
    for node in ast.walk(ast.parse(module.read_text())):
        if isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            f = node.func
            if (
                isinstance(f, ast.Attribute)
                and f.attr == "get"
                and isinstance(f.value, ast.Name)
                and f.value.id == "opts"
            ):
                keys.add(node.args[0].value)
        f = getattr(node, "func", None)
        if isinstance(f, ast.Name) and f.id == "_option":
            assert isinstance(node, ast.Call) and isinstance(node.args[1], ast.Constant)
            keys.add(node.args[1].value)
        value = getattr(node, "value", None)
        if isinstance(node, ast.Subscript) and isinstance(value, ast.Name) and value.id == "opts":
            assert isinstance(node.slice, ast.Constant)
            keys.add(node.slice.value)
    return keys


def test_the_known_keys_are_the_keys_each_publisher_reads() -> None:
    assert set(OPTIONS) == set(BUILTIN)
    for name, entry in BUILTIN.items():
        module = PUBLISHERS / (entry.module.rsplit(".", 1)[1] + ".py")
        read = _keys_read(module)
        # the daemon hands every publisher [daemon] distro, and the ROS faces its node name
        assert read <= set(OPTIONS[name]), (name, read - set(OPTIONS[name]))
        assert set(OPTIONS[name]) - read <= {"distro", "node"}, (name, set(OPTIONS[name]) - read)


@pytest.mark.slow
def test_a_descriptor_file_that_is_a_device_or_huge_is_refused_at_once(tmp_path: Path) -> None:
    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * (2 << 20))
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # (opening it for reading would wait for a writer for ever)
    for path, said in (
        ("/dev/zero", "not a regular file"),
        (str(fifo), "not a regular file"),
        (str(big), "at most 1048576"),
    ):
        cfg = parse_config({"board": [{"url": "tcp://127.0.0.1:9", "descriptors": path}]})
        with pytest.raises(DescriptorError, match=said):  # (by its stat: nothing was read)
            Daemon(cfg)
    r = run_config(tmp_path, '[[board]]\nurl = "tcp://127.0.0.1:9"\ndescriptors = "/dev/zero"\n')
    assert r.returncode == 2 and "not a regular file" in r.stderr and r.stderr.count("\n") == 1
    r = ml("run", "--config", "/dev/zero", timeout=60)
    assert r.returncode == 2 and "/dev/zero: refused: not a regular file" in r.stderr


@pytest.mark.slow
def test_control_creates_no_directory(tmp_path: Path) -> None:
    where = tmp_path / "made" / "by" / "the" / "config"
    with pytest.raises(ConfigError, match="does not exist"):
        parse_config({"daemon": {"control": str(where / "control.sock")}})
    assert not (tmp_path / "made").exists()
    ok = parse_config({"daemon": {"control": str(tmp_path / "control.sock")}})  # it exists
    assert ok.control == str(tmp_path / "control.sock")
    # the per-user runtime directory is the one the daemon makes itself (mode 0700)
    mine = parse_config({"daemon": {"control": str(Path(runtime_dir()) / "control.sock")}})
    assert mine.control is not None and mine.control.endswith("control.sock")
    r = run_config(tmp_path, f'[daemon]\ncontrol = "{where}/c.sock"\n[[board]]\nurl = "x"\n')
    assert r.returncode == 2 and "does not exist" in r.stderr and r.stderr.count("\n") == 1
    assert not (tmp_path / "made").exists()
