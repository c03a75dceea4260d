// The firmware's files into MicroPython's in-memory filesystem (host.mjs, heapprobe.mjs).
import { readFileSync, readdirSync, statSync } from "node:fs";
import { join } from "node:path";

// Copy the .py files of the directory tree `src` to `dst` in `mp`'s filesystem (no caches);
// `every`: every file, as it is (a board's flash); `src` null: `dst` empty.
export function copyTree(mp, src, dst, every = false) {
  mp.FS.mkdir(dst);
  for (const name of src === null ? [] : readdirSync(src)) {
    const p = join(src, name);
    if (statSync(p).isDirectory()) {
      if (every || name !== "__pycache__") copyTree(mp, p, dst + "/" + name, every);
    } else if (every || name.endsWith(".py")) {
      mp.FS.writeFile(dst + "/" + name, readFileSync(p));
    }
  }
}
