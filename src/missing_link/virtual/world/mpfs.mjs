// The firmware's files into MicroPython's in-memory filesystem (host.mjs, heapprobe.mjs).
import { readFileSync, readdirSync, statSync } from "node:fs";
import { join } from "node:path";

// Copy the .py files of the directory tree `src` to `dst` in `mp`'s filesystem (no caches).
export function copyTree(mp, src, dst) {
  mp.FS.mkdir(dst);
  for (const name of readdirSync(src)) {
    const p = join(src, name);
    if (statSync(p).isDirectory()) {
      if (name !== "__pycache__") copyTree(mp, p, dst + "/" + name);
    } else if (name.endsWith(".py")) {
      mp.FS.writeFile(dst + "/" + name, readFileSync(p));
    }
  }
}
