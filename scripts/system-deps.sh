#!/usr/bin/env bash
# Installs the Debian packages missing-link's tests need, only if they are missing. Idempotent.
#   nodejs + npm: run MicroPython (WebAssembly port from npm) to prove the board runtime on it.
#   g++: create-msgs --build compiles the generated ROS 2 type support (tests do it).
#   gcc-avr, avr-libc, simavr, libsimavr-dev, libsimavrparts1, avrdude: the AVR firmware is built and run
#           as real AVR machine code in simavr by the tests (src/missing_link/firmware/avr).
#   chromium: the web console's test drives it with Playwright (tests/test_web_browser.py); Debian's,
#           since this machine cannot download Playwright's own browser builds.
#   --ros1: ROS 1 from Debian (ros-core, rospy, message packages) for the ros1 publisher and its
#           test; .ci/run passes it.  `make demo` never needs it.
set -euo pipefail
need=()
command -v node >/dev/null 2>&1 || need+=(nodejs)
command -v npm >/dev/null 2>&1 || need+=(npm)
command -v c++ >/dev/null 2>&1 || need+=(g++)   # create-msgs --build compiles ROS 2 type support
for pkg in gcc-avr avr-libc binutils-avr simavr libsimavr-dev libsimavrparts1 avrdude chromium; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || need+=("$pkg")
done
if [ "${1:-}" = "--ros1" ]; then
    for pkg in ros-core python3-rospy python3-rosbag python3-sensor-msgs python3-diagnostic-msgs; do
        dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || need+=("$pkg")
    done
fi
if [ ${#need[@]} -eq 0 ]; then
    echo "system-deps: nothing to install"
    exit 0
fi
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
echo "system-deps: installing ${need[*]}"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}"
