"""The firmware-in-the-loop link: a ControllerLink whose controller is C firmware in a process
of its own (``hil.sil.worker``), reached through its object dictionary and its peripherals.

Roles go through the firmware's object dictionary as the device profile (CANopen form) maps them,
exactly as on a CAN bench (``RoleLink``). Edges do not go through any message: a
``hil.bench.lockstep.LockstepBench`` of this link runs its plant (``simulation()``) beside the firmware,
whose interrupts see the Hall pins, the ADC and
the timer, and whose gates drive the plant's inverter. Commutation is judged from the gates.

A firmware that crashes, hangs in an interrupt beyond ``hang_s`` of wall time, or breaks the
interface raises ``FirmwareFault`` naming the event, the simulated instant and the counter; the
next request starts a freshly loaded firmware.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from ..dut.link import LinkError
from ..dut.role_link import RoleLink
from .firmware import FirmwareInfo, SilInterfaceError
from .peripherals import EVENTS

#: how long a new firmware process may take to start (imports numpy and the plant) before it is
#: called dead
START_TIMEOUT_S = 120.0


class FirmwareFault(LinkError):
    """The firmware crashed, hung or broke the interface; the message names the event, the
    simulated instant and the counter."""


#: how a processor fault of the emulated core (pil:) is told in a FirmwareFault's message, before the
#: finding's own text (``hil.pil.core.ProcessorFinding``: "UsageFault in ctl_hall_isr (control.c:837)
#: at pc ...")
PROCESSOR_FAULT = "processor fault: "
_PROCESSOR_FAULT = re.compile(re.escape(PROCESSOR_FAULT) + r"(\w+) in (\S+)(?: \(([^)]*)\))?")


def processor_fault(message: str) -> str | None:
    """A failure message's processor fault as "KIND in FUNCTION (FILE:LINE)" (a test's ``message``
    in the HIL report), or None when it names none."""
    m = _PROCESSOR_FAULT.search(message or "")
    if m is None:
        return None
    return f"{m[1]} in {m[2]}" + (f" ({m[3]})" if m[3] else "")


class SilProcess:
    """One firmware instance in its own process."""

    def __init__(self, library: Path, label: str, hang_s: float, kind: str = "sil", target: Path | None = None):
        self.library, self.label, self.hang_s = library, label, hang_s
        #: the firmware kind (sil: a shared library; pil: an ELF on an emulated core of ``target``)
        self.kind, self.target = kind, target
        self.proc = None
        self.info: FirmwareInfo | None = None
        self.starts = 0

    def _start(self) -> None:
        """A new process (``python -m hil.sil.worker``) holding a freshly loaded firmware. A plain
        subprocess, not multiprocessing's spawn, which would import the caller's main module again."""
        from .worker import _Duplex

        fd, record_file = tempfile.mkstemp(prefix="hil-sil-", suffix=".record")
        os.write(fd, bytes(40))
        os.close(fd)
        self._record_file = record_file
        self._view = np.memmap(record_file, dtype=np.float64, mode="r+", shape=(5,))
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hil.sil.worker", str(to_child_r), str(from_child_w), record_file,
             str(self.library), self.kind, str(self.target or "")],
            pass_fds=(to_child_r, from_child_w), cwd=os.getcwd(), env={**os.environ, "PYTHONPATH": _python_path()},
        )
        os.close(to_child_r)
        os.close(from_child_w)
        self.conn = _Duplex(Connection(from_child_r, writable=False), Connection(to_child_w, readable=False))
        self.starts += 1
        status, value = self._wait("start", START_TIMEOUT_S)
        if status == "interface":
            self._stop()
            raise SilInterfaceError(value)
        if status == "error":
            self._stop()
            raise value
        self.info = value

    def call(self, op: str, *args):
        if self.proc is None:
            self._start()
        try:
            self.conn.send((op, args))
        except (BrokenPipeError, OSError):
            pass  # the process died: _wait says how
        status, value = self._wait(op, None)
        if status == "ok":
            return value
        if status == "fault":
            self._stop()
            raise FirmwareFault(f"{self.label}: {value}")
        if status == "processor fault":
            # the part's own failure on valid input, as a device's general-error answer is
            # (hil.verdicts.judging): it fails the requirement of the test that met it
            self._stop()
            fault = FirmwareFault(f"{self.label}: {PROCESSOR_FAULT}{value}")
            fault.device_failure = True
            raise fault
        raise value

    def _wait(self, op: str, limit_s: float | None):
        """The answer to ``op``; a dead process or a call stuck in the firmware is a FirmwareFault."""
        started = time.monotonic()
        seen_seq, seen_at = None, None
        while True:
            if self.conn.poll(0.05):
                try:
                    return self.conn.recv()
                except (EOFError, OSError):
                    pass  # died while answering: below
            if self.proc.poll() is not None:
                code = self.proc.returncode
                where = self._record_text()
                self._stop()
                if code is not None and code < 0:
                    name = signal.Signals(-code).name
                    raise FirmwareFault(f"{self.label}: the firmware crashed with {name} in {where}")
                raise FirmwareFault(f"{self.label}: the firmware's process ended (exit {code}) in {where}")
            seq, in_call = self._view[0], self._view[4]
            now = time.monotonic()
            if in_call:
                if seq != seen_seq:
                    seen_seq, seen_at, cpu_at = seq, now, self._cpu_s()
                elif now - seen_at > self.hang_s and self._stuck(now - seen_at, self._cpu_s() - cpu_at):
                    where = self._record_text()
                    self._stop()
                    raise FirmwareFault(
                        f"{self.label}: the firmware hung: {where} did not return within {self.hang_s:g} s "
                        "of wall time (hang=SECONDS sets the limit)"
                    )
            else:
                seen_seq = None
            if limit_s is not None and now - started > limit_s:
                self._stop()
                raise LinkError(f"{self.label}: the firmware's process did not {op} within {limit_s:g} s")

    def _cpu_s(self) -> float:
        """CPU time the firmware's process has used (Linux /proc; NaN where it cannot be read)."""
        try:
            fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            return float("nan")

    def _stuck(self, wall_s: float, cpu_s: float) -> bool:
        """A call that has not returned for ``wall_s`` > hang_s hangs when the process spent at least
        half of hang_s on the CPU meanwhile (a loop), or when ten times hang_s have passed (a wait
        that burns nothing). A process the host did not schedule (a loaded machine) is not hung."""
        return cpu_s != cpu_s or cpu_s >= 0.5 * self.hang_s or wall_s > 10.0 * self.hang_s

    def _record_text(self) -> str:
        seq, event, t_s, count, in_call = self._view.tolist()
        name = EVENTS[int(event)] if 0 < int(event) < len(EVENTS) else "the framework's own code"
        if not in_call:
            return f"the framework's process after {name} at t = {t_s:.9f} s"
        return f"{name} at t = {t_s:.9f} s (counter {int(count)})" if count >= 0 else f"{name} (before any run)"

    def _stop(self) -> None:
        if self.proc is not None:
            try:
                if self.proc.poll() is None:
                    self.proc.kill()
                self.proc.wait(5.0)
            finally:
                self.conn.close()
                self.proc = None
                try:
                    os.unlink(self._record_file)
                except OSError:
                    pass

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            try:
                self.conn.send(("close", ()))
                if self.conn.poll(2.0):
                    self.conn.recv()
            except (OSError, EOFError):
                pass
        self._stop()


