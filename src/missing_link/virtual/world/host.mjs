// Runs a missing-link MicroPython firmware under the real MicroPython interpreter (WebAssembly
// port, from npm) with simulated peripherals, and serves its J2A link on a TCP port.
//
//   node host.mjs BOARDFILE [--port N] [--host ADDR] [--flash DIR] [--absent NAME,...]
//                 [--file NAME=PATH]... [--mpy PATH/micropython.mjs] [--seed N] [--lib DIR]
//                 [--dial HOST:PORT] [--chip-id HEX]
//   (--seed: the simulated chip's machine.unique_id(), so each board has its own; --chip-id:
//   that id itself, 16 hex digits (board --file keeps one in its --flash DIR); --lib: the
//   runtime's files from DIR, e.g. a flashed board's lib/mlboard, not from the package;
//   --dial: the board dials HOST:PORT whatever its board file's link says, board/dial.py;
//   --no-dial: it listens on --port even when its board file's link dials: board --file)
//   node host.mjs BOARDFILE --run SCRIPT.py   (run SCRIPT with the same files and sim, then exit:
//                                            the firmware benchmark)
//
// Prints "LISTEN <port> <micropython version>" when ready.  Lines on stdin are control requests
// for the simulated world: a JSON string of Python code (setting `result`); each gets one line
// back, "OK <repr(result)>" or "ERR <message>".  The firmware stepping its own loop, the bytes
// of each connection moved between its socket and the firmware as they come (the firmware's
// link, as on a device, decides which connection is its host and closes the others).  "BREAK"
// is printed when the firmware stops for the REPL (the break between frames, board/wire.py),
// "CRASH" when it stops on an exception; the simulated world stays there for control requests
// (what the firmware left its devices doing) until stdin closes.
//
// The board's filesystem is /flash, the firmware's current directory (a saved configuration,
// a key).  With --flash DIR it is loaded from DIR at start and every change is written through
// to DIR as it is made (a file when it is closed, renames, removals, directories): the board's
// flash kept between runs.  Without it, /flash starts empty and is gone at exit.  --file puts a
// file there (a signing key, as `flash --key` does).  --absent leaves those parts (transducer
// names) unplugged (parts.py).  The simulator (this directory) is loaded as the package
// `simworld`, its machine.py also as `machine`; the firmware as `mlboard`, as on a device.
//
// A flash that holds a main.py (as `missing-link flash` leaves it) is started from, as a board
// does: the slot its boot record names, the runtime and the board file there (flashboot.py;
// BOARDFILE is not read), and the firmware takes updates (board/update.py).  The power can be
// cut in the middle of the flash's writes (flashcut.mjs): --cut-after N, or the control line
// {"cut": N}: N more units reach DIR (a file's write: its bytes + 1, torn short of that; a
// rename, removal or directory: 1), then "POWER CUT" and the process ends, as a board without
// power.  --journal FILE: every change that reaches DIR, one JSON line each.
import { existsSync, mkdirSync, readFileSync, readdirSync, renameSync, rmSync, statSync,
  writeFileSync } from "node:fs";
import { connect as dialTcp, createServer } from "node:net";
import { createInterface } from "node:readline";
import { dirname, join, posix } from "node:path";
import { fileURLToPath, pathToFileURL } from "node:url";
import { FlashCut } from "./flashcut.mjs";

const here = dirname(fileURLToPath(import.meta.url));
const args = process.argv.slice(2);
const boardFile = args[0];
const opt = (name) => (args.indexOf(name) >= 0 ? args[args.indexOf(name) + 1] : null);
const portArg = Number(opt("--port") ?? 0);
const hostArg = opt("--host") ?? "127.0.0.1";
const runArg = opt("--run");
const flashDir = opt("--flash");
const absent = (opt("--absent") ?? "").split(",").filter((s) => s);
const seedArg = opt("--seed");
const chipArg = opt("--chip-id");
if (chipArg !== null && !/^[0-9a-f]{16}$/.test(chipArg)) {
  process.stderr.write(`--chip-id ${chipArg}: expected 16 hex digits\n`);
  process.exit(2);
}
const libArg = opt("--lib");
const dialArg = opt("--dial");
const noDial = args.includes("--no-dial");
// --file NAME=PATH (repeatable): a file on the board's filesystem (a signing key, as flash puts it)
const files = args.flatMap((a, i) => (a === "--file" ? [args[i + 1]] : []));
const mpyPath = opt("--mpy"); // where npm put MicroPython (the CLI finds it; else node resolves it)
const fromFlash = flashDir !== null && existsSync(join(flashDir, "main.py")); // (flashboot.py)
const cut = new FlashCut(opt("--cut-after"), opt("--journal"));

const { loadMicroPython } = await import(
  mpyPath ? pathToFileURL(mpyPath).href : "@micropython/micropython-webassembly-pyscript"
);
const mp = await loadMicroPython({
  stdout: (line) => (runArg ? process.stdout : process.stderr).write((runArg ? "" : "mpy: ") + line + "\n"),
  stderr: (line) => process.stderr.write("mpy! " + line + "\n"),
});

