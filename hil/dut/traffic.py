"""What the edge messages cost on the wire: frames (CAN) or transactions (Modbus), bytes and bus time.

Each protocol link counts what it sends and receives for the edges it carries
(``LinkTraffic``); the acceptance report sums it per DUT as its top-level ``traffic``
(docs/controller.md, "The bus"). Bus time is computed, not timed: the bits each frame takes on
the wire, with the worst-case bit stuffing (one stuff bit per four bits of the stuffed fields, the
bound ISO 11898-1 allows), so a real bus at that rate needs at most this long.

* Classical CAN, 11-bit identifier, ``n`` data bytes: 47 + 8 n bits (SOF, identifier, RTR, IDE,
  r0, DLC, data, CRC 15, CRC delimiter, ACK slot and delimiter, EOF 7, intermission 3), of which
  the 34 + 8 n bits from SOF to the CRC are stuffed: at most (33 + 8 n) // 4 stuff bits. An
  8-byte frame is 135 bits, 135 us at 1 Mbit/s.
* CAN FD (1 Mbit/s arbitration, 5 Mbit/s data, bit-rate switch): the same payload bytes an edge
  message sends, in frames of up to 64 bytes (a device on CAN FD takes the message in as few
  frames as its bytes need). Arbitration phase (nominal rate): SOF, identifier, RRS, IDE, FDF,
  res, BRS (17 bits, up to 4 stuff bits), CRC delimiter, ACK 2, EOF 7, intermission 3. Data
  phase: ESI, DLC 4, the data, the stuff count 4, CRC 17 (up to 16 bytes) or 21, with up to
  (5 + 8 n) // 4 dynamic and (4 + CRC) // 4 + 1 fixed stuff bits.
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass

#: the nominal (arbitration) and data bit rates the figures are for
CAN_BIT_RATE = 1e6
CAN_FD_DATA_BIT_RATE = 5e6
#: CAN FD data lengths (the DLC codes 9-15 stand for 12, 16, 20, 24, 32, 48 and 64 bytes)
CAN_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


@functools.cache  # a link counts every frame it moves: one figure per length
def can_frame_bits(data_bytes: int) -> int:
    """Bits of a classical CAN base frame with ``data_bytes`` (0-8), worst-case stuffing, with
    the 3-bit intermission."""
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"a classical CAN frame carries 0-8 bytes, got {data_bytes}")
    return 47 + 8 * data_bytes + (33 + 8 * data_bytes) // 4


@functools.cache
def can_fd_frame_s(data_bytes: int) -> float:
    """Seconds a CAN FD base frame with bit-rate switch takes for ``data_bytes`` (padded to the
    next length CAN FD has), worst-case stuffing, 1 Mbit/s arbitration and 5 Mbit/s data."""
    n = next((k for k in CAN_FD_LENGTHS if k >= data_bytes), None)
    if n is None:
        raise ValueError(f"a CAN FD frame carries 0-64 bytes, got {data_bytes}")
    crc = 17 if n <= 16 else 21
    nominal = 17 + 4 + 1 + 2 + 7 + 3
    data = 5 + 8 * n + (5 + 8 * n) // 4 + 4 + crc + (4 + crc) // 4 + 1
    return nominal / CAN_BIT_RATE + data / CAN_FD_DATA_BIT_RATE


def can_fd_message_s(payload_bytes: int) -> float:
    """Seconds ``payload_bytes`` take on CAN FD in frames of up to 64 bytes."""
    full, rest = divmod(payload_bytes, 64)
    return full * can_fd_frame_s(64) + (can_fd_frame_s(rest) if rest or not full else 0.0)


@dataclass
class LinkTraffic:
    """What a link moved for the edges it carried (counts since it was opened)."""

    protocol: str
    edges: int = 0
    frames_to_device: int = 0  #: CAN frames (Modbus: request frames, one per transaction)
    frames_from_device: int = 0
    bytes_to_device: int = 0  #: data bytes (CAN payloads; Modbus register bytes)
    bytes_from_device: int = 0
    transactions: int = 0  #: Modbus requests answered (CAN: 0)
    can_bits: int = 0  #: classical CAN bits, worst-case stuffing
    can_fd_s: float = 0.0  #: CAN FD seconds (1 / 5 Mbit/s), the same bytes in frames of up to 64

    def can_message(self, to_device: list[bytes], from_device: list[bytes]) -> None:
        """One edge on CAN: the frames sent to the device and those it answered with."""
        self.edges += 1
        lengths_to, lengths_from = [len(f) for f in to_device], [len(f) for f in from_device]
        self.frames_to_device += len(lengths_to)
        self.frames_from_device += len(lengths_from)
        self.bytes_to_device += sum(lengths_to)
        self.bytes_from_device += sum(lengths_from)
        self.can_bits += sum(map(can_frame_bits, lengths_to)) + sum(map(can_frame_bits, lengths_from))
        # on CAN FD: the message's bytes in as few frames as they need (a data frame's sequence
        # and index bytes are the classical framing's and not needed in one 64-byte frame, but
        # they are counted), each reply frame as it is
        self.can_fd_s += can_fd_message_s(sum(lengths_to))
        self.can_fd_s += sum(map(can_fd_frame_s, lengths_from))

    def modbus_transaction(self, request_bytes: int, response_bytes: int) -> None:
        """One Modbus request and its response (register bytes each way)."""
        self.transactions += 1
        self.frames_to_device += 1
        self.frames_from_device += 1
        self.bytes_to_device += request_bytes
        self.bytes_from_device += response_bytes

    def as_dict(self) -> dict:
        """The counts, with the bus time of CAN's (seconds add up, so a test's share is a difference)."""
        out = {k: v for k, v in asdict(self).items() if k not in ("can_bits", "can_fd_s")}
        if self.protocol == "modbus":
            out.pop("frames_to_device"), out.pop("frames_from_device")
        else:
            out.pop("transactions")
            out["bus_time_s"] = {"can_1mbit": self.can_bits / CAN_BIT_RATE, "can_fd_5mbit": self.can_fd_s}
        return out


def traffic_delta(after: dict, before: dict) -> dict:
    """The counts one test added (``after`` minus ``before``, field by field)."""
    return {k: (traffic_delta(v, before[k]) if isinstance(v, dict) else v if isinstance(v, str) else v - before[k])
            for k, v in after.items()}
