// A probe of the MicroPython simulator's modules (virtual/world/) in real MicroPython (the
// WebAssembly port, 32-bit like a board's: small integers are 31 bits).  Usage:
// node simworld.mjs SIMWORLD_DIR PROBE.py CASES_JSON: the simulator's modules as /lib/simworld,
// PROBE.py run, then its run(*case) for each case (it prints one JSON line a case).
import { readFileSync } from "node:fs";
import { loadMicroPython } from "@micropython/micropython-webassembly-pyscript";
import { copyTree } from "../../src/missing_link/virtual/world/mpfs.mjs";

const [simworld, probe, cases] = process.argv.slice(2);
const mp = await loadMicroPython({
  stdout: (line) => process.stdout.write(line + "\n"),
  stderr: (line) => process.stderr.write("mpy! " + line + "\n"),
});
mp.FS.mkdir("/lib");
copyTree(mp, simworld, "/lib/simworld");
mp.runPython(readFileSync(probe, "utf8"));
const run = mp.globals.get("run");
for (const c of JSON.parse(cases)) run(...c);