function copyTree(src, dst) {
  mp.FS.mkdir(dst);
  for (const name of readdirSync(src)) {
    const p = join(src, name);
    if (statSync(p).isDirectory()) {
      if (name !== "__pycache__") copyTree(p, dst + "/" + name);
    } else if (name.endsWith(".py")) {
      mp.FS.writeFile(dst + "/" + name, readFileSync(p));
    }
  }
}
mp.FS.mkdir("/lib");
if (!fromFlash) copyTree(libArg ?? join(here, "..", "..", "board"), "/lib/mlboard");
copyTree(here, "/lib/simworld");
if (!fromFlash) mp.FS.writeFile("/lib/board.py", readFileSync(boardFile));

// ---- the board's flash ----------------------------------------------------------------------
const FLASH = "/flash";
function loadFlash(dir, at) {
  for (const name of readdirSync(dir)) {
    const p = join(dir, name);
    if (statSync(p).isDirectory()) {
      mp.FS.mkdir(at + "/" + name);
      loadFlash(p, at + "/" + name);
    } else {
      mp.FS.writeFile(at + "/" + name, readFileSync(p));
    }
  }
}
mp.FS.mkdir(FLASH);
if (flashDir) {
  mkdirSync(flashDir, { recursive: true });
  loadFlash(flashDir, FLASH);
  writeThrough(flashDir);
}
mp.FS.chdir(FLASH);
for (const spec of files) {
  const eq = spec.indexOf("=");
  mp.FS.writeFile(FLASH + "/" + spec.slice(0, eq), readFileSync(spec.slice(eq + 1)));
}

// Every change under /flash is made in DIR too, after the interpreter's own succeeded: a file
// when it is closed after writing, a rename, a removal, a directory.  A failure is said on
// stderr (the interpreter has it in memory; the flash on disk does not).
function writeThrough(dir) {
  const onDisk = (p) => {
    const abs = posix.normalize(p.startsWith("/") ? p : mp.FS.cwd() + "/" + p);
    return abs.startsWith(FLASH + "/") ? join(dir, abs.slice(FLASH.length + 1)) : null;
  };
  // (the power may go in the middle: flashcut.mjs; `op` is the journal's entry when whole)
  const mirror = (what, fn, units = 1, op = null) => {
    const n = cut.take(units);
    try {
      if (n > 0) fn(n);
      if (n === units && op) cut.record(dir, ...op);
    } catch (e) {
      process.stderr.write(`flash: cannot ${what}: ${e.message}\n`);
    }
    if (cut.gone) cut.powerOff();
  };
  const wrap = (name, after) => {
    const orig = mp.FS[name];
    mp.FS[name] = function (...a) {
      const r = orig.apply(this, a);
      after(...a);
      return r;
    };
  };
  wrap("close", (stream) => {
    const host = stream.path ? onDisk(stream.path) : null;
    if (host && (stream.flags & 3) !== 0) {
      const data = mp.FS.readFile(stream.path);
      mirror(`write ${host}`, (n) => writeFileSync(host, data.subarray(0, n - 1)), data.length + 1,
        ["write", host, { data }]);
    }
  });
  wrap("rename", (from, to) => {
    const [a, b] = [onDisk(from), onDisk(to)];
    if (a && b) mirror(`rename ${a}`, () => renameSync(a, b), 1, ["rename", a, { to: b }]);
    else if (a) mirror(`remove ${a}`, () => rmSync(a, { recursive: true, force: true }), 1, ["remove", a]);
    else if (b) mirror(`write ${b}`, () => writeFileSync(b, mp.FS.readFile(to)), 1, ["write", b, { data: mp.FS.readFile(to) }]);
  });
  wrap("unlink", (p) => {
    const host = onDisk(p);
    if (host) mirror(`remove ${host}`, () => rmSync(host, { force: true }), 1, ["remove", host]);
  });
  wrap("rmdir", (p) => {
    const host = onDisk(p);
    if (host) mirror(`remove ${host}`, () => rmSync(host, { recursive: true, force: true }), 1, ["remove", host]);
  });
  wrap("mkdir", (p) => {
    const host = onDisk(p);
    if (host && !existsSync(host)) mirror(`make ${host}`, () => mkdirSync(host), 1, ["mkdir", host]);
  });
}

const boot = [
  "import sys",
  "sys.path.append('/lib')",
  "import simworld.machine",
  "sys.modules['machine'] = simworld.machine",
].join("\n");
if (runArg) {
  mp.runPython(boot + "\n" + readFileSync(runArg, "utf8"));
  process.exit(0);
}
const seed = chipArg !== null ? `simworld.machine.WORLD.unique_id = bytes.fromhex("${chipArg}")\n` :
  seedArg === null ? "" : `simworld.machine.seed_unique_id(${Math.trunc(Number(seedArg))})\n`;
const dialTo = dialArg !== null ?
  `import board\nlink = dict(board.BOARD.get("link", {}), kind="tcp", dial=${JSON.stringify(dialArg)})\n` +
  `link.pop("port", None)\nboard.BOARD["link"] = link\n` :
  noDial ? `import board\nboard.BOARD.get("link", {}).pop("dial", None)\n` : "";
