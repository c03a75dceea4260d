"""``serial:///dev/ttyACM0?baud=115200``: UARTs, USB CDC-ACM boards, pseudo-terminals (pyserial)."""

from __future__ import annotations

from urllib.parse import unquote, urlsplit

import serial

from ..errors import BadURL, TransportBroken
from .base import FdTransport

DEFAULT_BAUD = 115200


class SerialTransport(FdTransport):
    def __init__(self, url: str, port: serial.Serial) -> None:
        super().__init__(url, port.fileno())
        self.port = port

    def _recv(self, n: int) -> bytes:
        try:
            data: bytes = self.port.read(max(1, min(n, self.port.in_waiting)))
        except serial.SerialException as e:
            # pyserial says "device reports readiness to read but returned no data" when the
            # other end of a pty or an unplugged USB serial device is gone.
            raise OSError(str(e)) from e
        return data

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._wake_reader()
            try:
                self.port.close()
            except (OSError, serial.SerialException):
                pass


def open_serial(url: str, query: dict[str, str]) -> SerialTransport:
    path = unquote(urlsplit(url).path)
    if not path:
        raise BadURL(f"{url!r}: expected serial:///dev/DEVICE[?baud=N]")
    try:
        baud = int(query.get("baud", DEFAULT_BAUD))
    except ValueError as e:
        raise BadURL(f"{url!r}: baud must be a number, not {query.get('baud')!r}") from e
    try:
        port = serial.Serial(path, baudrate=baud, timeout=0, write_timeout=2.0, exclusive=True)
    except (serial.SerialException, OSError, ValueError) as e:
        raise TransportBroken(f"{url}: cannot open: {e}") from e
    # Whatever the board sent before we opened the port (samples nobody read) is stale.
    port.reset_input_buffer()
    return SerialTransport(url, port)
