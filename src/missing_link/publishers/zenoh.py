"""ROS 2 through Zenoh, in the rmw_zenoh wire format, without a ROS 2 install.

What a ROS 2 graph running rmw_zenoh (``rmw_zenohd`` router, ``RMW_IMPLEMENTATION=rmw_zenoh_cpp``)
sees from this publisher:

* one node, liveliness token ``@ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/%/%/<node>``;
* per topic a data key ``<domain>/<topic>/<pkg>::msg::dds_::<Name>_/<type hash>`` and a publisher
  token ``@ros2_lv/<domain>/<zid>/<nid>/<eid>/MP/%/%/<node>/<%topic>/<dds type>/<hash>/<qos>``;
* every sample: the CDR payload (with its 4-byte encapsulation header) and the 33-byte
  attachment ``<q sequence number><q source timestamp ns><B 16><16-byte gid>`` - without it
  rmw_zenoh drops the sample silently; the source timestamp is the sample's host time from
  clock sync (when the board measured, not when the message was sent);
* per actuator a subscription token (``MS``) on ``/<board>/<name>/cmd``: a ROS 2 node
  publishing the transducer's message type there drives the board;
* an actuator's state topic (``/<board>/<name>``) is transient local, keep last 1, as
  rmw_zenoh makes one: an advanced publisher with a cache and publisher detection, so a late
  subscriber with history (rmw_zenoh's transient local, or zenoh's ``AdvancedSubscriber``)
  gets the current state although the board reports it only when it changes.

* the boards' logs on ``/rosout`` (``rcl_interfaces/msg/Log``, ``name`` the board), with
  rcl's rosout QoS: transient local, keep last 1000 (an advanced publisher's cache), lifespan
  10 s (in the token; a cache keeps what it keeps);

The type hash is RIHS01 from the configured distro's typestore; Humble has none
(``TypeHashNotSupported``).  Sessions are peers that connect to ``tcp/127.0.0.1:7447`` (where
rmw_zenohd listens) with multicast scouting off; every endpoint is configurable.
"""

from __future__ import annotations

import logging
import os
import struct
import time
from collections.abc import Callable
from typing import Any

import xxhash

from ..errors import ConfigError
from ..host.board_log import LogLine
from ..ros.diagnostics import DIAG_TOPIC, DIAG_TYPE
from ..ros.logmsgs import ROS2_LOG, ROSOUT, ROSOUT_DEPTH, ROSOUT_QOS, rosout_cdr
from ..topics import Command, Topic, Update
from .rosbase import RosPublisher
from .zenoh_config import check_endpoints, loopback_only, session_config, takes_commands

log = logging.getLogger(__name__)

DEFAULT_CONNECT = ["tcp/127.0.0.1:7447"]
#: like rmw_zenoh's sessions: listen on a free loopback port so peers can dial this one
DEFAULT_LISTEN = ["tcp/127.0.0.1:0"]
#: <reliability>:<durability>:<history>,<depth>:<deadline>:<lifespan>:<liveliness>; empty means
#: rmw_zenoh's default.  Reliable (default), volatile written out (2: the default durability
#: changed from transient-local to volatile in rmw_zenoh PR #521, March 2025), keep last 10.
QOS = ":2:,10:,:,:,,"
#: an actuator's state: transient local (1), keep last 1, so a late subscriber gets the current
#: state (the board reports it only when it changes)
QOS_STATE = ":1:,1:,:,:,,"


def dds_type(type_name: str) -> str:
    """``sensor_msgs/msg/Range`` -> ``sensor_msgs::msg::dds_::Range_``."""
    pkg, kind, name = type_name.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def type_hash(typestore: Any, type_name: str, distro: str) -> str:
    if distro == "humble":
        return "TypeHashNotSupported"
    return str(typestore.hash_rihs01(type_name))


def data_key(domain: int, topic: str, type_name: str, hash_: str) -> str:
    return f"{domain}/{topic.lstrip('/')}/{dds_type(type_name)}/{hash_}"


def mangle(name: str) -> str:
    return name.replace("/", "%")


def attachment(seq: int, source_ns: int, gid: bytes) -> bytes:
    return struct.pack("<qqB", seq, source_ns, 16) + gid


class _Entity:
    __slots__ = ("gid", "key", "pub", "seq", "token")

    def __init__(self, key: str, gid: bytes) -> None:
        self.key = key
        self.gid = gid
        self.seq = 0
        self.pub: Any = None
        self.token: Any = None


