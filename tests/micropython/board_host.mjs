// Runs the missing-link board runtime on MicroPython (WebAssembly port, from npm) as a J2A board
// whose link is this process's stdin/stdout: one hex line in (bytes from the host), one hex line
// out (the board's output after feed + poll).  Usage: node board_host.mjs BOARD_DIR SETUP_PY
import { loadMicroPython } from "@micropython/micropython-webassembly-pyscript";
import { readFileSync, readdirSync } from "node:fs";
import { createInterface } from "node:readline";

const [boardDir, setupPath] = process.argv.slice(2);
const mp = await loadMicroPython({
  stdout: (line) => process.stderr.write("mpy: " + line + "\n"),
  stderr: (line) => process.stderr.write("mpy! " + line + "\n"),
});
mp.FS.mkdir("/lib");
mp.FS.mkdir("/lib/mlboard");
for (const name of readdirSync(boardDir)) {
  if (name.endsWith(".py")) {
    mp.FS.writeFile("/lib/mlboard/" + name, readFileSync(boardDir + "/" + name));
  }
}
mp.runPython("import sys\nsys.path.append('/lib')\n" + readFileSync(setupPath, "utf8"));
const step = mp.globals.get("_step");
process.stdout.write("READY " + mp.globals.get("_ident")() + "\n");
const rl = createInterface({ input: process.stdin });
for await (const line of rl) {
  const hex = line.trim();
  if (hex === "QUIT") break;
  try {
    process.stdout.write(step(hex) + "\n");
  } catch (e) {
    process.stdout.write("ERROR " + String(e).split("\n").join(" | ") + "\n");
  }
}
