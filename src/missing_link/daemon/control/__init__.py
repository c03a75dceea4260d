"""Who may steer the robot and how (a room of the daemon, above the session).

- :mod:`.endpoint` - the local control endpoint (``missing-link config``, ``info``, ``call``)
- :mod:`.ops` - what that endpoint serves, from the daemon's verbs
- :mod:`.updates` - firmware updates through the endpoint, the session's port held meanwhile
- :mod:`.allowlist` - who may move the robot: the allow-list, on every path to an actuator
- :mod:`.config_guard` - a face's configuration change that would move an actuator, guarded

Light on purpose: a one-off ``missing-link call`` imports :mod:`.endpoint` and nothing else of
the daemon.
"""