mp.runPython(
  boot + "\n" + seed + (fromFlash ? "" : dialTo) +
  (fromFlash ? [
    "from simworld import flashboot, mpyhost",
    `flashboot.adjust = ${JSON.stringify(dialTo)}`,
    `mpyhost.start_flash(flashboot, ${JSON.stringify(absent)})`,
  ] : [
    "from board import BOARD",
    "import mlboard.clock, mlboard.dial, mlboard.firmware, mlboard.link",
    "import mlboard",
    "from simworld import mpyhost",
    `mpyhost.start(BOARD, mlboard, ${JSON.stringify(absent)})`,
  ]).concat(["from simworld.mpyhost import _open, _feed, _closed, _tick, _due_us, _ctl, _ident"])
    .join("\n"),
);
const open = mp.globals.get("_open");
const feed = mp.globals.get("_feed");
const closed = mp.globals.get("_closed");
const tick = mp.globals.get("_tick");
const dueUs = mp.globals.get("_due_us");
const ctl = mp.globals.get("_ctl");
const ident = mp.globals.get("_ident")();

const conns = new Map(); // connection number -> socket: the firmware's link decides who stays
let nextConn = 1;
let stopped = false; // the firmware gave the REPL back: no more steps
let pending = null; // the next run(): { immediate } or { timeout }
function cancel() {
  if (pending === null) return;
  if (pending.immediate) clearImmediate(pending.immediate);
  else clearTimeout(pending.timeout);
  pending = null;
}
function run() {
  pending = null;
  let out;
  try {
    out = tick();
  } catch (e) {
    process.stderr.write("firmware crashed: " + String(e) + "\n");
    // as a board whose main.py raised: the firmware stops (its actuators made safe by then,
    // board/firmware.py), the world stays for control requests
    process.stdout.write("CRASH\n");
    stopped = true;
    return;
  }
  if (out === "BREAK") {
    process.stdout.write("BREAK\n");
    stopped = true;
    return;
  }
  for (const tok of out ? out.split(" ") : []) {
    if (tok[0] === "+") {
      dial(tok.slice(1));
    } else if (tok[0] === "-") {
      const s = conns.get(Number(tok.slice(1)));
      conns.delete(Number(tok.slice(1)));
      if (s) s.destroy();
    } else {
      const at = tok.indexOf(":");
      const s = conns.get(Number(tok.slice(0, at)));
      if (s) s.write(Buffer.from(tok.slice(at + 1), "hex"));
    }
  }
  schedule(Boolean(out));
}
// Step again at once after input or output (more may be queued), else at the drivers' next
// deadline, at most 5 ms later (the firmware's own receive timeout needs a poll).
function schedule(now) {
  if (stopped || (pending !== null && !now)) return;
  cancel();
  const due = now ? 0 : dueUs();
  const ms = due < 0 ? 5 : Math.min(5, Math.floor(due / 1000));
  pending = ms <= 0 ? { immediate: setImmediate(run) } : { timeout: setTimeout(run, ms) };
}

// A connection's bytes to the firmware, and its end (the firmware may have closed it first).
function attach(n, s) {
  s.setNoDelay(true);
  s.on("data", (d) => {
    feed(n, d.toString("hex"));
    schedule(true);
  });
  s.on("close", () => {
    if (conns.delete(n)) closed(n);
    schedule(true);
  });
  s.on("error", () => {});
}

// The firmware dials ("n:HOST:PORT", board/dial.py): the connection is the firmware's once up
// (open), or it failed (closed, never opened).
function dial(spec) {
  const n = Number(spec.slice(0, spec.indexOf(":")));
  const host = spec.slice(spec.indexOf(":") + 1, spec.lastIndexOf(":"));
  const port = Number(spec.slice(spec.lastIndexOf(":") + 1));
  const s = dialTcp({ host, port });
  conns.set(n, s);
  s.on("connect", () => {
    if (conns.has(n)) open(n);
    schedule(true);
  });
  attach(n, s);
}

const server = createServer((s) => {
  const n = nextConn++;
  conns.set(n, s);
  open(n);
  attach(n, s);
});
server.on("error", (e) => {
  process.stderr.write(`cannot listen on ${hostArg}:${portArg}: ${e.message}\n`);
  process.exit(1);
});
server.listen(portArg, hostArg, () => {
  process.stdout.write(`LISTEN ${server.address().port} ${ident}\n`);
  schedule(true);
});

const rl = createInterface({ input: process.stdin });
rl.on("line", (line) => {
  try {
    const req = JSON.parse(line); // (code, or {"cut": N}: flashcut.mjs)
    process.stdout.write("OK " + (typeof req === "string" ? ctl(req) : cut.arm(req.cut)) + "\n");
  } catch (e) {
    process.stdout.write("ERR " + String(e).split("\n").join(" | ") + "\n");
  }
  schedule(true);
});
rl.on("close", () => process.exit(0));
