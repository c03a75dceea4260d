# The board's side of the backbone link on a microcontroller: USB CDC (the REPL's stdin/stdout)
# or a UART.  read() -> bytes available now (or None), write(bytes), wait(µs): sleep until input
# or the timeout, close(): hand the port back to the REPL.

import sys


class StdioLink:
    # USB CDC on rp2/esp32-s2/s3 (and the UART REPL on plain esp32): sys.stdin/stdout in binary.
    # Ctrl-C is turned off so a 0x03 in a frame does not interrupt the firmware; see firmware.py
    # for the way back to the REPL.
    def __init__(self):
        import select

        import micropython

        micropython.kbd_intr(-1)
        self._micropython = micropython
        self._in = sys.stdin.buffer
        self._out = sys.stdout.buffer
        self._poll = select.poll()
        self._poll.register(sys.stdin, select.POLLIN)

    def read(self):
        data = bytearray()
        while len(data) < 256 and self._poll.poll(0):
            data.extend(self._in.read(1))
        return bytes(data) if data else None

    def write(self, data):
        self._out.write(data)

    def wait(self, us):
        self._poll.poll(max(0, us // 1000))

    def close(self):
        self._micropython.kbd_intr(3)


class UartLink:
    def __init__(self, machine, uart_id=0, baudrate=115200, tx=None, rx=None, rxbuf=1024):
        kw = {"baudrate": baudrate, "rxbuf": rxbuf}
        if tx is not None:
            kw["tx"] = machine.Pin(tx)
        if rx is not None:
            kw["rx"] = machine.Pin(rx)
        self._uart = machine.UART(uart_id, **kw)
        import time

        self._time = time

    def read(self):
        n = self._uart.any()
        return self._uart.read(n) if n else None

    def write(self, data):
        self._uart.write(data)

    def wait(self, us):
        # The UART has no poll on every port: sleep in short slices, at most 1 ms late.
        t = self._time
        end = t.ticks_add(t.ticks_us(), us)
        while not self._uart.any():
            left = t.ticks_diff(end, t.ticks_us())
            if left <= 0:
                break
            t.sleep_us(min(1000, left))

    def close(self):
        self._uart.deinit()


def open_link(cfg, machine):
    kind = cfg.get("kind", "usb")
    if kind == "usb":
        return StdioLink()
    if kind == "uart":
        return UartLink(
            machine,
            cfg.get("id", 0),
            cfg.get("baudrate", 115200),
            cfg.get("tx"),
            cfg.get("rx"),
            cfg.get("rxbuf", 1024),
        )
    raise ValueError("link kind must be usb or uart, not %s" % kind)
