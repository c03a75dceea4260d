"""An independent ROS 1 node for the standard types: Debian's rospy in the system Python, the
installed message classes, no missing_link code.  Subscribes to each --sub TOPIC=TYPE (a ROS 1
type like sensor_msgs/Imu), publishes each --float64 TOPIC=VALUE at 10 Hz, and prints one JSON
object with the messages summarised once every topic has --count of them (or --timeout)."""

import argparse
import json
import threading
import time

import roslib.message
import rospy
from std_msgs.msg import Float64


def summarise(msg):
    if hasattr(msg, "__slots__"):
        out = {}
        for k in msg.__slots__:
            v = getattr(msg, k)
            if k == "header":
                out["stamp_ns"] = v.stamp.to_nsec()
                out["frame_id"] = v.frame_id
            elif hasattr(v, "to_nsec"):
                out[k] = v.to_nsec()
            else:
                out[k] = summarise(v)
        return out
    if isinstance(msg, (list, tuple)):
        return [summarise(x) for x in msg]
    return msg


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sub", action="append", default=[])
    ap.add_argument("--float64", action="append", default=[])
    ap.add_argument("--count", type=int, default=3)
    ap.add_argument("--timeout", type=float, default=40)
    a = ap.parse_args()
    rospy.init_node("standard_listener", disable_signals=True)
    got = {}
    lock = threading.Lock()

    def keep(topic, msg):
        with lock:
            got[topic] = [*got[topic][-20:], {**summarise(msg), "recv_ns": time.time_ns()}]

    for spec in a.sub:
        topic, type_name = spec.split("=")
        got[topic] = []
        rospy.Subscriber(topic, roslib.message.get_message_class(type_name),
                         lambda m, t=topic: keep(t, m))  # fmt: skip
    pubs = [(rospy.Publisher(t, Float64, queue_size=10), float(v))
            for t, v in (s.split("=") for s in a.float64)]  # fmt: skip
    deadline = time.monotonic() + a.timeout
    while time.monotonic() < deadline:
        for pub, value in pubs:
            pub.publish(Float64(data=value))
        with lock:
            if all(len(v) >= a.count for v in got.values()):
                break
        time.sleep(0.1)
    with lock:
        print(json.dumps({"received": got}), flush=True)
    rospy.signal_shutdown("done")


if __name__ == "__main__":
    main()
