// Runs a missing-link MicroPython firmware under the real MicroPython interpreter (WebAssembly
// port, from npm) with simulated peripherals, and serves its J2A link on a TCP port on 127.0.0.1.
//
//   node host.mjs BOARDFILE [--port N]
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
import { loadMicroPython } from "@micropython/micropython-webassembly-pyscript";
import { readFileSync, readdirSync, statSync } from "node:fs";
import { createServer } from "node:net";
import { createInterface } from "node:readline";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const root = join(here, "..", "..", "..");
const args = process.argv.slice(2);
const boardFile = args[0];
const portArg = args.indexOf("--port") >= 0 ? Number(args[args.indexOf("--port") + 1]) : 0;
const runArg = args.indexOf("--run") >= 0 ? args[args.indexOf("--run") + 1] : null;
// --file NAME=PATH (repeatable): a file on the board's filesystem (a signing key, as flash puts it)
const files = args.flatMap((a, i) => (a === "--file" ? [args[i + 1]] : []));

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
copyTree(join(root, "src", "missing_link", "board"), "/lib/mlboard");
mp.FS.writeFile("/lib/machine.py", readFileSync(join(here, "machine.py")));
mp.FS.writeFile("/lib/simdevices.py", readFileSync(join(here, "devices.py")));
mp.FS.writeFile("/lib/simhost.py", readFileSync(join(here, "host.py")));
mp.FS.writeFile("/lib/board.py", readFileSync(boardFile));
for (const spec of files) {
  const eq = spec.indexOf("=");
  mp.FS.writeFile("/" + spec.slice(0, eq), readFileSync(spec.slice(eq + 1)));
}
if (runArg) {
  mp.runPython("import sys\nsys.path.append('/lib')\n" + readFileSync(runArg, "utf8"));
  process.exit(0);
}
mp.runPython("import sys\nsys.path.append('/lib')\nfrom simhost import _open, _feed, _closed, _tick, _due_us, _ctl, _ident\n");
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
    if (tok[0] === "-") {
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

const server = createServer((s) => {
  const n = nextConn++;
  conns.set(n, s);
  open(n);
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
});
server.listen(portArg, "127.0.0.1", () => {
  process.stdout.write(`LISTEN ${server.address().port} ${ident}\n`);
  schedule(true);
});

const rl = createInterface({ input: process.stdin });
rl.on("line", (line) => {
  try {
    process.stdout.write("OK " + ctl(JSON.parse(line)) + "\n");
  } catch (e) {
    process.stdout.write("ERR " + String(e).split("\n").join(" | ") + "\n");
  }
  schedule(true);
});
rl.on("close", () => process.exit(0));
