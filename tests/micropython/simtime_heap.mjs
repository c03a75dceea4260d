// simtime.ticks_diff and ticks_add (the simulated board's clock, --fast) in real MicroPython (the
// WebAssembly port, 32-bit like a board's: small integers are 31 bits).  Usage:
// node simtime_heap.mjs SIMWORLD_DIR CASES_JSON; CASES: [[a, b, n], ...]; one JSON line out a
// case: what the heap grew by over n calls of each (collections off; the calls' results kept in
// preallocated lists), ticks_diff(a, b) and ticks_add(b, ticks_diff(a, b)).
import { loadMicroPython } from "@micropython/micropython-webassembly-pyscript";
import { copyTree } from "../../src/missing_link/virtual/world/mpfs.mjs";

const [simworld, cases] = process.argv.slice(2);
const mp = await loadMicroPython({
  stdout: (line) => process.stdout.write(line + "\n"),
  stderr: (line) => process.stderr.write("mpy! " + line + "\n"),
});
mp.FS.mkdir("/lib");
copyTree(mp, simworld, "/lib/simworld");
mp.runPython(`
import sys
sys.path.append('/lib')
import simworld.simtime as simtime
import gc
OUT = [0, 0]

def run(a, b, n):
    diff = simtime.ticks_diff
    add = simtime.ticks_add
    gc.collect()
    gc.disable()
    before = gc.mem_alloc()
    for _ in range(n):
        OUT[0] = diff(a, b)
        OUT[1] = add(b, OUT[0])
    grew = gc.mem_alloc() - before
    gc.enable()
    print('{"grew": %d, "diff": %d, "add": %d}' % (grew, OUT[0], OUT[1]))
`);
const run = mp.globals.get("run");
for (const [a, b, n] of JSON.parse(cases)) run(a, b, n);
