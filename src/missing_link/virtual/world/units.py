"""Quantities a device model keeps as whole numbers of a small unit (a GPS receiver's altitude in
0.1 m, as its sentence prints it; a sonar's distance in mm; a latitude as whole degrees and
1e-7 degree), read and set by the world in the unit a person says (m, cm, degrees).  The
MicroPython subset only (this file runs inside the board's interpreter too; worldlink.py, under
CPython, splits degrees as the models keep them).
"""


def scaled(attr, per_unit):
    """A property in units over the integer ``attr`` kept in 1/``per_unit`` of one: it reads
    ``attr / per_unit`` and a set rounds to the nearest step (never a float in ``attr``)."""

    def get(self):
        return getattr(self, attr) / per_unit

    def put(self, value):
        setattr(self, attr, int(round(value * per_unit)))

    return property(get, put)


def scaled_xyz(attr, per_unit):
    """``scaled`` for a vector: a property in units over the list ``attr`` of three integers
    (x, y, z) kept in 1/``per_unit`` of one; it reads a tuple, a set rounds each axis in place."""

    def get(self):
        return tuple(v / per_unit for v in getattr(self, attr))

    def put(self, value):
        xyz = getattr(self, attr)
        for i in range(3):
            xyz[i] = int(round(value[i] * per_unit))

    return property(get, put)


def split_degrees(deg):
    """Degrees as (whole degrees, 1e-7 degree), both of the sign of ``deg``: small integers, where
    one float would lose the seventh decimal under MicroPython."""
    e7 = int(round(deg * 10000000))
    whole = int(e7 / 10000000)
    return whole, e7 - whole * 10000000


def degrees(whole_attr, e7_attr):
    """A property in degrees over the integers ``whole_attr`` and ``e7_attr`` (split_degrees)."""

    def get(self):
        return getattr(self, whole_attr) + getattr(self, e7_attr) / 10000000

    def put(self, deg):
        whole, e7 = split_degrees(deg)
        setattr(self, whole_attr, whole)
        setattr(self, e7_attr, e7)

    return property(get, put)
