// Runs a missing-link MicroPython firmware under the real MicroPython interpreter (WebAssembly
// port, from npm) with simulated peripherals, and serves its J2A link on a TCP port.
//
//   node host.mjs BOARDFILE [--port N] [--host ADDR] [--flash DIR] [--absent NAME,...]
//                 [--file NAME=PATH]... [--mpy PATH/micropython.mjs] [--seed N] [--lib DIR]
//                 [--dial HOST:PORT] [--chip-id HEX] [--heap BYTES]
//                 [--fast [--lead-ms MS | --lockstep]]
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
// `simworld`, its machine.py also as `machine`, simgc.py as `gc`; the firmware as `mlboard`,
// as on a device.
//
// A flash that holds a main.py (as `missing-link flash` leaves it) is started from, as a board
// does: the slot its boot record names, the runtime and the board file there (flashboot.py;
// BOARDFILE is not read), and the firmware takes updates (board/update.py).  The power can be
// cut in the middle of the flash's writes (flashcut.mjs): --cut-after N, or the control line
// {"cut": N}: N more units reach DIR (a file's write: its bytes + 1, torn short of that; a
// rename, removal or directory: 1), then "POWER CUT" and the process ends, as a board without
// power.  --journal FILE: every change that reaches DIR, one JSON line each.
//
// --heap BYTES: the firmware gets a board's fixed heap of BYTES (a Raspberry Pi Pico: 209936,
// docs/hardware.md "Memory"): heap.mjs.  --fast: simulated time (fastclock.mjs, simtime.py): the
// clock jumps over what the firmware sleeps and moves on by what its work costs on a Pico
// (simcost.py), never by the host's CPU time or clock; the link still carries every byte, at
// most 512 into the firmware a step (as link.py's reads), and the steps wait while a host has
// 64 KiB of output not taken; --lead-ms: and while the simulation is MS ahead of a host's last
// bytes (a host map it keeps fresh stays fresh); --lockstep: it runs only when its controller
// says, taking a host's bytes when the controller says they were sent (lockstep.mjs): the same
// host, the same run.  Control lines {"sim": "time"} (simulated µs since the start), "held"
// (whether --lead-ms holds it now), "gc" (the collections: fastclock.mjs).  (A board started
// from its flash is loaded as flashboot.py loads it, not a module a call.)
import { existsSync, mkdirSync, readFileSync, renameSync, rmSync, writeFileSync } from "node:fs";
import { connect as dialTcp, createServer } from "node:net";
import { createInterface } from "node:readline";
import { dirname, join, posix } from "node:path";
import { fileURLToPath, pathToFileURL } from "node:url";
import { FastClock } from "./fastclock.mjs";
import { Lockstep } from "./lockstep.mjs";
import { copyTree } from "./mpfs.mjs";
import { FlashCut } from "./flashcut.mjs";
import { SIM_ROOM, capHeap, quietGrowth } from "./heap.mjs";
import { rememberTableEntries } from "./wasmtable.mjs";
import { worldBeside } from "./worldtick.mjs";

const here = dirname(fileURLToPath(import.meta.url));
const args = process.argv.slice(2);
const boardFile = args[0];
const opt = (name) => (args.indexOf(name) >= 0 ? args[args.indexOf(name) + 1] : null);
const portArg = Number(opt("--port") ?? 0);
const hostArg = opt("--host") ?? "127.0.0.1";
const runArg = opt("--run");
const flashDir = opt("--flash");
const absent = (opt("--absent") ?? "").split(",").filter((s) => s);
// --file NAME=PATH (repeatable): a file on the board's filesystem (a signing key, as flash puts it)
const files = args.flatMap((a, i) => (a === "--file" ? [args[i + 1]] : []));
const mpyPath = opt("--mpy"); // where npm put MicroPython (the CLI finds it; else node resolves it)
const seedArg = opt("--seed");
const chipArg = opt("--chip-id");
if (chipArg !== null && !/^[0-9a-f]{16}$/.test(chipArg)) {
  process.stderr.write(`--chip-id ${chipArg}: expected 16 hex digits\n`);
  process.exit(2);
}
const libArg = opt("--lib");
const dialArg = opt("--dial");
const noDial = args.includes("--no-dial");
const heapArg = opt("--heap") === null ? null : Number(opt("--heap"));
if (heapArg !== null && !(Number.isInteger(heapArg) && heapArg > 0)) {
  process.stderr.write(`--heap ${opt("--heap")}: a number of bytes, as a board's gc.mem_free()\n`);
  process.exit(2);
}
const fast = args.includes("--fast") ? new FastClock() : null;
const leadUs = opt("--lead-ms") === null ? null : Number(opt("--lead-ms")) * 1000;
const lock = fast && args.includes("--lockstep") ? new Lockstep() : null;
let heardAt = 0; // --lead-ms: simulated µs when bytes last came from a host
if (heapArg !== null) quietGrowth();
const fromFlash = flashDir !== null && existsSync(join(flashDir, "main.py")); // (flashboot.py)
const cut = new FlashCut(opt("--cut-after"), opt("--journal"));

