"""Putting firmware on boards: board files, generated firmware, flashing and the check after.

- :mod:`.boardfile` - a board file (``BOARD = {...}``): what is connected where, validated
- :mod:`.flash` - ``missing-link flash``: MicroPython boards through mpremote
- :mod:`.avr` - AVR boards: the C firmware built with make and written with avrdude
- :mod:`.avrgen` - ``gen-firmware``: the C tables of an AVR board from its board file
- :mod:`.check` - does the flashed board answer J2A as its board file says
"""
