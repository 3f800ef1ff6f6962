"""The Modbus client link (TCP or RTU): the framework's view of a Modbus controller through its
device profile (hil.dut.profile; the roles' values through hil.dut.role_link). Edges are exchanged
in one transaction: function 23 writes the edge message to the profile's mailbox and reads the
reply at its reply address (hil.dut.modbus_codec).
"""

from __future__ import annotations

from bldc.contract import CommandMessage, EdgeMessage, edge_epoch

from .link import LinkError, LinkTimeout
from .modbus_codec import REPLY_FRAMES, bytes_of, registers_of
from .profile import EDGE_HEADER_WORDS, REPLY_WORDS, Profile, bound_profile, mailbox_words
from .role_link import RoleLink
from .traffic import LinkTraffic


class ModbusLink(RoleLink):
    """The framework's view of a Modbus controller (TCP or RTU), through its profile."""

    name = "modbus"

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 502,
        unit: int = 1,
        timeout_s: float = 1.0,
        serial_port: str | None = None,
        baudrate: int = 115200,
        profile: Profile | str | None = None,
        pole_pairs: int = 2,
    ):
        """Modbus TCP at host:port, or Modbus RTU on ``serial_port`` when given; the map is
        ``profile``'s (default: the virtual controller's own)."""
        from pymodbus.client import ModbusSerialClient, ModbusTcpClient
        from pymodbus.framer import FramerType

        self.profile = bound_profile("modbus", profile, pole_pairs)
        self._mailbox_words = mailbox_words(self.profile) if self.profile.edge_hook.kind == "mailbox" else 0
        self.unit, self.timeout_s = unit, timeout_s
        self.host, self.port, self.serial_port = host, port, serial_port
        self.applied_calibration = None
        if serial_port is not None:
            self.where = f"Modbus RTU unit {unit} on {serial_port}"
            self.client = ModbusSerialClient(
                serial_port, framer=FramerType.RTU, baudrate=baudrate, timeout=timeout_s, retries=0
            )
        else:
            self.where = f"Modbus unit {unit} at {host}:{port}"
            self.client = ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0)
        if not self.client.connect():
            raise LinkTimeout(f"{self.where}: cannot connect within {timeout_s} s")
        self._seq = 0
        self.traffic = LinkTraffic("modbus")  #: what the edges moved (hil.dut.traffic)

    def _call(self, what: str, fn):
        from pymodbus.exceptions import ModbusException

        try:
            r = fn()
        except ModbusException as exc:
            raise LinkTimeout(f"{self.where}: no answer to {what} within {self.timeout_s} s ({exc})") from None
        except Exception as exc:  # the transport itself failed (a reset connection, a closed port)
            raise LinkError(f"{self.where}: {what} failed: {type(exc).__name__}: {exc}") from None
        if r.isError():
            code = getattr(r, "exception_code", None)
            raise LinkError(
                f"{self.where}: {what} refused with exception code {code:02d}"
                if code is not None
                else f"{self.where}: {what} failed: {r}"
            )
        return r

    def read(self, address: int, count: int, table: str = "holding") -> list[int]:
        """``count`` registers (or bits) of ``table`` from ``address``."""
        fn = {"holding": self.client.read_holding_registers, "input": self.client.read_input_registers,
              "coil": self.client.read_coils, "discrete": self.client.read_discrete_inputs}[table]
        r = self._call(f"read {count} {table} at {address}", lambda: fn(address, count=count, device_id=self.unit))
        return r.registers if table in ("holding", "input") else [int(b) for b in r.bits[:count]]

    def write(self, address: int, registers: list[int], table: str = "holding") -> None:
        if table == "coil":
            self._call(
                f"write {len(registers)} coils at {address}",
                lambda: self.client.write_coils(address, [bool(v) for v in registers], device_id=self.unit),
            )
            return
        self._call(
            f"write {len(registers)} registers at {address}",
            lambda: self.client.write_registers(address, registers, device_id=self.unit),
        )

    # --- RoleLink: raw values of an object ---------------------------------------------------------
    def read_raw(self, obj) -> list:
        regs = self.read(obj.address, obj.count * obj.registers, obj.table)
        n = obj.registers
        return [obj.from_registers(regs[k * n : (k + 1) * n]) for k in range(obj.count)]

    def write_raw(self, obj, raws: list) -> None:
        self.write(obj.address, sum((obj.to_registers(r) for r in raws), []), obj.table)

    def reset(self) -> None:
        super().reset()
        self._seq = 0

    def edge(self, edge: dict) -> list:
        hook = self.profile.edge_hook
        if hook.kind != "mailbox":
            raise LinkError(f"{self.where}: the profile {self.profile.path} gives edges no mailbox ({hook.kind})")
        epoch = edge_epoch(edge["t_capture_s"])
        seq = self._seq
        self._seq = (self._seq + 1) & 0x7F
        values = registers_of(EdgeMessage.from_edge(edge, seq).pack())
        header, rest = values[:EDGE_HEADER_WORDS], values[EDGE_HEADER_WORDS:]
        room = self._mailbox_words - EDGE_HEADER_WORDS  # of the rest, in the header's write
        ahead = rest[: max(len(rest) - room, 0)]
        for k in range(0, len(ahead), room):  # what does not fit, ahead of the header, in order
            part = ahead[k : k + room]
            # PDUs: function 16 (code, address, quantity, byte count, registers), answered with 5 bytes
            self.traffic.modbus_transaction(6 + 2 * len(part), 5)
            self._call(
                f"ADC data of edge #{seq}",
                lambda part=part: self.client.write_registers(
                    hook.request_address + EDGE_HEADER_WORDS, part, device_id=self.unit
                ),
            )
        values = header + rest[len(ahead) :]
        r = self._call(
            f"edge #{seq} (t = {edge['t_capture_s']:.7f} s)",
            lambda: self.client.readwrite_registers(
                read_address=hook.reply_address,
                read_count=REPLY_WORDS,
                write_address=hook.request_address,
                values=values,
                device_id=self.unit,
            ),
        )
        # function 23: code, read address and quantity, write address and quantity, byte count and
        # the registers; answered with code, byte count and the registers read
        self.traffic.modbus_transaction(10 + 2 * len(values), 2 + 2 * REPLY_WORDS)
        self.traffic.edges += 1
        regs = r.registers
        if len(regs) != REPLY_WORDS or regs[0] > REPLY_FRAMES:
            raise LinkError(
                f"{self.where}: reply to edge #{seq} is malformed ({len(regs)} registers, {regs[:1]} frames)"
            )
        commands = []
        for k in range(min(regs[0], REPLY_FRAMES)):
            f = CommandMessage.unpack(bytes_of(regs[1 + 4 * k : 5 + 4 * k]))
            if f.seq != seq & 0x7F:
                raise LinkError(f"{self.where}: reply to edge #{seq} carries sequence {f.seq} (a stale answer)")
            if not f.keeps_everything:
                commands.append(f.to_command(epoch))
        return commands

    def close(self) -> None:
        self.client.close()
