"""mousedom as a node of the ROS 2 graph: what ``ros2 node list`` and rclpy's
``get_node_names()`` read.

DDS knows participants, readers and writers; ROS 2 knows nodes.  Every rmw joins the two
through the topic ``ros_discovery_info`` (no ``rt/`` prefix: it is not a ROS topic), on
which each participant publishes one ``rmw_dds_common/msg/ParticipantEntitiesInfo``: its
own GID and, per node it hosts, the node's namespace and name and the GIDs of the node's
readers and writers.  A GID is the entity's DDS GUID, 16 bytes (``char[16]``, Iron and
later; Humble had 24).  The QoS is rmw's: reliable, transient local, keep last 1, so a
ROS 2 tool started later still gets it.  The message is sent again whenever the node's
endpoints change.
"""

# No ``from __future__ import annotations`` here: cyclonedds reads the message classes'
# annotations as objects, and the classes are local to graph_types().
import functools
from typing import Any

TOPIC = "ros_discovery_info"
GID_SIZE = 16
MAX_NAME = 256  # string<=256 in NodeEntitiesInfo.msg


@functools.lru_cache(maxsize=1)
def graph_types() -> tuple[type, type, type]:
    """(Gid, NodeEntitiesInfo, ParticipantEntitiesInfo) as cyclonedds classes named as
    rmw_dds_common's on the wire."""
    from dataclasses import dataclass

    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl import types as t

    # (mypy does not read cyclonedds: IdlStruct is Any to it, and it still checks the
    # class keyword ``typename`` against object.__init_subclass__: hence the ignores)

    @dataclass
    class Gid_(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):  # type: ignore[call-arg]
        data: t.array[t.uint8, GID_SIZE]

    @dataclass
    class NodeEntitiesInfo_(  # type: ignore[call-arg]
        IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"
    ):
        node_namespace: t.bounded_str[MAX_NAME]
        node_name: t.bounded_str[MAX_NAME]
        reader_gid_seq: t.sequence[Gid_]
        writer_gid_seq: t.sequence[Gid_]

    @dataclass
    class ParticipantEntitiesInfo_(  # type: ignore[call-arg]
        IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"
    ):
        gid: Gid_
        node_entities_info_seq: t.sequence[NodeEntitiesInfo_]

    return Gid_, NodeEntitiesInfo_, ParticipantEntitiesInfo_


def gid(entity: Any) -> Any:
    """The GID of a cyclonedds entity (participant, reader, writer): its GUID's bytes."""
    Gid_, _, _ = graph_types()
    return Gid_(list(entity.guid.bytes[:GID_SIZE]))


def check_name(name: str, namespace: str) -> None:
    """ValueError unless ``name`` and ``namespace`` are what ROS 2 accepts (config's rules,
    which a loaded config has passed already: this guards other callers)."""
    from mousedom.config import ROS_NAMESPACE, ROS_NODE_NAME

    if not ROS_NODE_NAME.fullmatch(name):
        raise ValueError(f"node name {name!r}: letters, digits and _, not starting with a digit")
    if namespace != "/" and not ROS_NAMESPACE.fullmatch(namespace) or len(namespace) > MAX_NAME:
        raise ValueError(f"node namespace {namespace!r}: '/' or '/a/b' of such names")


class NodeAnnouncer:
    """Publishes the participant's one node and its endpoints on ros_discovery_info."""

    def __init__(self, participant: Any, name: str, namespace: str) -> None:
        from cyclonedds.pub import DataWriter
        from cyclonedds.qos import Policy, Qos
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        check_name(name, namespace)
        _, _, info = graph_types()
        qos = Qos(
            Policy.Reliability.Reliable(duration(milliseconds=100)),
            Policy.Durability.TransientLocal,
            Policy.History.KeepLast(1),
        )
        self.participant = participant
        self.name, self.namespace = name, namespace
        self.topic = Topic(participant, TOPIC, info, qos=qos)
        self.writer = DataWriter(participant, self.topic, qos)
        self.readers: list[Any] = []
        self.writers: list[Any] = []

    def announce(self, readers: list[Any], writers: list[Any]) -> None:
        """The node's endpoints now: sent at once, and kept for late joiners."""
        _, node_info, info = graph_types()
        self.readers, self.writers = list(readers), list(writers)
        node = node_info(
            node_namespace=self.namespace,
            node_name=self.name,
            reader_gid_seq=[gid(r) for r in self.readers],
            writer_gid_seq=[gid(w) for w in self.writers],
        )
        self.writer.write(info(gid=gid(self.participant), node_entities_info_seq=[node]))

    def withdraw(self) -> None:
        """The node is going: the participant's node list emptied, as rmw does when a node
        is destroyed.  ROS 2's graph then drops the node at once: Fast DDS does not act on
        Cyclone's disposal of a deleted participant, which it keeps until its lease ends
        (10 s: a restarted daemon was two nodes of one name meanwhile)."""
        _, _, info = graph_types()
        self.readers, self.writers = [], []
        self.writer.write(info(gid=gid(self.participant), node_entities_info_seq=[]))
