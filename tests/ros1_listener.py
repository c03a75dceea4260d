"""An independent ROS 1 subscriber: Debian's rospy in the system Python, no missing_link code.
Prints one JSON line per message received on each topic given, until --count per topic."""

import argparse
import json
import sys
import threading

import genpy.dynamic
import rospy
from sensor_msgs.msg import Range


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--custom", required=True, help="TOPIC=TYPE=DEFINITION")
    ap.add_argument("--range", help="a sensor_msgs/Range topic")
    ap.add_argument("--command", help="TOPIC=VALUE: publish VALUE there (the custom type), 2 Hz")
    ap.add_argument("--expect", type=int, help="done when the custom topic carries this value")
    ap.add_argument("--count", type=int, default=5)
    ap.add_argument("--timeout", type=float, default=30)
    a = ap.parse_args()
    topic, typ, text = a.custom.split("=", 2)
    cls = genpy.dynamic.generate_dynamic(typ, text.replace("\\n", "\n"))[typ]
    rospy.init_node("independent_listener", disable_signals=True)
    counts = {topic: 0}
    if a.range:
        counts[a.range] = 0
    done = threading.Event()
    lock = threading.Lock()

    def out(name, obj):
        with lock:
            if a.expect is not None:
                if name == topic and a.expect in obj["values"]:
                    print(json.dumps({"topic": name, **obj}), flush=True)
                    done.set()
                return
            if counts[name] >= a.count:
                return
            counts[name] += 1
            print(json.dumps({"topic": name, **obj}), flush=True)
            if all(c >= a.count for c in counts.values()):
                done.set()

    rospy.Subscriber(
        topic,
        cls,
        lambda m: out(
            topic, {"md5": cls._md5sum, "values": list(m.values), "secs": [t.secs for t in m.times]}
        ),
    )
    if a.command:
        cmd_topic, value = a.command.split("=")
        pub = rospy.Publisher(cmd_topic, cls, queue_size=10)

        def send():
            while not done.is_set():
                pub.publish(cls(times=[rospy.Time.now()], values=[int(value)]))
                done.wait(0.5)

        threading.Thread(target=send, daemon=True).start()
    if a.range:
        rospy.Subscriber(
            a.range,
            Range,
            lambda m: out(
                a.range,
                {
                    "range": m.range,
                    "frame": m.header.frame_id,
                    "secs": m.header.stamp.secs,
                    "type": m.radiation_type,
                },
            ),
        )
    ok = done.wait(a.timeout)
    rospy.signal_shutdown("done")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
