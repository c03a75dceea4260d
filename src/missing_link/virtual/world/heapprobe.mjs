// What a board file's parts take of the heap under MicroPython (the WebAssembly port, 32-bit
// like a board's), measured for the fit check's table (deploy/heap.py, docs/hardware.md
// "Memory"):
//
//   node heapprobe.mjs SPEC.json    -> one JSON line: {"runtime": B, "modules": {module: B},
//                                      "instance": {driver: B}, "bus": B}
//
// SPEC: {"entries": {driver: a board file entry without name and id}, "bus": {i2c bus}}.
// Each figure is the heap still allocated after a collection (live data: bytecode, objects),
// as deltas in one interpreter: "runtime", the firmware's modules and a built firmware with no
// transducers; "modules", a driver's module imported; "instance", one more transducer of it in
// a built firmware (a board file with two of it, less one with one); "bus", an I2C bus opened.
// This port collects only when a call into it returns (simgc.py), so every step is a call of
// its own, with gc.collect() asked for at its end.  The clock is simulated time (simtime.py, as
// host.mjs --fast): with the port's, which is the host's, the parts' state and how often a
// driver polled one at its start-up came from how fast the host ran, and what a collection
// keeps of the garbage with them, so each figure moved by up to 128 bytes from run to run.
import { readFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";
import { copyTree } from "./mpfs.mjs";

const here = dirname(fileURLToPath(import.meta.url));
const spec = JSON.parse(readFileSync(process.argv[2], "utf8"));
const mpyPath = process.argv[3];
const { loadMicroPython } = await import(
  mpyPath ? new URL("file://" + mpyPath).href : "@micropython/micropython-webassembly-pyscript"
);
let said = ""; // the interpreter's last line out (qstr_info's)
const mp = await loadMicroPython({
  stdout: (line) => {
    said = line;
    process.stderr.write("mpy: " + line + "\n");
  },
  stderr: (line) => process.stderr.write("mpy! " + line + "\n"),
});

mp.FS.mkdir("/lib");
copyTree(mp, join(here, "..", "..", "board"), "/lib/mlboard");
copyTree(mp, here, "/lib/simworld");
mp.FS.mkdir("/flash");
mp.FS.chdir("/flash");
mp.runPython(
  [
    "import sys",
    "sys.path.append('/lib')",
    "import simworld.simtime",
    "sys.modules['time'] = simworld.simtime",
    "import simworld.simgc",
    "sys.modules['gc'] = simworld.simgc",
    "import simworld.machine",
    "sys.modules['machine'] = simworld.machine",
    "from simworld import parts",
    "KEEP = []",
  ].join("\n"),
);

// run `code`, then collect (at the call's end), then read what is allocated
function live(code) {
  mp.runPython(code + "\nimport gc\ngc.collect()");
  mp.runPython("import gc\n_alloc = gc.mem_alloc()");
  return mp.globals.get("_alloc");
}

// The interned names' tables (micropython.qstr_info): MicroPython adds a pool twice the size of
// the last when one is full, so whichever import fills it pays for a table that holds the next
// imports' names too (the HC-SR04 module measured 10,560 bytes for its 1,600 once the
// simulator's own modules had moved the fill).  A module's share of a new pool is its names'
// entries (QSTR_ENTRY bytes each: hash, length, pointer on a 32-bit port).
const QSTR_ENTRY = 6;
function names() {
  mp.runPython("import micropython\nmicropython.qstr_info()");
  const m = said.match(/n_qstr=(\d+), n_str_data_bytes=(\d+), n_total_bytes=(\d+)/);
  if (!m) throw new Error(`qstr_info said ${JSON.stringify(said)}`);
  return { n: Number(m[1]), tables: Number(m[3]) - Number(m[2]) };
}
function newPool(before, after) {
  return Math.max(0, after.tables - before.tables - (after.n - before.n) * QSTR_ENTRY);
}

function board(entries) {
  return JSON.stringify({
    name: "probe",
    buses: { i2c0: spec.bus },
    transducers: entries.map((e, i) => ({ name: `t${i}`, id: i, ...e })),
  });
}

// the simulated parts first (the simulator's, not the firmware's), then the firmware
function populate(entries) {
  return `B = ${board(entries)}\nparts.populate(B)\nKEEP.append(B)`;
}
const build = "import machine\nfrom mlboard import firmware\nKEEP.append(firmware.build(B, machine))";

const out = { runtime: 0, modules: {}, instance: {}, bus: 0 };
const s0 = live("pass");
const mods = live("import mlboard.firmware, mlboard.link");
const p0 = live(populate([]));
let at = live(build);
out.runtime = mods - s0 + (at - p0);
const bus = live(
  `import machine\nfrom mlboard import firmware\n` +
    `KEEP.append(firmware.open_buses({"buses": {"b": ${JSON.stringify(spec.bus)}}}, machine))`,
);
out.bus = bus - at;
at = bus;
for (const [driver, entry] of Object.entries(spec.entries)) {
  const q0 = names();
  const module = live(`from mlboard.drivers import driver_class\nKEEP.append(driver_class("${driver}"))`);
  out.modules[driver] = module - at - newPool(q0, names());
  const p1 = live(populate([entry]));
  const one = live(build) - p1; // a firmware and one of it
  const p2 = live(populate([entry, entry]));
  at = live(build);
  out.instance[driver] = at - p2 - one; // (a firmware and two of it) - (a firmware and one)
}
process.stdout.write(JSON.stringify(out) + "\n");