rememberTableEntries(); // (a tenth of a --fast soak's time: wasmtable.mjs)
const { loadMicroPython } = await import(
  mpyPath ? pathToFileURL(mpyPath).href : "@micropython/micropython-webassembly-pyscript"
);
const mp = await loadMicroPython({
  ...(heapArg !== null ? { heapsize: heapArg + SIM_ROOM } : {}),
  stdout: (line) => (runArg ? process.stdout : process.stderr).write((runArg ? "" : "mpy: ") + line + "\n"),
  stderr: (line) => process.stderr.write("mpy! " + line + "\n"),
});

mp.FS.mkdir("/lib");
if (!fromFlash) copyTree(mp, libArg ?? join(here, "..", "..", "board"), "/lib/mlboard");
copyTree(mp, here, "/lib/simworld");
if (!fromFlash) mp.FS.writeFile("/lib/board.py", readFileSync(boardFile));

// ---- the board's flash ----------------------------------------------------------------------
const FLASH = "/flash";
if (flashDir) mkdirSync(flashDir, { recursive: true });
copyTree(mp, flashDir, FLASH, true); // (every file of DIR, as it is; none: an empty flash)
if (flashDir) writeThrough(flashDir);
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

// the firmware's modules, each after those it imports (board/)
const BOOT_ORDER = ["clock", "dtypes", "wire", "log", "identity", "transducer", "runtime",
  "store", "config", "timing", "failsafe", "memory", "drivers", "firmware", "dial", "link"];
const bootPy = [
  "import sys",
  "sys.path.append('/lib')",
  ...(fast ? ["import simworld.simtime", "sys.modules['time'] = simworld.simtime"] : []),
  "import simworld.simgc",
  "sys.modules['gc'] = simworld.simgc",
  "import simworld.machine",
  "sys.modules['machine'] = simworld.machine",
].join("\n");
if (runArg) {
  mp.runPython(bootPy + "\n" + readFileSync(runArg, "utf8"));
  process.exit(0);
}
const seed = chipArg !== null ? `simworld.machine.WORLD.unique_id = bytes.fromhex("${chipArg}")\n` :
  seedArg === null ? "" : `simworld.machine.seed_unique_id(${Math.trunc(Number(seedArg))})\n`;
const dialTo = dialArg !== null ?
  `import board\nlink = dict(board.BOARD.get("link", {}), kind="tcp", dial=${JSON.stringify(dialArg)})\n` +
  `link.pop("port", None)\nboard.BOARD["link"] = link\n` :
  noDial ? `import board\nboard.BOARD.get("link", {}).pop("dial", None)\n` : "";
