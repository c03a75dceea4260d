"""Boards' run-time configuration as ROS 2 parameters of the daemon's node (``ros2``): every key
``<transducer>.<key>`` of a board is the parameter ``<board>.<transducer>.<key>`` (for example
``thesis.dist_ir.rate_hz`` on ``/missing_link``), declared with a descriptor (its range, or its
choices in the description; read-only where the board says so).

Theory of operation
-------------------
A set from any ROS 2 client (``ros2 param set``, a parameter client, a launch file) reaches
``_on_set`` on the node's executor thread: the values are grouped per board and handed to the
daemon's ``apply`` (the board's ``a2jConfigSet``: all or nothing); a refusal is an unsuccessful
``SetParametersResult`` with the reason, and the parameter keeps its value.  ``apply`` is this
face's own (fanout.py): the keys of an actuator are commands, so with ``[ros2] commands =
false`` (the default off loopback) or an allow-list that does not name the actuator, a set that
would change them is refused (counted under ``ros2``) like a command on its topic.  A change made
through another face (``missing-link config``, ``Daemon.configure``) comes back through
``config_changed`` and is set here without going to the board again.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from ..errors import ConfigError, MissingLinkError
from ..host.config import ConfigKey, Value

log = logging.getLogger(__name__)

Apply = Callable[[dict[str, object]], dict[str, Value]]


class RosParameters:
    def __init__(self, node: Any) -> None:
        from rcl_interfaces.msg import (
            FloatingPointRange,
            IntegerRange,
            ParameterDescriptor,
            SetParametersResult,
        )

        self.node = node
        self._descriptor = ParameterDescriptor
        self._int_range, self._float_range = IntegerRange, FloatingPointRange
        self._result = SetParametersResult
        self._apply: dict[str, Apply] = {}  # board -> apply
        self._keys: dict[str, ConfigKey] = {}  # parameter name -> key
        self._following = threading.local()  # set while we follow a change made elsewhere
        self.refused = 0
        node.add_on_set_parameters_callback(self._on_set)

    def add_board(self, board: str, keys: list[ConfigKey], values: dict[str, Value],
                  apply: Apply) -> None:  # fmt: skip
        self._apply[board] = apply
        self._following.on = True  # (declaring runs the set callback: it is not a change)
        try:
            for k in keys:
                name = f"{board}.{k.name}"
                known = name in self._keys
                self._keys[name] = k
                if not known:
                    self.node.declare_parameter(
                        name, values.get(k.name, k.default), self._describe(k)
                    )
        finally:
            self._following.on = False
        self.follow(board, values)

    def _describe(self, k: ConfigKey) -> Any:
        d = self._descriptor(
            description=f"{k.name} of the board: {k.allowed()} (default {k.default})",
            read_only=k.read_only,
        )
        if k.kind == "int" and k.lo is not None and k.hi is not None:
            d.integer_range = [self._int_range(from_value=int(k.lo), to_value=int(k.hi), step=0)]
        elif k.kind == "float" and k.lo is not None and k.hi is not None:
            d.floating_point_range = [
                self._float_range(from_value=float(k.lo), to_value=float(k.hi), step=0.0)
            ]
        elif k.kind == "enum":
            d.additional_constraints = f"one of {', '.join(k.choices)}"
        return d

    def follow(self, board: str, values: dict[str, Value]) -> None:
        """The board's values changed elsewhere: the parameters follow (not sent back)."""
        from rclpy.parameter import Parameter

        if getattr(self._following, "in_set", False):
            return  # (a set through the parameters themselves: rclpy stores those values)
        params = [
            Parameter(f"{board}.{name}", value=value)
            for name, value in values.items()
            if f"{board}.{name}" in self._keys
            and self.node.get_parameter(f"{board}.{name}").value != value
        ]
        if not params:
            return
        self._following.on = True
        try:
            self.node.set_parameters(params)
        finally:
            self._following.on = False

    def _on_set(self, params: list[Any]) -> Any:
        if getattr(self._following, "on", False):
            return self._result(successful=True)
        per_board: dict[str, dict[str, object]] = {}
        for p in params:
            key = self._keys.get(p.name)
            if key is None:
                continue  # not a board's (the node's own, e.g. use_sim_time)
            board = p.name[: -len(key.name) - 1]
            per_board.setdefault(board, {})[key.name] = p.value
        self._following.in_set = True
        try:
            for board, values in per_board.items():
                try:
                    self._apply[board](values)
                except (ConfigError, MissingLinkError) as e:
                    self.refused += 1
                    log.warning("ros2: parameters of %s refused: %s", board, e)
                    return self._result(successful=False, reason=str(e))
        finally:
            self._following.in_set = False
        return self._result(successful=True)
