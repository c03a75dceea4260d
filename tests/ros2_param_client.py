"""An independent ROS 2 parameter client (rclpy and rcl_interfaces only; nothing of missing_link):
lists a node's parameters, describes some, sets some, and prints one JSON object.

    python ros2_param_client.py --node /missing_link --prefix thesis. \
        --describe thesis.dist_ir.rate_hz --set thesis.dist_ir.rate_hz=double:5.0 ...

Each --set is NAME=TYPE:VALUE (TYPE bool, integer, double, string) and is sent alone; the
result (successful, reason) and the values read back afterwards are reported."""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import rclpy
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters

TYPES = {
    "bool": (ParameterType.PARAMETER_BOOL, "bool_value", lambda t: t == "true"),
    "integer": (ParameterType.PARAMETER_INTEGER, "integer_value", int),
    "double": (ParameterType.PARAMETER_DOUBLE, "double_value", float),
    "string": (ParameterType.PARAMETER_STRING, "string_value", str),
}


def value_of(v: ParameterValue) -> Any:
    for _kind, field, _conv in TYPES.values():
        if v.type == _kind:
            return getattr(v, field)
    return None


def call(node: Any, srv_type: Any, name: str, request: Any, timeout: float = 10.0) -> Any:
    client = node.create_client(srv_type, name)
    if not client.wait_for_service(timeout_sec=timeout):
        raise SystemExit(f"no service {name}")
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    if future.result() is None:
        raise SystemExit(f"{name}: no answer")
    return future.result()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--node", default="/missing_link")
    ap.add_argument("--prefix", default="")
    ap.add_argument("--describe", action="append", default=[])
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--wait", type=float, default=30.0, help="for the prefix's parameters")
    a = ap.parse_args()
    rclpy.init()
    node = rclpy.create_node("param_client")
    out: dict[str, Any] = {}
    deadline = time.monotonic() + a.wait
    names: list[str] = []
    while time.monotonic() < deadline:  # until the board's parameters are there, all of them
        req = ListParameters.Request()
        now = list(call(node, ListParameters, f"{a.node}/list_parameters", req).result.names)
        if any(n.startswith(a.prefix) for n in now) and now == names:
            break
        names = now
        time.sleep(0.5)
    out["names"] = sorted(n for n in names if n.startswith(a.prefix))
    if a.describe:
        req = DescribeParameters.Request(names=a.describe)
        got = call(node, DescribeParameters, f"{a.node}/describe_parameters", req)
        out["descriptors"] = {
            d.name: {
                "type": d.type,
                "read_only": d.read_only,
                "description": d.description,
                "float_range": [[r.from_value, r.to_value] for r in d.floating_point_range],
                "int_range": [[r.from_value, r.to_value] for r in d.integer_range],
            }
            for d in got.descriptors
        }
    results = []
    for item in a.set:
        name, _, typed = item.partition("=")
        kind, _, text = typed.partition(":")
        ptype, field, conv = TYPES[kind]
        value = ParameterValue(type=ptype, **{field: conv(text)})
        req = SetParameters.Request(parameters=[Parameter(name=name, value=value)])
        r = call(node, SetParameters, f"{a.node}/set_parameters", req).results[0]
        results.append({"set": item, "successful": r.successful, "reason": r.reason})
    out["results"] = results
    req = GetParameters.Request(names=out["names"])
    got = call(node, GetParameters, f"{a.node}/get_parameters", req)
    out["values"] = {n: value_of(v) for n, v in zip(out["names"], got.values, strict=True)}
    print(json.dumps(out))
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
