// A board's heap for the firmware under MicroPython's WebAssembly port (host.mjs --heap BYTES).
//
// The npm build grows its heap on demand (MICROPY_GC_SPLIT_HEAP_AUTO: a new heap area is
// malloc'ed when an allocation fails), where a board has a fixed one: a Raspberry Pi Pico has
// what the RP2040 port's linker script leaves of its 256 KiB of RAM (docs/hardware.md,
// "Memory").  So, once the simulator's own modules are loaded and before the firmware is:
//
// 1. padding: one bytearray takes whatever the heap has free beyond BYTES, so the firmware's
//    share is BYTES exactly (gc.mem_free() less the port's 128 MiB "max new split", simgc.py);
// 2. no growth: the WebAssembly memory may not grow any more and every byte of C heap left is
//    malloc'ed here (and never freed) but one piece of RESERVE bytes (node's calls into the
//    interpreter malloc small buffers from it), less than the GC heap's size: a new heap area is
//    never smaller than the heap it joins (py/gc.c gc_try_add_heap), so none can be added, and
//    an allocation that finds no room fails with MemoryError, as on a board.
// The padding comes last, in pieces (the free space has holes by then).
//
// What is not a board's: this port collects only when the step returns to node (simgc.py), so
// garbage made within one step is never collected during it: the firmware needs its live data,
// plus one step's garbage, plus what it lets pile up between collections.  Stricter than a
// board, not looser.

export const SPLIT = 128 * 1024 * 1024; // gc_get_max_new_split() of the webassembly port
export const SIM_ROOM = 128 * 1024; // GC heap for the simulator's own modules (~57 KiB), beyond BYTES
const RESERVE = 64 * 1024; // (less than SIM_ROOM: less than any GC heap here)

// emscripten says every refused growth on stderr (its `err`, bound to console.error when the
// module is made): quiet while this module exhausts the C heap on purpose
let quiet = false;
export function quietGrowth() {
  const orig = console.error;
  console.error = (...a) => {
    if (quiet && /grow/i.test(String(a[0]))) return;
    orig(...a);
  };
}

function freeNow(mp) {
  // (the interpreter's own gc module: `gc` is simgc.py's by now)
  mp.runPython(
    `from simworld.simgc import _gc\n_ml_free = _gc.mem_free() - ${SPLIT}\n` +
      "_ml_alloc = _gc.mem_alloc()",
  );
  return [mp.globals.get("_ml_free"), mp.globals.get("_ml_alloc")];
}

// -> [the bytes allocated (the simulator's and the padding: simgc.BASE), the bytes free beyond
// BYTES the padding could not take (less than a few blocks: simgc.SLACK)]
export function capHeap(mp, bytes) {
  mp.runPython("import gc\ngc.collect()"); // (runs as the call returns: on this port, then)
  const [free] = freeNow(mp);
  if (free < bytes + 1024) {
    throw new Error(`--heap ${bytes}: the simulator left only ${free} bytes (SIM_ROOM)`);
  }
  const M = mp._module;
  WebAssembly.Memory.prototype.grow = function () {
    throw new RangeError("the board's heap is fixed (--heap)");
  };
  quiet = true;
  const reserve = M._malloc(RESERVE); // (given back once the rest is taken: one piece)
  for (let size = 1 << 26; size >= 64; size >>= 1) while (M._malloc(size));
  M._free(reserve);
  // room held back for saying why the firmware stopped (mpyhost.py release()): the simulator's
  mp.runPython("from simworld import mpyhost\nmpyhost.spare = [None] * 1024");
  // The padding, in pieces (no new area can be added now, and the free space has holes): a
  // piece that does not fit is tried at half the size, down to one block; a collection between
  // the pieces (this port collects only between calls, simgc.py).
  mp.runPython("_ml_pad = []");
  let piece = 1 << 16;
  for (let left = freeNow(mp)[0]; left - bytes > 32 && piece >= 16; left = freeNow(mp)[0]) {
    const want = Math.max(1, Math.min(piece, left - bytes - 32));
    mp.runPython(
      `_ml_ok = True\ntry:\n    _ml_pad.append(bytearray(${want}))\nexcept MemoryError:\n` +
        "    _ml_ok = False",
    );
    if (!mp.globals.get("_ml_ok")) piece >>= 1;
    mp.runPython("import gc\ngc.collect()");
  }
  quiet = false;
  mp.runPython("import gc\ngc.collect()");
  const [left, alloc] = freeNow(mp);
  if (left < bytes || left - bytes > 64) {
    throw new Error(`--heap ${bytes}: the padding left ${left} bytes free, not ${bytes}`);
  }
  return [alloc, left - bytes];
}