mp.runPython(bootPy + "\n" + seed + "from simworld import mpyhost");
const world = worldBeside(mp, opt("--world-fds"), fast); // (--world-fds R,W: worldtick.mjs)
if (heapArg !== null) {
  const [base, slack] = capHeap(mp, heapArg); // (before the firmware: it gets heapArg bytes)
  mp.runPython(
    `import simworld.simgc\nsimworld.simgc.BASE = ${base}\nsimworld.simgc.SLACK = ${slack}\n` +
      `simworld.simgc.heap_blocks = ${Math.floor(heapArg / 16)}\n` +
      "simworld.machine.WORLD.log_cap = 0",
  );
}
// The firmware loads as on a board, but a module a call: this port collects only between calls
// (simgc.py), where a board collects while it imports; then it is built from the board file.
// A firmware that cannot boot (a MemoryError, perhaps) says so in one line and exits 1 (node's
// own report of an uncaught error quotes the interpreter's minified source: 100 KiB).
function boot(code) {
  try {
    mp.runPython(`try:\n${code.replace(/^/gm, "    ")}\nexcept BaseException:\n` +
      "    mpyhost.release()\n    raise");
  } catch (e) {
    const last = String(e.message ?? "").trim().split("\n").pop(); // (a traceback's last line)
    process.stderr.write(`the firmware did not boot: ${last || e.type || e.name}\n`);
    process.exit(1);
  }
}
mp.runPython(`import simworld.simgc as G\nG.fast = ${fast ? "True" : "False"}\nG._gc.collect()`);
if (fast) mp.runPython("import simworld.simgc\nsimworld.simgc.settle()"); // (its live blocks)
if (fromFlash) {
  boot("from simworld import flashboot\n" + `flashboot.adjust = ${JSON.stringify(dialTo)}\n` +
    `mpyhost.start_flash(flashboot, ${JSON.stringify(absent)})`);
} else {
  boot(dialTo + "from board import BOARD");
  for (const m of BOOT_ORDER) boot(`import mlboard.${m}`);
  boot("from mlboard.drivers import driver_class\nfor _t in BOARD['transducers']:\n" +
    "    driver_class(_t['driver'])");
  // fw.hash reads every runtime file (the whole package here; a board has only the drivers its
  // board file uses): a step of its own, where a board collects as it reads (identity.py caches)
  boot("mlboard.identity.runtime_hash()");
  boot(`import mlboard\nmpyhost.start(BOARD, mlboard, ${JSON.stringify(absent)})`);
}
if (fast) mp.registerJsModule("simjs", { report: (...f) => fast.report(...f) });
if (fast) mp.runPython("import simjs\nfrom simworld import mpyhost\nmpyhost.report = simjs.report");
// (after the boot: the heap watched, the allocator's threshold kept by simgc.py)
if (fast && heapArg !== null) mp.runPython("import simworld.simgc\nsimworld.simgc.watch_heap()");
mp.runPython(
  "from simworld.mpyhost import _open, _feed, _closed, _tick, _step, _settle, _due_us, _ctl, " +
    "_ident, _heap_used, _heap_live",
);
const open = mp.globals.get("_open");
const feed = mp.globals.get("_feed");
const closed = mp.globals.get("_closed");
const step = mp.globals.get("_step"); // (--fast: the connections' bytes go in with the step)
const settle = mp.globals.get("_settle");
const [used, live] = [mp.globals.get("_heap_used"), mp.globals.get("_heap_live")];
const heapNow = heapArg === null ? null : () => [Number(used()), Number(live())];
const tick = fast ? () => fast.step((now, ns) => step(now, ns, feedSome()), settle, heapNow) :
  mp.globals.get("_tick");
const dueUs = mp.globals.get("_due_us");
const ctl = mp.globals.get("_ctl");
const ident = mp.globals.get("_ident")();

const conns = new Map(); // connection number -> socket: the firmware's link decides who stays
const inbox = new Map(); // connection number -> bytes not fed yet (at most CHUNK a step)
const ended = new Set(); // closed by the client: said to the firmware once its bytes are in
const CHUNK = 512; // (link.py's TcpServer reads 512 bytes at a time)
const BACKLOG = 64 * 1024; // --fast: output a host has not taken before the steps wait for it
let nextConn = 1;
let stopped = false; // the firmware gave the REPL back: no more steps
let pending = null; // the next run(): { immediate } or { timeout }
function cancel() {
  if (pending === null) return;
  if (pending.immediate) clearImmediate(pending.immediate);
  else clearTimeout(pending.timeout);
  pending = null;
}
// At most CHUNK bytes of each connection into the firmware; --fast: as "n:hex" and "-n" (closed)
// for the step to feed itself (mpyhost.py _step), else fed here.
function feedSome() {
  const toks = [];
  for (const [n, buf] of inbox) {
    const take = Math.min(CHUNK, buf.length, lock ? lock.allowance(n) : Infinity);
    if (take > 0) {
      const hex = buf.subarray(0, take).toString("hex");
      if (fast) toks.push(`${n}:${hex}`);
      else feed(n, hex);
      inbox.set(n, buf.subarray(take));
      if (lock) lock.took(n, take);
    } else if (!buf.length && ended.has(n) && (!lock || lock.mayClose(n))) {
      inbox.delete(n);
      ended.delete(n);
      if (fast) toks.push(`-${n}`);
      else closed(n);
    }
  }
  return toks.join(" ");
}
const waiting = () => lock ? [...inbox.keys()].some((n) => lock.allowance(n) > 0) :
  [...inbox.values()].some((b) => b.length) || ended.size > 0;
