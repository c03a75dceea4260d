"""``world URL VERB ...``: a hand on a running virtual board's world (virtual/worldctl.py's
endpoint, docs/world.md): push, turn, bump, place, tilt the robot; block a ranger, fail a
sensor, make a wheel slip; or read where the robot is (``state``)."""

from __future__ import annotations

import argparse

from ..errors import ConfigError
from ..text import clean
from .common import emit_json

#: each verb's arguments as the world's event keys (cli/board_args.py names them so)
KEYS = {
    "state": (),
    "push": ("dx_m", "dy_m", "over_s"),
    "turn": ("deg", "over_s"),
    "bump": ("dx_m", "dy_m"),
    "place": ("x_m", "y_m", "yaw_deg"),
    "tilt": ("roll_deg", "pitch_deg", "over_s"),
    "block": ("part", "distance_m", "for_s"),
    "fail": ("part", "mode", "for_s"),
    "slip": ("part", "fraction", "for_s"),
}


def cmd_world(args: argparse.Namespace) -> int:
    from ..virtual.worldctl import ask

    answer = ask(args.url, args.verb, {k: getattr(args, k) for k in KEYS[args.verb]})
    if "error" in answer:
        raise ConfigError(str(answer["error"]))  # (the world refused it: one line, exit 2)
    state = answer.get("state", {})
    if args.json:
        emit_json(state)
        return 0
    print(
        f"t {state['t_s']:.3f} s  x {state['x_m']:.3f} m  y {state['y_m']:.3f} m  "
        f"yaw {state['yaw_deg']:.1f} deg  speed {state['speed_m_s']:.3f} m/s  "
        f"turn {state['turn_dps']:.1f} deg/s  battery {state['battery_v']:.2f} V  "
        f"bumps {state['bumps']}"
        + (f"  blocked {clean(','.join(state['blocked']))}" if state.get("blocked") else "")
        + (f"  failed {clean(','.join(state['failed']))}" if state.get("failed") else "")
    )
    return 0
