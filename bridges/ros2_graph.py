"""The bridge's watch on the ROS 2 graph: a publisher of the wrong type is named.

DDS matches a publisher and a subscription only when their types agree; a
``geometry_msgs/msg/Twist`` publisher on ``/robot1/cmd_vel`` (where the bridge takes
``TwistStamped``) is never matched and nothing on either side says so: the robot just
does not move. Every ``PERIOD_S`` the bridge looks at the graph; a publisher of another
type on a topic it subscribes gets one warning naming the topic, the publishing node, the
type seen, the type expected and the topic of this robot that takes the type seen (if
any). It is said again only after that publisher has left and one has come back.

rclpy is not imported here: the bridge hands over its node.
"""
from __future__ import annotations

#: how often the graph is looked at (a warning comes within about twice this)
PERIOD_S = 0.5
#: looks at a wrong publisher whose node name is not known yet before warning without it
_LOOKS_FOR_NAME = 3


def advice(topic: str, seen: str, expected: dict[str, str], who: str = "?") -> str:
    """The warning for node ``who`` publishing ``seen`` on ``topic`` (``expected``: topic ->
    the type the bridge takes there)."""
    base = topic.rsplit("/", 1)[0]
    takes = [t for t, ty in expected.items() if ty == seen and t.rsplit("/", 1)[0] == base]
    where = (f"publish {seen} on {takes[0]} instead" if takes
             else f"no topic of the bridge takes {seen}")
    return (f"{topic}: node {who} publishes {seen}, but the bridge takes {expected[topic]} "
            f"there; DDS never delivers it, so the robot ignores it: {where}")


class GraphWatch:
    """Looks for publishers of another type on the topics the bridge subscribes.

    ``expected``: ROS 2 topic -> the type name the bridge subscribes it with
    (``geometry_msgs/msg/TwistStamped``)."""

    def __init__(self, node, expected: dict[str, str], log) -> None:
        self.node = node
        self.expected = dict(expected)
        self.log = log
        self.warned: set[tuple[str, str]] = set()     # (topic, type) said and still there
        self.pending: dict[tuple[str, str], int] = {}  # (topic, type) -> looks seen, unsaid
        self.warnings = 0
        self.timer = node.create_timer(PERIOD_S, self.poll)

    def poll(self) -> None:
        """One look at the graph (an rclpy timer callback: it never raises)."""
        try:
            present: dict[tuple[str, str], set] = {}     # (topic, type seen) -> node names
            for topic, types in self.node.get_topic_names_and_types():
                want = self.expected.get(topic)
                if want is None or all(t == want for t in types):
                    continue
                for info in self.node.get_publishers_info_by_topic(topic):
                    if info.topic_type != want:
                        present.setdefault((topic, info.topic_type), set()).add(
                            _node_name(info))
            for key in sorted(present):
                if key in self.warned:
                    continue
                who = ", ".join(sorted(n for n in present[key] if n)) or None
                # DDS shows the endpoint before its node's name: wait a look or two for it
                looks = self.pending[key] = self.pending.get(key, 0) + 1
                if who is None and looks < _LOOKS_FOR_NAME:
                    continue
                self.warned.add(key)
                self.warnings += 1
                self.log.warning("%s", advice(*key, self.expected, who or "(unnamed)"))
            now = set(present)
            self.warned &= now
            self.pending = {k: n for k, n in self.pending.items() if k in now}
        except Exception as exc:       # the node going away under the timer at exit
            self.log.debug("graph watch: %s", exc)

    def close(self) -> None:
        self.timer.cancel()


def _node_name(info) -> str | None:
    """``/namespace/name`` of an endpoint's node; None while DDS does not know it yet."""
    name, ns = info.node_name, info.node_namespace
    if not name or "_UNKNOWN_" in name or "_UNKNOWN_" in ns:
        return None
    return f"{ns.rstrip('/')}/{name}"