def _python_path() -> str:
    """The caller's import path for the worker, so it imports this very framework (a checkout
    that is not installed, a test's ``sys.path``)."""
    root = str(Path(__file__).resolve().parent.parent.parent)
    parts = [root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    return os.pathsep.join(dict.fromkeys(parts))


class SilLink(RoleLink):
    """A ControllerLink to firmware in the loop (module docstring)."""

    name = "sil"  #: the firmware kind: sil, or pil (set per link)
    #: its interrupts see the plant's Hall pins (``hil.dut.link.edge_hook_kind``); a firmware kind's
    #: link (``hil.dut.kinds``: ``firmware``)
    edges_through_pins = True

    def __init__(self, library: Path, profile, *, hang_s: float = 1.0, wrap_at_s: float = 0.25,
                 label: str | None = None, kind: str = "sil", target: Path | None = None):
        self.library = Path(library)
        self.name = kind
        self.process = SilProcess(self.library, label or f"{kind.upper()} firmware {self.library}", hang_s, kind,
                                  target)
        self.info: FirmwareInfo = self.process.call("info")
        self.where = f"{kind.upper()} firmware {self.info.name!r} ({self.library})"
        self.process.label = self.where
        self.profile = profile
        self.wrap_at_s = wrap_at_s
        self.applied_calibration = None
        self._emcy: list[tuple[float, int]] = []  #: EMCY codes since the last power cycle

    # --- the object dictionary ----------------------------------------------------------------
    def od_read(self, index: int, sub: int, size: int) -> bytes | int:
        """One object's bytes, or the firmware's (negative) SDO abort code: the raw answer, for
        conformance tests of the dictionary itself."""
        return self.process.call("od_read", index, sub, size)

    def od_write(self, index: int, sub: int, data: bytes) -> int:
        """0, or the firmware's (negative) SDO abort code."""
        return self.process.call("od_write", index, sub, bytes(data))

    def _abort(self, what: str, code: int) -> LinkError:
        return LinkError(f"{self.where}: {what} refused with SDO abort 0x{(-code) & 0xFFFFFFFF:08X}")

    def read_raw(self, obj) -> list:
        out = []
        for k in range(obj.count):
            sub = obj.subindex_of(k)
            data = self.process.call("od_read", obj.index, sub, obj.size)
            if isinstance(data, int):
                raise self._abort(f"read {obj.label(k)} ({obj.role})", data)
            out.append(obj.unpack_le(data))
        return out

    def write_raw(self, obj, raws: list) -> None:
        for k, raw in enumerate(raws):
            code = self.process.call("od_write", obj.index, obj.subindex_of(k), obj.pack_le(raw))
            if code != 0:
                raise self._abort(f"write {obj.label(k)} ({obj.role}) = {raw!r}", code)

    # --- ControllerLink --------------------------------------------------------------------------
    def identity(self) -> dict:
        ident = super().identity()
        ident["firmware"] = self.info.name
        return ident

    def reset(self) -> None:
        """Clear the latched faults (when the profile has the action), then a power cycle
        (``hil_sil_reset``: the profile's reset action on SIL)."""
        if self.profile.has("clear_faults") and self.profile.get("clear_faults") is not None:
            self.act("clear_faults")
        self.process.call("power_cycle")
        self._emcy = []

    def edge(self, edge: dict):
        raise LinkError(f"{self.where}: edges reach a firmware in the loop through its pins (a LockstepBench of "
                        "this link runs the plant beside it)")

    def emcy_codes(self) -> list[int]:
        """The EMCY codes the firmware sent since the last power cycle or error reset, oldest first."""
        self._emcy += self.process.call("emcy")
        codes: list[int] = []
        for _, code in self._emcy:
            codes = [] if code == 0x0000 else codes + [code]  # 0x0000: error reset, the errors cleared
        return codes

    def faults(self) -> list[int]:
        """Latched faults, newest first, as framework codes: from the EMCY codes and/or the
        ``fault_code`` register, as the profile's ``[faults] source`` says."""
        out: list[int] = []
        if "emcy" in self.profile.fault_sources:
            for code in reversed(self.emcy_codes()):
                if self.profile.framework_fault(code) not in out:
                    out.append(self.profile.framework_fault(code))
        if "register" in self.profile.fault_sources or not self.profile.fault_sources:
            out += [c for c in super().faults() if c not in out]
        return out

    def simulation(self, config, seed: int, wiring=None, **sim_kwargs) -> "RemoteSimulation":
        """The plant of a bench, run in the firmware's process beside its peripherals
        (``hil.bench.lockstep.LockstepBench`` asks for it); ``wiring``: the faults' injector, acting on the pins."""
        if config.motor.pole_pairs != self.info.pole_pairs:
            raise LinkError(
                f"{self.where}: the plant has {config.motor.pole_pairs} pole pairs, the firmware is configured for "
                f"{self.info.pole_pairs} (hil_sil_describe)"
            )
        return RemoteSimulation(self, config, seed, sim_kwargs, wiring)

    def processor(self) -> dict | None:
        """What the emulated core and the interrupt schedule measured in this firmware's process so
        far (``pil:``; None for ``sil:``, whose interrupts take no time): ``hil.sil.worker.op_processor``."""
        return self.process.call("processor")

    def close(self) -> None:
        self.process.close()


class RemoteSimulation:
    """The plant of a bench with a firmware in the loop, in the firmware's process: the part of
    ``Simulation`` the suite reads."""

    def __init__(self, link: SilLink, config, seed: int, sim_kwargs: dict, wiring=None):
        self.link, self.config, self.wiring = link, config, wiring
        self._call = link.process.call
        self.t_s = self._call("bench", config, seed, link.wrap_at_s, sim_kwargs)
        self.interrupts: dict = {}
        if wiring is not None:  # the faults switched on the parent's injector act on the pins, in the worker
            wiring.mirror = lambda action, fault: self._call("wiring", action, fault.as_dict())

    def run_until(self, t_stop_s: float) -> None:
        self.t_s, self.interrupts, log = self._call("run_until", float(t_stop_s))
        if self.wiring is not None:
            self.wiring.log += log

    def commutations(self):
        """Every commutation the firmware's gates made, with the plant's true rotor angle."""
        return self._call("commutations")

    def edges(self):
        return self._call("sim", "edges")

    def edge_count(self) -> int:
        return self._call("sim", "edge_count")

    def samples(self):
        return self._call("sim", "samples")

    def energy(self):
        return self._call("sim", "energy")

    def set_edge_jitter(self, time_rms_s: float) -> None:
        self._call("sim", "set_edge_jitter", time_rms_s)

    def set_load_scale(self, scale: float) -> None:
        self._call("sim", "set_load_scale", scale)

    @property
    def edge_jitter_s(self) -> float:
        return self._call("sim", "edge_jitter_s")

    @property
    def speed_rpm(self) -> float:
        return self._call("sim", "speed_rpm")