// --lead-ms: the simulation waits for a host's bytes (it is MS past the last)
const held = () => fast && leadUs !== null && !waiting() && fast.now - heardAt > leadUs;
function run() {
  pending = null;
  if (held()) return; // (on data)
  if (lock && !lock.begin(fast.nowNs)) return; // (on the controller's word)
  let out;
  try {
    world?.before(); // (the world's tick and its edges due, in the simulation's time)
    if (!fast) feedSome();
    out = tick();
  } catch (e) {
    process.stderr.write("firmware crashed: " + String(e) + "\n");
    // as a board whose main.py raised: the firmware stops (its actuators made safe by then,
    // board/firmware.py), the world stays for control requests
    process.stdout.write("CRASH\n");
    stopped = true;
    if (lock) lock.after(fast.nowNs, true);
    return;
  }
  if (out === "BREAK") {
    process.stdout.write("BREAK\n");
    stopped = true;
    if (lock) lock.after(fast.nowNs, true);
    return;
  }
  let full = null; // --fast: a host that does not take its output holds the steps up
  for (const tok of out ? out.split(" ") : []) {
    if (tok[0] === "+") {
      dial(tok.slice(1));
    } else if (tok[0] === "-") {
      const s = conns.get(Number(tok.slice(1)));
      conns.delete(Number(tok.slice(1)));
      inbox.delete(Number(tok.slice(1)));
      lock?.flush(Number(tok.slice(1))); // (what it was sent first)
      if (s) s.destroy();
    } else {
      const at = tok.indexOf(":");
      const s = conns.get(Number(tok.slice(0, at)));
      const data = s ? Buffer.from(tok.slice(at + 1), "hex") : null;
      if (s && lock) lock.hold(Number(tok.slice(0, at)), data, (d) => s.write(d));
      else if (s) s.write(data);
      if (s && fast && s.writableLength > BACKLOG) full = s;
    }
  }
  if (full) {
    full.once("drain", () => schedule(true));
    full.once("close", () => schedule(true));
    return;
  }
  if (fast && !out && !waiting()) fast.idle(lock ? lock.untilNs : Infinity); // (a board sleeps)
  if (lock) lock.after(fast.nowNs, false);
  schedule(Boolean(out) || waiting() || fast !== null);
}
// Step again at once after input or output (more may be queued), else at the drivers' next
// deadline, at most 5 ms later (the firmware's own receive timeout needs a poll).  --fast: at
// once (the clock has jumped already).
function schedule(now) {
  if (stopped || (pending !== null && !now)) return;
  cancel();
  const due = now ? 0 : dueUs();
  const ms = due < 0 ? 5 : Math.min(5, Math.floor(due / 1000));
  pending = ms <= 0 ? { immediate: setImmediate(run) } : { timeout: setTimeout(run, ms) };
}

// A connection's bytes to the firmware, and its end (the firmware may have closed it first).
function attach(n, s) {
  inbox.set(n, Buffer.alloc(0));
  s.setNoDelay(true);
  s.on("data", (d) => {
    if (inbox.has(n)) inbox.set(n, Buffer.concat([inbox.get(n), d]));
    if (fast) heardAt = fast.now;
    if (lock) lock.received(n, d.length);
    schedule(true);
  });
  s.on("close", () => {
    if (conns.delete(n) && inbox.has(n)) ended.add(n);
    if (lock) lock.ended(n);
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
  if (lock) lock.accept(n, () => open(n)); // (the firmware sees it at the run that names it)
  else open(n);
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

// {"sim": "time"} / {"sim": "held"} / {"sim": "gc"}: the simulation's own figures (--fast), as JSON
function simCtl(what) {
  if (!fast) throw new Error("not a --fast simulation");
  if (what === "time") return String(Math.floor(fast.now));
  if (what === "held") return String(Boolean(held()));
  if (what === "gc") {
    const { log, collections, gcUs, steps, heap } = fast;
    return JSON.stringify({ collections, log, us: gcUs, steps, heap });
  }
  throw new Error(`no such figure: ${what}`);
}

const rl = createInterface({ input: process.stdin });
rl.on("line", (line) => {
  try {
    const req = JSON.parse(line); // (code, {"cut": N}: flashcut.mjs, or {"sim": what})
    if (req?.sim === "run" && lock) { // (answered when the run is over: lockstep.mjs)
      lock.request(req.us, req.rx, (out) => process.stdout.write("OK " + out + "\n"));
      if (stopped) lock.after(fast.nowNs, true, true); // (nothing runs any more)
      schedule(true);
      return;
    }
    const out = typeof req === "string" ? ctl(req, fast ? Math.floor(fast.now) : null) :
      "cut" in req ? cut.arm(req.cut) : simCtl(req.sim);
    process.stdout.write("OK " + out + "\n");
  } catch (e) {
    process.stdout.write("ERR " + String(e).split("\n").join(" | ") + "\n");
  }
  schedule(true);
});
rl.on("close", () => process.exit(0));
