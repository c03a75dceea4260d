"""The world a virtual board's robot lives in (issue 47): a body moved by the board file's
actuators in a room of walls, seen by its rangers, felt by its IMU, compass and GPS, drawing its
battery.  Pure: no I/O, time comes in, a seeded random stream per part, so the same seed and
the same commands give the same samples.  The runtimes feed it and deliver what it says
(virtual/worldlink.py); docs/world.md is its reference.

- spec.py: what a world is made of, with every default; worldfile.py: a world file read into it
- datasheets.py: each part's kind and figures; robot.py: the board file's parts as the world
  mounts them
- geometry.py, motion.py: axes, rotations, rays; the body, its wheels and what stops it
- sensing.py: what each sensor reads; world.py: the world, stepped by its runtime
"""
