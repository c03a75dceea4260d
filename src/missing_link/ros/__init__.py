"""ROS vocabulary without I/O: message names and ``.msg`` text from descriptors, the CDR
encoder, typestores, standard types, ``/diagnostics``, and the package ``create-msgs`` writes
and builds.

- :mod:`.msgs` - thesis-format message types from transducer descriptors, CDR, typestores
- :mod:`.standard` - standard ROS types a transducer maps to (``sensor_msgs/msg/Range``, ...)
- :mod:`.diagnostics` - the ``diagnostic_msgs/msg/DiagnosticArray`` every face publishes
- :mod:`.clock` - the clock record (one per ``a2jClock`` exchange, with the map after it)
- :mod:`.board_record` - what a recording keeps of each board so that it can be replayed
- :mod:`.package` - writing a generated package to disk (``create-msgs``)
- :mod:`.build` - building it with the ROS 2 in this environment (``create-msgs --build``)
"""
