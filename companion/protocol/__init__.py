"""The wire protocol between companions and the ground station (docs/protocol.md).

Sans-I/O: ``Encoder`` turns messages, reports, commands and status into authenticated UDP
payloads of at most 1200 bytes; ``Decoder`` takes datagrams with ``now`` and hands back
events. Neither touches a socket or a clock.
"""

from companion.protocol.decoder import COUNTER_NAMES, Decoder, DecoderLimits
from companion.protocol.encoder import Encoder, message_metadata
from companion.protocol.errors import (
    BadTag,
    LocalProtocolError,
    MalformedPacket,
    OversizePacket,
    ProtocolError,
    RemoteProtocolError,
    ReplayedPacket,
    StalePacket,
    UnsupportedVersion,
    WrongFleet,
)
from companion.protocol.events import (
    AckReceived,
    Address,
    CommandReceived,
    Event,
    MessageExpired,
    MessageReassembled,
    PacketDropped,
    ReportReceived,
    StatusReceived,
)
from companion.protocol.records import (
    EPOCH_STATUS,
    ClockEcho,
    ClockSample,
    Command,
    Report,
    ReportEntry,
    Status,
    clock_sample,
    entry_from_message,
    report_messages,
)
from companion.protocol.wire import MAX_DATAGRAM_BYTES, PROTOCOL_VERSION, TAG_BYTES, PacketKind

__all__ = [
    "COUNTER_NAMES",
    "EPOCH_STATUS",
    "MAX_DATAGRAM_BYTES",
    "PROTOCOL_VERSION",
    "TAG_BYTES",
    "AckReceived",
    "Address",
    "BadTag",
    "ClockEcho",
    "ClockSample",
    "Command",
    "CommandReceived",
    "Decoder",
    "DecoderLimits",
    "Encoder",
    "Event",
    "LocalProtocolError",
    "MalformedPacket",
    "MessageExpired",
    "MessageReassembled",
    "OversizePacket",
    "PacketDropped",
    "PacketKind",
    "ProtocolError",
    "RemoteProtocolError",
    "ReplayedPacket",
    "Report",
    "ReportEntry",
    "ReportReceived",
    "StalePacket",
    "Status",
    "StatusReceived",
    "UnsupportedVersion",
    "WrongFleet",
    "clock_sample",
    "entry_from_message",
    "message_metadata",
    "report_messages",
]
