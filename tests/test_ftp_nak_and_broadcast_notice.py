"""MAVLink FTP requests addressed to us get a NAK (UnknownCommand) a ground station decodes, so MAVProxy stops
waiting; a mag-cal command broadcast to component 0 that we do not act on is said once (log and STATUSTEXT)."""

from __future__ import annotations

import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ahrsd.daemon.broadcast_notice import BroadcastNotice
from ahrsd.daemon.ftp_nak import ftp_nak

OURS = (1, 200)


def request(target_system, target_component, seq=41, session=3, opcode=4, offset=0, data=b"@PARAM/param.pck"):
    payload = struct.pack("<HBBBBBBI", seq, session, opcode, len(data), 0, 0, 0, offset) + data
    msg = mavlink.MAVLink_file_transfer_protocol_message(0, target_system, target_component,
                                                         list(payload.ljust(251, b"\0")))
    wire = msg.pack(mavlink.MAVLink(None, srcSystem=255, srcComponent=190))
    return mavlink.MAVLink(None).parse_char(wire)     # as it arrives: source 255/190


def decode(reply):
    wire = reply.pack(mavlink.MAVLink(None, srcSystem=OURS[0], srcComponent=OURS[1]))
    back = mavlink.MAVLink(None).parse_char(wire)
    seq, session, opcode, size, req_opcode, burst, _pad, offset = struct.unpack_from("<HBBBBBBI", bytes(back.payload))
    return back, (seq, session, opcode, size, req_opcode, burst, offset), bytes(back.payload)[12:12 + size]


def test_a_request_to_us_gets_an_unknown_command_nak_to_the_sender():
    back, (seq, session, opcode, size, req_opcode, _burst, offset), data = decode(ftp_nak(request(*OURS, offset=512),
                                                                                     *OURS))
    assert (back.target_system, back.target_component) == (255, 190)
    assert (seq, session, opcode, size, req_opcode, offset) == (42, 3, 129, 1, 4, 512)   # seq + 1, NAK, OpenFileRO
    assert data == bytes([7])                                                            # ERR_UnknownCommand


def test_requests_for_others_broadcasts_and_replies_get_nothing():
    assert ftp_nak(request(1, 1), *OURS) is None          # the autopilot's FTP server
    assert ftp_nak(request(2, 200), *OURS) is None        # another system
    assert ftp_nak(request(1, 0), *OURS) is None          # broadcast: another component may serve it
    assert ftp_nak(request(*OURS, opcode=129), *OURS) is None   # a NAK is not a request
    assert ftp_nak(request(*OURS, seq=0xFFFF), *OURS) is not None


def test_an_ignored_broadcast_is_said_once_per_sender_and_command(caplog):
    texts = []
    notice = BroadcastNotice(lambda severity, text: texts.append((severity, text)), 200)
    for _ in range(3):
        notice.note(42424, (255, 190))
    notice.note(42425, (255, 190))
    notice.note(42424, (254, 190))
    assert [t for _, t in texts] == ["ahrsd: DO_START_MAG_CAL ignored: send to comp 200",
                                     "ahrsd: DO_ACCEPT_MAG_CAL ignored: send to comp 200",
                                     "ahrsd: DO_START_MAG_CAL ignored: send to comp 200"]
    assert all(len(t) <= 50 for _, t in texts)             # STATUSTEXT.text holds 50 characters
    assert caplog.text.count("ignored DO_START_MAG_CAL broadcast to component 0 by 255/190") == 1


def test_the_command_router_tells_the_notice_about_a_handled_command_sent_to_component_0():
    from ahrsd.daemon.commands import CommandRouter

    noted = []

    class Notice:
        def note(self, command_id, source):
            noted.append((command_id, source))

    acks = []
    router = CommandRouter(send_ack=lambda ep, m: acks.append(m), broadcast_notice=Notice())
    router.register(42424, lambda ctx: None, accept_broadcast=False)
    msg = mavlink.MAVLink_command_long_message(1, 0, 42424, 0, 0, 0, 0, 0, 0, 0, 0)
    msg = mavlink.MAVLink(None).parse_char(msg.pack(mavlink.MAVLink(None, srcSystem=255, srcComponent=190)))
    router.handle(msg, endpoint=None, broadcast=True)
    unknown = mavlink.MAVLink_command_long_message(1, 0, 31000, 0, 0, 0, 0, 0, 0, 0, 0)
    unknown = mavlink.MAVLink(None).parse_char(unknown.pack(mavlink.MAVLink(None, srcSystem=255, srcComponent=190)))
    router.handle(unknown, endpoint=None, broadcast=True)   # not ours at all: the autopilot answers it, silence
    assert noted == [(42424, (255, 190))] and acks == []
