"""Modbus encodings the device and the link share: the edge mailbox's words, the functions each
table takes, and the exception a malformed request must get (the Modbus application protocol)."""

from __future__ import annotations

import struct

from bldc.contract import MAX_ADC_SAMPLES

from .profile import REPLY_WORDS, Profile

#: the edge mailbox, at the profile's request address (edge message version 2: docs/controller.md):
#: the message's bytes two per register, the first one high; its header (4 registers) triggers the
#: controller, the rest (accumulators, ADC window) follows it in the same write. Where the mailbox
#: has less room than the message (``profile.mailbox_words``), the rest's first part is written
#: before, at the register after the header, in writes of their own that the device appends.
#: The reply: a frame count, then up to four command messages.
REPLY_FRAMES = 4
assert REPLY_WORDS == 1 + 4 * REPLY_FRAMES
#: the most registers a message's rest may take (accumulators and a full window)
MESSAGE_REST_WORDS = 7 + 3 * MAX_ADC_SAMPLES


def registers_of(b: bytes) -> list[int]:
    """A byte string (even length) as registers, two bytes each, the first one high."""
    return list(struct.unpack(f">{len(b) // 2}H", b))


def bytes_of(r) -> bytes:
    return struct.pack(f">{len(r)}H", *r)


#: the function codes that read (and write) each table
TABLE_FUNCTIONS = {"holding": (3, 6, 16, 23), "input": (4,), "coil": (1, 5, 15), "discrete": (2,)}
FUNCTION_TABLE = {fc: table for table, fcs in TABLE_FUNCTIONS.items() for fc in fcs}


def supported_functions(profile: Profile) -> tuple[int, ...]:
    """The functions a device with this map implements: those of its tables (the mailbox is holding)."""
    tables = {o.table for o in profile.objects.values()}
    if profile.edge_hook.kind == "mailbox":
        tables.add("holding")
    return tuple(sorted(fc for t in tables for fc in TABLE_FUNCTIONS[t]))


def request_exception(pdu: bytes, supported=(3, 6, 16, 23)) -> bytes | None:
    """The exception PDU the Modbus application protocol requires for a malformed request, or None.

    01 illegal function: a function code this device does not implement (``supported``: those of
    the tables its map has); 03 illegal data value: a quantity out of range or a byte count that
    does not match it. Addresses (02) and values of well-formed requests are judged by the map.
    """
    if not pdu:
        return None
    fc = pdu[0]
    if fc & 0x80 or fc not in supported:
        return bytes([(fc | 0x80) & 0xFF, 0x01])
    bad = bytes([fc | 0x80, 0x03])
    try:
        if fc in (3, 4):
            _, qty = struct.unpack_from(">HH", pdu, 1)
            return bad if not 1 <= qty <= 125 or len(pdu) != 5 else None
        if fc in (1, 2):
            _, qty = struct.unpack_from(">HH", pdu, 1)
            return bad if not 1 <= qty <= 2000 or len(pdu) != 5 else None
        if fc == 5:
            _, value = struct.unpack_from(">HH", pdu, 1)
            return bad if len(pdu) != 5 or value not in (0, 0xFF00) else None
        if fc == 6:
            return bad if len(pdu) != 5 else None
        if fc == 15:
            _, qty, nbytes = struct.unpack_from(">HHB", pdu, 1)
            return bad if not 1 <= qty <= 1968 or nbytes != (qty + 7) // 8 or len(pdu) != 6 + nbytes else None
        if fc == 16:
            _, qty, nbytes = struct.unpack_from(">HHB", pdu, 1)
            return bad if not 1 <= qty <= 123 or nbytes != 2 * qty or len(pdu) != 6 + nbytes else None
        if fc == 23:
            _, rqty, _, wqty, nbytes = struct.unpack_from(">HHHHB", pdu, 1)
            ok = 1 <= rqty <= 125 and 1 <= wqty <= 121 and nbytes == 2 * wqty and len(pdu) == 10 + nbytes
            return None if ok else bad
    except struct.error:
        return bad
    return None
