"""MAVLink FTP (FILE_TRANSFER_PROTOCOL) is not served: every request addressed to us gets a NAK, so a ground
station that tries it first (MAVProxy fetches parameters over FTP, then falls back to PARAM_REQUEST_LIST) learns
at once instead of waiting for its time-out ("FTP: request timed out").

Payload layout and codes: mavlink.io/en/services/ftp.html — seq (uint16), session, opcode, size, req_opcode,
burst_complete, padding (uint8 each), offset (uint32), then data; a NAK is opcode 129 with the error code in
data[0] and req_opcode the request's opcode; the reply's seq is the request's + 1.
"""

from __future__ import annotations

import struct

from ahrsd.daemon.mavlink_io import is_for_us, mavlink

HEADER = struct.Struct("<HBBBBBBI")    # seq, session, opcode, size, req_opcode, burst_complete, padding, offset
OP_NAK = 129
OP_TERMINATE_SESSION = 1
OP_RESET_SESSIONS = 2
ERR_UNKNOWN_COMMAND = 7    # "Unknown command / opcode": no FTP server here
PAYLOAD_BYTES = 251


def ftp_nak(msg, system_id: int, component_id: int):
    """The FILE_TRANSFER_PROTOCOL NAK answering `msg`, or None when it is not a request addressed to this
    component (broadcasts included: another component on the system may serve FTP)."""
    ours, broadcast = is_for_us(msg, system_id, component_id)
    if not ours or broadcast or msg.target_system != system_id:
        return None
    payload = bytes(msg.payload)
    if len(payload) < HEADER.size:
        return None
    seq, session, opcode, _size, _req, _burst, _pad, offset = HEADER.unpack_from(payload)
    if opcode >= 128:      # an ACK/NAK from someone else, not a request
        return None
    reply = HEADER.pack((seq + 1) & 0xFFFF, session, OP_NAK, 1, opcode, 0, 0, offset) + bytes([ERR_UNKNOWN_COMMAND])
    return mavlink.MAVLink_file_transfer_protocol_message(0, msg.get_srcSystem(), msg.get_srcComponent(),
                                                          list(reply.ljust(PAYLOAD_BYTES, b"\0")))