class ZenohPublisher(RosPublisher):
    name = "zenoh"

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        import zenoh

        opts = dict(options or {})
        super().__init__(str(opts.get("distro", "jazzy")))
        # like rcl: the domain comes from ROS_DOMAIN_ID unless the config says otherwise
        self.domain = int(opts.get("domain", os.environ.get("ROS_DOMAIN_ID") or 0))
        self.node = str(opts.get("node", "missing_link"))
        mode = str(opts.get("mode", "peer"))
        if mode not in ("peer", "client"):
            raise ConfigError(f"[zenoh] mode must be peer or client, not {mode!r}")
        connect = list(opts.get("connect", DEFAULT_CONNECT))
        listen = list(opts.get("listen", DEFAULT_LISTEN))
        check_endpoints("[zenoh] connect", connect)
        check_endpoints("[zenoh] listen", listen)
        native = opts.get("config")
        cfg = session_config(mode, connect, listen, str(native) if native else None)
        self.takes_commands = takes_commands(
            opts.get("commands"), loopback_only(connect + listen), "[zenoh]"
        )
        self.commands_how = (
            "it connects or listens off loopback: [zenoh] commands = true in --config turns "
            "them on; docs/security.md"
        )
        if mode == "peer":
            cfg.insert_json5("scouting/gossip/enabled", "true")
        # as rmw_zenoh's default config: samples carry HLC timestamps (the actuators' state
        # cache needs them to sequence its samples)
        cfg.insert_json5("timestamping/enabled", "true")
        try:
            self.session: Any = zenoh.open(cfg)
        except zenoh.ZError as e:  # (a certificate that does not load, an endpoint in use)
            raise ConfigError(f"[zenoh] cannot open the session: {e}") from None
        self.zid = str(self.session.info.zid())
        self._entities: dict[str, _Entity] = {}
        self._subs: dict[str, tuple[Any, Any]] = {}
        self._next_id = 1
        self._node_id = 0
        self.published = 0
        self.commands = 0
        self.command_errors = 0
        self._node_token: Any = self.session.liveliness().declare_token(
            f"@ros2_lv/{self.domain}/{self.zid}/{self._node_id}/{self._node_id}/NN/%/%/{self.node}"
        )
        with self._lock:
            self._declare_publisher(DIAG_TOPIC, DIAG_TYPE)
            # the boards' logs, as a ROS 2 node's rosout (transient local, keep last 1000)
            self._declare_publisher(ROSOUT, ROS2_LOG, qos=ROSOUT_QOS, cache=ROSOUT_DEPTH)
        #: what ``run`` prints: where this face is
        self.url = (
            f"{mode} {self.zid}, connect {' '.join(connect) or '-'}, listen {' '.join(listen)}"
        )
        log.info("zenoh: session %s", self.url)
        info = self.session.info
        if connect and not list(info.routers_zid()) and not list(info.peers_zid()):
            log.warning(
                "zenoh: nothing answers at %s yet (start rmw_zenohd, or missing-link router "
                "--listen %s): ROS 2 nodes behind it see nothing until it runs; zenoh keeps "
                "trying, and peers that dial this session get every topic meanwhile",
                " ".join(connect),
                connect[0],
            )

    # ---- graph ------------------------------------------------------------------------------
    @staticmethod
    def _gid(token: str) -> bytes:
        """rmw_zenoh's gid: XXH3-128 of the entity's liveliness token, low 64 bits first."""
        return bytes(xxhash.xxh3_128(token.encode()).intdigest().to_bytes(16, "little"))

    def _token(
        self, kind: str, entity_id: int, topic: str, type_name: str, hash_: str, qos: str = QOS
    ) -> str:
        return (
            f"@ros2_lv/{self.domain}/{self.zid}/{self._node_id}/{entity_id}/{kind}/%/%/{self.node}"
            f"/{mangle(topic)}/{dds_type(type_name)}/{hash_}/{qos}"
        )

    def add_topic(self, topic: Topic) -> None:
        with self._lock:
            if self._closed or topic.name in self._entities:
                return
            topic.register_type(self.typestore)
            self._declare_publisher(topic.name, topic.type_name, state=topic.transducer.is_actuator)

    def _declare_publisher(
        self, name: str, type_name: str, *, state: bool = False, qos: str = "", cache: int = 0
    ) -> _Entity:
        """``state``: an actuator's state (transient local, keep last 1); ``qos`` and
        ``cache``: another transient-local publisher's QoS and depth (``/rosout``)."""
        hash_ = type_hash(self.typestore, type_name, self.distro)
        eid = self._next_id
        self._next_id += 1
        qos = qos or (QOS_STATE if state else QOS)
        cache = cache or (1 if state else 0)
        token = self._token("MP", eid, name, type_name, hash_, qos)
        ent = _Entity(data_key(self.domain, name, type_name, hash_), self._gid(token))
        if cache:
            # as rmw_zenoh makes a transient-local publisher: a cache of the last samples that
            # late subscribers with history (rmw_zenoh's transient local) query when they
            # detect this publisher
            from zenoh.ext import CacheConfig, declare_advanced_publisher

            ent.pub = declare_advanced_publisher(
                self.session, ent.key, cache=CacheConfig(cache), publisher_detection=True
            )
        else:
            ent.pub = self.session.declare_publisher(ent.key)
        ent.token = self.session.liveliness().declare_token(token)
        self._entities[name] = ent
        return ent

    def add_command_topic(self, name: str, topic: Topic, deliver: Callable[[Any], None]) -> None:
        """Subscribe to ``name`` (the actuator's command topic, of ``topic``'s type): of the
        thesis type each message a ``Command`` to the handler; of a standard type
        (``std_msgs/msg/Float64`` per actuator, the robot's ``JointState`` commands), the
        message itself, decoded by rosbags."""
        type_name, standard = topic.type_name, topic.standard
        with self._lock:
            if self._closed or name in self._subs:
                return
            if not standard:
                topic.register_type(self.typestore)
            hash_ = type_hash(self.typestore, type_name, self.distro)
            eid = self._next_id
            self._next_id += 1

            def on_sample(sample: Any) -> None:  # zenoh's thread: decode and hand over
                try:
                    msg: Any = self.typestore.deserialize_cdr(bytes(sample.payload), type_name)
                    # (a Command's times[0]: when to act)
                    deliver(msg if standard else Command.from_message(msg, time.time_ns()))
                    self.commands += 1
                except Exception as e:  # noqa: BLE001 - a bad command must not kill zenoh's thread
                    self.command_errors += 1  # (in status(): /diagnostics shows it)
                    log.warning("zenoh: a command on %s rejected: %s", name, e)

            key = data_key(self.domain, name, type_name, hash_)
            sub = self.session.declare_subscriber(key, on_sample)
            token = self.session.liveliness().declare_token(
                self._token("MS", eid, name, type_name, hash_)
            )
            self._subs[name] = (sub, token)

    # ---- data -------------------------------------------------------------------------------
    def publish(self, update: Update) -> None:
        ent = self._entities.get(update.topic.name)
        if ent is None or self._closed:
            return
        # ours out here: an encoder that raises is a bug, counted by kind by the fan-out
        # (faults), never a drop
        cdr = update.cdr
        ent.seq += 1
        att = attachment(ent.seq, update.stamp_ns, ent.gid)
        try:
            ent.pub.put(cdr, attachment=att)
        except TypeError:  # (what we handed it: a bug, for the fan-out to count)
            raise
        except Exception:  # noqa: BLE001 - a put zenoh refuses is a dropped message, counted
            self.dropped += 1
            return
        self.published += 1

    def log(self, line: LogLine) -> None:
        ent = self._entities.get(ROSOUT)
        if ent is None or self._closed:
            return
        cdr = rosout_cdr(
            self.typestore, line.host_ns, line.level, line.board, line.text, line.source
        )
        ent.seq += 1
        try:
            ent.pub.put(cdr, attachment=attachment(ent.seq, line.host_ns, ent.gid))
        except Exception:  # noqa: BLE001 - a put zenoh refuses is a dropped message, counted
            self.dropped += 1

    def send_diagnostics(self, cdr: bytes, now_ns: int) -> None:
        ent = self._entities[DIAG_TOPIC]
        ent.seq += 1
        ent.pub.put(cdr, attachment=attachment(ent.seq, now_ns, ent.gid))

    def status(self) -> dict[str, Any]:
        """The base's, and what came in: ``commands`` handed on, ``commands_rejected`` (a
        payload that does not decode as the topic's type, or that its handler raised on).  The
        daemon adds ``commands_refused`` (its allow-list and the face's ``commands`` option)."""
        return {
            **super().status(),
            "published": self.published,
            "commands": self.commands,
            "commands_rejected": self.command_errors,
        }

    def shutdown(self) -> None:
        for sub, token in self._subs.values():
            token.undeclare()
            sub.undeclare()
        for ent in self._entities.values():
            ent.token.undeclare()
            ent.pub.undeclare()
        self._node_token.undeclare()
        self.session.close()
