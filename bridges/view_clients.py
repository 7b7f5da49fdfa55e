"""What Foxglove clients send the live view (bridges/view.py): teleop twists on
``/<robot>/cmd_vel`` (TwistStamped) or ``/<robot>/cmd_vel_unstamped`` (Twist), and the
``/reset_simulation`` service call."""
from __future__ import annotations

import json
import math

import zenoh

from bus import codec

RESET_SERVICE = "/reset_simulation"
#: an empty ROS 2 message in CDR: the encapsulation header and the one placeholder byte
EMPTY_CDR = b"\x00\x01\x00\x00\x00"
TWIST_TYPES = ("geometry_msgs/msg/Twist", "geometry_msgs/Twist",
               "geometry_msgs/msg/TwistStamped", "geometry_msgs/TwistStamped")


class ClientInput:
    """The :class:`bridges.view.View` methods that take what clients send (a part of the
    view, not used alone: it relies on the view's ``session``, ``keys``, ``info``, ``log``,
    ``sim_ns``, ``rejects``, ``topic_name``, ``_client_channels``, ``_seq``)."""

    def reset_service(self):
        """``/reset_simulation`` (``std_srvs/srv/Empty``, as over ROS 2) for Foxglove's
        Service Call panel: a ``sim/reset`` query with no arguments."""
        import foxglove
        from foxglove.websocket import MessageSchema, Service, ServiceSchema

        def schema(part: str):
            return MessageSchema(encoding="cdr", schema=foxglove.Schema(
                name=f"std_srvs/srv/Empty_{part}", encoding="ros2msg", data=b""))

        def handler(request) -> bytes:
            said = None
            for reply in self.session.get(self.keys.reset, timeout=5.0):
                if reply.ok is not None:
                    said = reply.ok.payload.to_bytes().decode("utf-8", "replace")
                else:
                    raise RuntimeError(reply.err.payload.to_bytes().decode("utf-8", "replace"))
            if said is None:
                raise RuntimeError(f"no plant answered {self.keys.reset}")
            self.log.info("%s: %s", RESET_SERVICE, said)
            self.resets += 1
            return b"{}" if request.encoding == "json" else EMPTY_CDR
        return Service(name=RESET_SERVICE, schema=ServiceSchema(
            name="std_srvs/srv/Empty", request=schema("Request"), response=schema("Response")),
            handler=handler)

    def on_client_advertise(self, client, channel) -> None:
        self._client_channels[(client.id, channel.id)] = (
            channel.topic, channel.encoding, channel.schema_name)

    def on_client_unadvertise(self, client, client_channel_id: int) -> None:
        self._client_channels.pop((client.id, client_channel_id), None)

    def on_message_data(self, client, client_channel_id: int, data: bytes) -> None:
        ch = self._client_channels.get((client.id, client_channel_id))
        if ch is None:
            self.rejects.reject("teleop", "data on a channel the client never advertised")
            return
        topic, encoding, schema = ch
        try:
            robot = self.teleop_robot(topic)
            v, w = parse_twist(bytes(data), encoding, schema)
        except ValueError as exc:
            self.rejects.reject("teleop", f"{topic}: {exc}")
            return
        t = self.sim_ns
        key = self.keys.topic(robot, "cmd_vel")
        self.session.put(key, codec.encode(codec.twist_stamped(t, v, w)),
                         encoding=zenoh.Encoding.APPLICATION_CDR,
                         attachment=codec.attachment(next(self._seq), t))
        self.teleop_in += 1
        self.published[key] = self.published.get(key, 0) + 1

    def teleop_robot(self, topic: str) -> str:
        """The robot a client's ``/<robot>/cmd_vel`` topic drives (ValueError if none)."""
        prefix = self.topic_name("")
        rest = topic[len(prefix):] if topic.startswith(prefix) else topic.lstrip("/")
        robot, _, suffix = rest.partition("/")
        if suffix not in ("cmd_vel", "cmd_vel_unstamped"):
            raise ValueError("teleop takes /<robot>/cmd_vel_unstamped (Twist) or "
                             "/<robot>/cmd_vel (TwistStamped)")
        if robot not in self.info.get("robots", {}):
            raise ValueError(f"no robot {robot!r} in the simulation "
                             f"(robots: {', '.join(self.info.get('robots', {})) or 'none'})")
        return robot


def parse_twist(data: bytes, encoding: str, schema_name: str) -> tuple[float, float]:
    """(linear x m/s, angular z rad/s) of a client's Twist or TwistStamped; ValueError if bad."""
    if schema_name and schema_name not in TWIST_TYPES:
        raise ValueError(f"expected geometry_msgs/msg/Twist, got {schema_name!r}")
    stamped = "Stamped" in (schema_name or "")
    if encoding == "json":
        try:
            msg = json.loads(data)
            tw = msg["twist"] if stamped else msg
            v, w = float(tw["linear"]["x"]), float(tw["angular"]["z"])
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"not a JSON Twist: {exc}") from None
    elif encoding == "cdr":
        msgtype = "geometry_msgs/msg/TwistStamped" if stamped else "geometry_msgs/msg/Twist"
        try:
            m = codec.decode(data, msgtype)
        except codec.CodecError as exc:
            raise ValueError(str(exc)) from None
        tw = m.twist if stamped else m
        v, w = float(tw.linear.x), float(tw.angular.z)
    else:
        raise ValueError(f"unsupported encoding {encoding!r} (cdr, json)")
    if not (math.isfinite(v) and math.isfinite(w)):
        raise ValueError(f"non-finite twist ({v}, {w})")
    return v, w
