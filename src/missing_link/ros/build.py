"""Build and install a generated ROS 2 message package with the ROS 2 found in this environment.

``colcon`` when it is on PATH (as in a ROS workspace), plain CMake otherwise.  ROS 2 is found
through ``AMENT_PREFIX_PATH`` (a sourced ``/opt/ros/<distro>/setup.bash``) and, for ROS 2 from
PyPI wheels, this Python's own prefix (``sys.prefix/share/ament_cmake``).  The build log goes to
``PREFIX/build-<package>.log``; a failure raises ``BuildError`` with its last lines.  After the
build, the daemon finds the types with ``[ros2] prefix = PREFIX`` (or
``MISSING_LINK_ROS2_PREFIX``), or on ``PYTHONPATH`` / ``LD_LIBRARY_PATH`` set as for any ROS 2
install prefix.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from ..errors import MissingLinkError


class BuildError(MissingLinkError):
    """The package could not be built (no ROS 2 found, or the compiler failed)."""


def ros2_roots() -> list[str]:
    """Install prefixes that hold ROS 2's ament_cmake (sourced setup first, then this Python)."""
    roots = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    if os.path.isdir(os.path.join(sys.prefix, "share", "ament_cmake")) and sys.prefix not in roots:
        roots.append(sys.prefix)
    return [r for r in roots if os.path.isdir(os.path.join(r, "share"))]


def build_package(
    package_dir: str, prefix: str, progress: Callable[[str], None] = lambda line: None
) -> Path:
    """Build ``package_dir`` and install it into ``prefix``; returns the log file."""
    roots = ros2_roots()
    if not any(os.path.isdir(os.path.join(r, "share", "ament_cmake")) for r in roots):
        raise BuildError(
            "no ROS 2 build tools found: source /opt/ros/<distro>/setup.bash, or pip install "
            "ros-kilted-rosidl-default-generators ros-kilted-ament-cmake cmake (docs/ros.md)"
        )
    env = dict(os.environ, AMENT_PREFIX_PATH=os.pathsep.join(roots))
    # Tools the wheels put next to this Python (cmake, rosidl) come first.
    env["PATH"] = os.pathsep.join([os.path.dirname(sys.executable), env.get("PATH", "")])
    prefix_path = Path(prefix).resolve()
    prefix_path.mkdir(parents=True, exist_ok=True)
    package = Path(package_dir).resolve()
    log_path = prefix_path / f"build-{package.name}.log"
    with open(log_path, "w", encoding="utf-8") as log, tempfile.TemporaryDirectory() as build:
        for step in _steps(package, prefix_path, build, roots, env["PATH"]):
            progress(" ".join(Path(step[0]).name if i == 0 else a for i, a in enumerate(step[:3])))
            log.write("$ " + " ".join(step) + "\n")
            log.flush()
            r = subprocess.run(step, stdout=log, stderr=subprocess.STDOUT, env=env)
            if r.returncode != 0:
                log.close()
                tail = log_path.read_text(encoding="utf-8", errors="replace").splitlines()[-15:]
                raise BuildError(
                    f"building {package.name} failed (log: {log_path}):\n  " + "\n  ".join(tail)
                )
    return log_path


def _steps(package: Path, prefix: Path, build: str, roots: list[str], path: str) -> list[list[str]]:
    """The commands that build and install: one colcon build when colcon is on ``path``, else
    CMake's configure, build and install."""
    cmake_args = [
        f"-DCMAKE_PREFIX_PATH={';'.join(roots)}",
        f"-DPython3_EXECUTABLE={sys.executable}",
        "-DBUILD_TESTING=OFF",
    ]
    colcon = shutil.which("colcon", path=path)
    if colcon:
        return [
            [
                *(colcon, "build", "--base-paths", str(package), "--build-base", build),
                *("--install-base", str(prefix), "--merge-install", "--cmake-args", *cmake_args),
            ]
        ]
    cmake = shutil.which("cmake", path=path)
    if cmake:
        return [
            [
                *(cmake, "-S", str(package), "-B", build),
                f"-DCMAKE_INSTALL_PREFIX={prefix}",
                *cmake_args,
            ],
            [cmake, "--build", build, "-j", str(os.cpu_count() or 2)],
            [cmake, "--install", build],
        ]
    raise BuildError("neither colcon nor cmake found (pip install cmake)")
