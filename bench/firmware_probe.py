# Runs inside the board's interpreter (MicroPython under node, via bench_firmware.py) and under
# CPython (the reference): what the firmware costs per sample and per received byte, and (on
# MicroPython) the heap the thesis-rig firmware takes.  Prints "key value" lines.
import gc
import sys
import time

MPY = sys.implementation.name == "micropython"
if MPY:
    ticks = time.ticks_us
    diff = time.ticks_diff
else:
    sys.path.insert(0, sys.argv[1])

    def ticks():
        return time.perf_counter_ns() // 1000

    def diff(a, b):
        return a - b


def mem():
    gc.collect()
    return gc.mem_free() if hasattr(gc, "mem_free") else -1


free0 = mem()
if MPY:
    import machine
    from board import BOARD
    from mlboard.firmware import build

    fw_rt, _drivers = build(BOARD, machine)
    print("heap_rig", free0 - mem())
    from mlboard.runtime import BoardRuntime, Transducer
    from mlboard.wire import SOF, encode_frame
else:
    from missing_link.board.runtime import BoardRuntime, Transducer
    from missing_link.board.wire import SOF, encode_frame


def per_sample(chan, dtype, value, n):
    rt = BoardRuntime("b", "m", "s", epoch="e")
    t = Transducer("x", 1, "p", "m", chan, dtype, -1 if dtype != "float" else float("nan"))
    rt.add_transducer(t)
    t0 = ticks()
    for i in range(n):
        for ch in range(chan):
            rt.record(t, ch, value if dtype == "float" else i & 0xFFFF)
        rt.poll()
        rt.take_output()
    return diff(ticks(), t0) / n


def per_byte(n):
    rt = BoardRuntime("b", "m", "s", epoch="e")
    req = encode_frame(SOF, 1, rt.index["a2jClock"], b"")
    t0 = ticks()
    for _ in range(n):
        rt.feed(req)
        rt.take_output()
    return diff(ticks(), t0) / (n * len(req))


def after_t3(n):
    # From a2jClock's t3 stamp (the runtime's clock() call in take_output) to the reply's bytes
    # in hand: work that lengthens the return trip the host sees, a bias clock sync cannot see.
    rt = BoardRuntime("b", "m", "s", epoch="e")
    req = encode_frame(SOF, 1, rt.index["a2jClock"], b"")
    clock = rt.clock
    stamped = [0]

    def stamping_clock():
        stamped[0] = ticks()
        return clock()

    total = 0
    for _ in range(n):
        rt.feed(req)
        rt.clock = stamping_clock
        rt.take_output()
        total += diff(ticks(), stamped[0])
        rt.clock = clock
    if stamped[0] == 0:  # (patch or fail: the runtime no longer stamps t3 with rt.clock)
        raise SystemExit("after_t3: take_output never called rt.clock: nothing was measured")
    return total / n


N = 20000 if MPY else 50000
print("us_per_sif_1ch", per_sample(1, "int32_t", 0, N))
print("us_per_sif_7ch", per_sample(7, "float", 1.5, N // 4))
print("us_per_rx_byte", per_byte(N // 4))
print("us_after_t3", after_t3(N // 4))
