"""One board in the daemon, from its link up (a room of the daemon: it imports the daemon's
configuration and claims below it, never the intake, control or service above it).

- :mod:`.session` - :class:`~.session.BoardSession`: connect, validate, serve, notice loss,
reconnect
- :mod:`.link` - how a session gets its board (by URL, or handed over into its ``Mailbox``)
- :mod:`.context` - what a session is handed instead of the daemon: values, its claims, its faces
- :mod:`.status` - a session's state (an enum) and status (a dataclass, its JSON keys)
- :mod:`.report` - what a session reports: its level and status, from its parts
- :mod:`.board_topics` - a board's topics, message types and command topics at each handshake
- :mod:`.sample_path` - a sample SIF in, host-timed updates out
- :mod:`.board_log` - the board's log SIFs in, log lines out to every face
- :mod:`.clock` - the board's clock sync in its session, its skew kept across links
- :mod:`.prober` - the board's clock probes on its reading thread
- :mod:`.alignment` - the host-time grid of aligned transducers, the board's account of it
- :mod:`.actuators` - commands for the board's actuators, latest wins; timed ones at their time
- :mod:`.run_config` - the board's run-time configuration: the file's keys at connect and reset
- :mod:`.liveness` - whether the link is alive, from what is heard (pure, time passed in)
- :mod:`.inflight` - the supervisor's calls to the board: never waited for, one of a kind out;
  a board's count read so in the background
- :mod:`.reads` - what the supervisor asks of a served board: keepalive, echo, its counts
- :mod:`.failsafe` - the host's side of the board's failsafe: keepalive, its trip count
- :mod:`.farewell` - the goodbye a stopping session sends
- :mod:`.board_memory` - the board's own memory figures (``a2jMemory``), read in the background
- :mod:`.background` - what the supervisor asks for but must not wait for (re-applying keys)
- :mod:`.hold` - the board's port let go for a while (an AVR update)
"""
