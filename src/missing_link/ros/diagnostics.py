"""``/diagnostics``: every board's and publisher's status as a
``diagnostic_msgs/msg/DiagnosticArray`` in CDR, the same bytes for every face that carries it
(MCAP, Zenoh, rclpy, Foxglove).  Pure: a rosbags typestore in, bytes out."""

from __future__ import annotations

from typing import Any

DIAG_TOPIC = "/diagnostics"
DIAG_TYPE = "diagnostic_msgs/msg/DiagnosticArray"


def status_label(s: dict[str, Any]) -> str:
    """The DiagnosticStatus name of one status dict: a board's or a publisher's."""
    if "board" in s:
        return f"missing_link: {s['board']}"
    return f"missing_link publisher: {s.get('publisher')}"


def status_level(s: dict[str, Any]) -> int:
    return int(s.get("level", 0 if s.get("state") == "up" else 2))


def status_message(s: dict[str, Any]) -> str:
    return str(s.get("message") or s.get("state", ""))


def diagnostics_cdr(typestore: Any, status: list[dict[str, Any]], now_ns: int) -> bytes:
    """Per-board status as a ``diagnostic_msgs/msg/DiagnosticArray`` (CDR)."""
    ts = typestore
    T = ts.types
    sec, nsec = divmod(now_ns, 1_000_000_000)
    header = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=""
    )
    Status, KV = T["diagnostic_msgs/msg/DiagnosticStatus"], T["diagnostic_msgs/msg/KeyValue"]
    items = []
    for s in status:
        values = [KV(key=str(k), value=str(v)) for k, v in s.items() if k != "board"]
        items.append(
            Status(
                level=status_level(s),
                name=status_label(s),
                message=status_message(s),
                hardware_id=str(s.get("serial", "")),
                values=values,
            )
        )
    msg = T[DIAG_TYPE](header=header, status=items)
    return bytes(ts.serialize_cdr(msg, DIAG_TYPE))
