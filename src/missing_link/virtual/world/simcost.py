"""What the firmware's work costs in simulated time (host.mjs --fast): a Raspberry Pi Pico's
RP2040, a Cortex-M0+ at 125 MHz (8 ns a cycle), running MicroPython 1.27.  The MicroPython
subset only (simtime.py, simgc.py and machine.py charge these as the work happens).

Theory of operation
-------------------
Simulated time is a function of the simulation: what a step did, never how long the machine
running the simulator took to do it.  So the same board file, seed and host give the same run,
sample for sample and collection for collection, on a quiet machine or a busy one; and the
board is as slow as a Pico, not as fast as the host's CPU running WebAssembly (about 25 times
faster: the simulator charged that CPU time until this model replaced it).

A step (one turn of the firmware's loop) costs
  TURN_NS                       the turn's own bytecode (board/firmware.py _turn: the link's
                                read, the runtime's poll, its output, memory.poll, the wait's
                                next deadline), whatever it finds to do;
  + TRANSDUCER_NS a transducer  the runtime asks each one three times a turn (its poll, whether
                                it has a sample, its next deadline): three Python calls;
  + READ_NS a clock read        time.ticks_us under board/clock.py's WrappingClock;
  + BYTE_IN_NS a byte in        board/wire.py's decoder: a Python loop turn per byte;
  + BYTE_OUT_NS a byte out      board/wire.py's encoder: the same, escaping and summing;
  + CALL_NS a peripheral call   a method of a machine object (Pin.value, ADC.read_u16, I2C,
                                UART, PWM), with what its hardware takes: ADC_NS a conversion,
                                an I2C transfer's bus time (machine.py);
  + SCAN_NS a heap block        gc.mem_free() / gc.mem_alloc(): gc_info() walks the allocation
                                table, every block of the heap;
  + what it slept (time.sleep_us, a pulse waited for), as its own time.
What a step allocated is not charged: the interpreter cannot say without a scan of the whole
heap, which costs the simulator as much as a few steps, and a charge at the step's end would
fall after the firmware's last reading of its clock (inside the span of a collection it asked
for at its turn's end): the Python work that allocates (float maths) is charged only as far as
it reads the clock, moves bytes or calls a peripheral, an underestimate for a stepper's maths.
A collection costs COLLECT_NS (the roots: the C stack, the registers, the interpreter's root
pointers) + MARK_NS per live block (each of its four words checked for a heap pointer, what it
points to marked and pushed) + SWEEP_NS per block of the heap (the allocation table walked).

Where the figures come from: the per-block costs are counted from py/gc.c's loops in
MicroPython 1.27 (instructions per block on Thumb-1, about one cycle each, two for a load) and
checked against what MicroPython's developers measured on related chips: gc_info over a
25.6 MB heap in 64 ms (micropython/micropython#19094: about 40 ns a block on a Cortex-M7/M55
several times this clock, so ~50 Cortex-M0+ cycles: SCAN_NS 400), a full scan of an RP2350's
~500 KB in ~4 ms (micropython#15620: ~19 Cortex-M33 cycles a block at 150 MHz; the sweep's loop
does about as much: SWEEP_NS 160) and a sweep-bound collection of 1 MB of PSRAM in 13.5 ms
(micropython#19476).  The ADC conversion is the RP2040 datasheet's (section 4.9: 96 cycles of
its 48 MHz clock, 2 µs).  The interpreter's costs (TURN, TRANSDUCER, READ, BYTE, CALL) are
estimates from bytecode counts at 60 to 120 cycles a simple bytecode and ~1,000 for a Python
call on the M0+ (a Python loop that sets a pin high and low takes ~31 µs a turn on a Pico: Roy
Longbottom's Pico benchmarks); none was measured on a Pico for this firmware: that is still to do
(docs/hardware.md, "Memory").  A board's own interrupts (the encoder's edges) cost nothing
here, and the world's devices (devices.py) read the clock for free: they are not the board.
"""

CYCLE_NS = 8  # 125 MHz

TURN_NS = 100000  # ~12,500 cycles: ~100 bytecodes and ten Python calls
TRANSDUCER_NS = 25000  # ~3,000 cycles: three Python calls and their tests
READ_NS = 9600  # ~1,200 cycles: a Python method call around the port's ticks_us
BYTE_IN_NS = 6000  # ~750 cycles a byte: a loop turn, a state test, the checksum, an append
BYTE_OUT_NS = 4000  # ~500 cycles a byte: a loop turn, a test for a marker, the checksum
CALL_NS = 3000  # ~375 cycles: a method looked up and called, its arguments parsed
ADC_NS = 2000  # RP2040 datasheet 4.9.1: 96 cycles of the 48 MHz ADC clock
BLOCK = 16  # bytes a heap block (MICROPY_BYTES_PER_GC_BLOCK on a 32-bit port)

SCAN_NS = 400  # ~50 cycles a heap block: gc_info()
SWEEP_NS = 160  # ~20 cycles a heap block: gc_sweep()
MARK_NS = 600  # ~75 cycles a live block: gc_mark_subtree()
COLLECT_NS = 200000  # ~25,000 cycles: the roots (a few KiB of C stack), gc_collect_start/end


def turn_ns(transducers):
    # a loop turn's own work, with `transducers` to poll
    return TURN_NS + TRANSDUCER_NS * transducers


def collection_ns(live_blocks, heap_blocks):
    # a collection with `live_blocks` reachable in a heap of `heap_blocks`
    return COLLECT_NS + MARK_NS * live_blocks + SWEEP_NS * heap_blocks


def scan_ns(heap_blocks):
    # gc.mem_free() or gc.mem_alloc() over a heap of `heap_blocks`
    return SCAN_NS * heap_blocks
