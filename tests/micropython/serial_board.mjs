// A MicroPython board as mpremote sees it on its serial port: MicroPython 1.27's own REPL (the
// WebAssembly port's event-driven REPL: the friendly REPL, Ctrl-C, the raw REPL with Ctrl-A,
// Ctrl-B and Ctrl-D soft reset) and its own filesystem.  tests/serial_board.py puts a pty in front
// of it, so mpremote runs unchanged against a serial device.
//
//   node serial_board.mjs FLASHDIR
//
// stdin is the board's RX, stdout its TX (bytes).  FLASHDIR is the board's flash: the filesystem
// is loaded from it at power-on and written back to it at a hard reset (`machine.reset()`, what
// `mpremote reset` runs) and at power-off (stdin closed).  A hard reset prints "RESET" on stderr
// and ends the process, as a USB board leaves the bus when it resets.
//
// Raw-paste mode (Ctrl-E 'A' Ctrl-A, what mpremote uses on every board since MicroPython 1.14)
// is this file's, not the port's, whose raw-paste reads stdin in a blocking loop that a
// callback-driven port cannot feed: the same bytes on the wire ("R\x01", the window, an \x01 per
// window taken, \x04 at the end), the code then run by the port's raw REPL with its "OK" left
// out, as raw-paste sends none.  (Declined, mpremote writes 256 bytes every 10 ms: a flash took
// 17 s here.)
//
// A flash that holds a main.py runs it at power-on, as a board does (serial_board_fw.py: the
// firmware stepped here, its link the port, its parts the simulator's): the REPL comes only
// after the break between frames stops it ("missing-link firmware stopped: REPL"), as flash
// sends it first (deploy/flash.py).
import { loadMicroPython } from "@micropython/micropython-webassembly-pyscript";
import { existsSync, mkdirSync, readdirSync, readFileSync, rmSync, statSync, writeFileSync }
  from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const flashDir = process.argv[2];

let tail = ""; // the last bytes sent, to know where the REPL is
let raw = false; // in the raw REPL
let atPrompt = false; // the raw REPL waits for a new command
let swallowOK = ""; // what is left of the raw REPL's "OK" to leave out (raw-paste sends none)
function tx(bytes) {
  let out = Buffer.from(bytes);
  while (swallowOK && out.length && out[0] === swallowOK.charCodeAt(0)) {
    swallowOK = swallowOK.slice(1);
    out = out.subarray(1);
  }
  if (!out.length) return;
  process.stdout.write(out);
  tail = (tail + out.toString("latin1")).slice(-64);
  if (tail.includes("raw REPL; CTRL-B to exit\r\n")) raw = true;
  if (tail.endsWith(">>> ")) raw = false;
  atPrompt = raw && tail.endsWith(">");
}

let resetAsked = false;
const mp = await loadMicroPython({ linebuffer: false, stdout: tx, stderr: tx });
mp.registerJsModule("machine", {
  reset: () => {
    resetAsked = true;
  },
});

function load(dir, at) {
  for (const name of readdirSync(dir)) {
    const p = join(dir, name);
    if (statSync(p).isDirectory()) {
      mp.FS.mkdir(at + name);
      load(p, at + name + "/");
    } else {
      mp.FS.writeFile(at + name, readFileSync(p));
    }
  }
}
function save(at, dir) {
  mkdirSync(dir, { recursive: true });
  for (const name of mp.FS.readdir(at)) {
    if (name === "." || name === "..") continue;
    const path = at + name;
    if (mp.FS.isDir(mp.FS.stat(path).mode)) save(path + "/", join(dir, name));
    else writeFileSync(join(dir, name), mp.FS.readFile(path));
  }
}
function powerOff() {
  rmSync(flashDir, { recursive: true, force: true });
  save("/flash/", flashDir);
}

// the board's filesystem: /flash of the runtime, mounted at / as a board mounts its flash; the
// simulator's parts imported before (they are not on the board's flash)
mkdirSync(flashDir, { recursive: true });
mp.FS.mkdir("/flash");
load(flashDir, "/flash/");
const world = join(here, "..", "..", "src", "missing_link", "virtual", "world");
mp.FS.mkdir("/sim");
mp.FS.mkdir("/sim/simworld");
for (const name of readdirSync(world).filter((n) => n.endsWith(".py"))) {
  mp.FS.writeFile("/sim/simworld/" + name, readFileSync(join(world, name)));
}
mp.runPython("import sys\nsys.path.append('/sim')\nimport simworld.machine, simworld.parts\n" +
  "sys.path.remove('/sim')");
mp.runPython(readFileSync(join(here, "serial_board_fs.py"), "utf8"));
let firmware = null; // main.py's firmware while it runs: { feed, step, timer }
if (existsSync(join(flashDir, "main.py"))) {
  mp.runPython(readFileSync(join(here, "serial_board_fw.py"), "utf8"));
  if (mp.globals.get("_fw_running")()) {
    firmware = { feed: mp.globals.get("_fw_feed"), step: mp.globals.get("_fw_step") };
    firmware.timer = setInterval(stepFirmware, 5);
  }
}
if (firmware === null) mp.replInit(); // the banner and the friendly REPL, as at boot without main.py

function stepFirmware() {
  const out = firmware.step();
  if (out === "BREAK") {
    clearInterval(firmware.timer);
    firmware = null;
    mp.replInit(); // main.py returned: the REPL
  } else if (out) {
    tx(Buffer.from(out, "hex"));
  }
}

function feed(c) {
  const ret = mp.replProcessChar(c);
  if (ret & 0x100) {
    // PYEXEC_FORCED_EXIT: a soft reset, as a port's main loop does it (the REPL comes back in
    // the mode it was in)
    tx(Buffer.from("MPY: soft reboot\r\n"));
    mp.replInit();
  }
  if (resetAsked) {
    powerOff();
    process.stderr.write("RESET\n");
    process.exit(0);
  }
}

const WINDOW = 256; // raw-paste: bytes the host may send before the next \x01
let held = []; // a raw-paste request being recognised
let paste = null; // raw-paste: the code so far, while one is being received
function pasted(c) {
  if (c === 0x04) {
    const code = paste;
    paste = null;
    tx(Buffer.from([0x04])); // the end seen; the code runs
    swallowOK = "OK";
    for (const b of code) feed(b);
    feed(0x04);
    return;
  }
  paste.push(c);
  if (paste.length % WINDOW === 0) tx(Buffer.from([0x01])); // taken: the next window
}
process.stdin.on("data", (data) => {
  if (firmware !== null) {
    firmware.feed(data.toString("hex"));
    stepFirmware();
    return;
  }
  for (const c of data) {
    if (paste !== null) {
      pasted(c);
      continue;
    }
    if ((held.length === 0 && atPrompt && c === 0x05) || (held.length === 1 && c === 0x41)) {
      held.push(c);
      continue;
    }
    if (held.length === 2 && c === 0x01) {
      held = [];
      paste = [];
      tx(Buffer.from([0x52, 0x01, WINDOW & 0xff, WINDOW >> 8]));
      continue;
    }
    for (const h of held) feed(h);
    held = [];
    feed(c);
  }
});
process.stdin.on("end", () => {
  powerOff();
  process.exit(0);
});
