"""A firmware's own process: the library, the plant and the peripherals between them.

One process per firmware instance: a firmware that crashes (a signal) or hangs (an interrupt
that does not return) ends its process, never the run; the parent (``hil.sil.link``) names the
event from the call record this process keeps in shared memory before every call into the
firmware (``[seq, event, t_s, count, in_call]``), and the next test gets a freshly loaded,
reset firmware.
"""

from __future__ import annotations

import sys
import traceback

import numpy as np

from .firmware import SilInterfaceError
from .peripherals import DESCRIBE, OD_READ, OD_WRITE, RESET, FirmwareFault, Peripherals, enter_call, leave_call


def load_firmware(kind: str, library: str, target: str):
    """The firmware of this process: a shared library (``sil``, ctypes) or an ELF on an emulated core
    of the ``[target]`` in ``target`` (``pil``, ``hil.sil.processor``)."""
    if kind == "pil":
        from .processor import processor_firmware

        return processor_firmware(library, target)
    from .firmware import Firmware

    return Firmware(library)


def firmware_faults(kind: str) -> tuple[type, ...]:
    """What a call into this kind of firmware raises when the firmware broke (its state can no longer
    be trusted: the process ends, the parent names it, the next request gets a fresh firmware)."""
    faults: tuple[type, ...] = (FirmwareFault, SilInterfaceError)
    if kind == "pil":
        from hil.pil.core import ProcessorFinding

        faults += (ProcessorFinding,)
    return faults


def processor_finding(exc: BaseException) -> str | None:
    """The kind of the emulated core's finding ``exc`` is or carries (UsageFault, StackOverflow,
    Hang ...; ``hil.pil.core.ProcessorFinding``, or a ``FirmwareFault`` the scheduler made of one), else None."""
    core = sys.modules.get("hil.pil.core")  # imported by a pil: worker only
    if core is not None and isinstance(exc, core.ProcessorFinding):
        return exc.kind
    return getattr(exc, "processor", None)


class _Worker:
    def __init__(self, library: str, record: np.ndarray, kind: str = "sil", target: str = ""):
        self.record = record
        self.fw = load_firmware(kind, library, target)
        self.simulated_s = 0.0  #: simulated time this process's benches ran (the soft-float rates' base)
        self._schedules: list[dict] = []  #: the finished benches' schedules (pil:)
        self._enter(DESCRIBE)
        self.info = self.fw.describe()
        self._leave()
        self.periph: Peripherals | None = None
        self.emcy: list[tuple[float, int]] = []

    def _enter(self, event: int, t_s: float = 0.0, count: float = -1.0) -> None:
        enter_call(self.record, event, t_s, count)

    def _leave(self) -> None:
        leave_call(self.record)

    def _now(self) -> tuple[float, int]:
        p = self.periph
        return (p.sim.t_s, p.count(p.sim.t_s)) if p is not None else (0.0, -1)

    def _drain_emcy(self) -> None:
        if self.periph is not None:
            self.emcy += self.periph.emcy
            self.periph.emcy = []
        if self.fw.has_emcy:
            t, _ = self._now()
            while (code := self.fw.emcy()) is not None:
                self.emcy.append((t, code))

    # --- operations (the parent's requests) -------------------------------------------------------
    def op_info(self):
        return self.info

    def op_od_read(self, index: int, sub: int, size: int):
        self._enter(OD_READ, *self._now())
        out = self.fw.od_read(index, sub, size)
        self._leave()
        self._drain_emcy()
        return out

    def op_od_write(self, index: int, sub: int, data: bytes):
        t, count = self._now()
        self._enter(OD_WRITE, t, count)
        out = self.fw.od_write(index, sub, data)
        if self.periph is not None:
            # as on the chip, what the write changed (a set point's duty, a strategy's gates) is in
            # force at once, not from the next interrupt
            self.periph.outputs_after(OD_WRITE, t, count)
        else:
            self._leave()
        self._drain_emcy()
        return out

    def op_power_cycle(self):
        """``hil_sil_reset`` with the pins as the plant holds them (the last run's; before any
        run, A high and B, C low: a legal Hall state)."""
        levels = self.periph.pins if self.periph is not None else 0b001
        self._finish()
        self._enter(RESET, *self._now())
        self.fw.reset(levels)
        self._leave()
        self.emcy = []
        self._drain_emcy()
        self.emcy = []  # what the firmware queued before the power cycle is gone with its RAM

    def op_bench(self, config, seed: int, wrap_at_s: float, sim_kwargs: dict):
        from plant_models.simulation import Simulation

        from plant_models import layout as L

        class _Source:  # the firmware answers through its peripherals, not through commands
            mode = L.MODE_EXTERNAL
            latency_s = 0.0

        sim = Simulation(config, _Source(), seed=seed, **sim_kwargs)
        self._drain_emcy()
        self.emcy = []
        from .scheduler import peripherals_for

        if self.periph is not None:
            self._finish()
            self._keep_figures()
        self.periph = peripherals_for(self.fw)(self.fw, self.info, sim, seed=seed, wrap_at_s=wrap_at_s,
                                               record=self.record)
        return sim.t_s

    def op_run_until(self, t_s: float):
        t0 = self.periph.sim.t_s
        try:
            self.periph.run_until(t_s)
        except BaseException:
            if getattr(self.fw, "core", None) is None:  # a core that met a fault takes no further call
                self._drain_emcy()
            raise
        self.simulated_s += self.periph.sim.t_s - t0
        self._drain_emcy()
        log, self.periph.injector.log = self.periph.injector.log, []
        return self.periph.sim.t_s, self.periph.interrupts, log

    def op_wiring(self, action: str, fault: dict):
        """Switch a wiring fault on or off between the plant and the pins (``hil.dut.faults``)."""
        from hil.dut.faults import wiring_fault_from_dict

        injector = self.periph.injector
        (injector.switch_on if action == "on" else injector.switch_off)(wiring_fault_from_dict(fault))

    def op_emcy(self):
        self._drain_emcy()
        out, self.emcy = self.emcy, []
        return out

    def op_sim(self, name: str, *args):
        """A plant result or setting: edges, samples, energy, set_edge_jitter, set_load_scale, edge_jitter_s,
        speed_rpm."""
        sim = self.periph.sim
        attr = getattr(sim, name)
        return attr(*args) if callable(attr) else attr

    def op_commutations(self):
        return self.periph.commutations()

    def _keep_figures(self) -> None:
        figures = getattr(self.periph, "figures", None)
        if figures is not None:
            self._schedules.append(figures())

    def _finish(self) -> None:
        """The interrupts a timed run left running end before a power cycle or a new bench."""
        finish = getattr(self.periph, "finish", None)
        if finish is not None:
            finish()

    def op_processor(self):
        """``pil:``: the core's figures (``PilFirmware.stats``: per interrupt its calls, cycles and soft
        floating-point routines, the stack, flash and RAM) and every bench's schedule
        (``TimedPeripherals.figures``) since this process started; None for a firmware without a core."""
        if getattr(self.fw, "core", None) is None:
            return None
        schedules = list(self._schedules)
        if self.periph is not None and hasattr(self.periph, "figures"):
            schedules.append(self.periph.figures())
        return {"core": self.fw.stats(), "schedules": schedules, "simulated_s": self.simulated_s}


def main(conn, record: np.ndarray, library: str, kind: str = "sil", target: str = "") -> None:
    """The process's loop: one request, one answer, until ``close`` or the parent goes away."""
    try:
        faults = firmware_faults(kind)
        worker = _Worker(library, record, kind, target)
    except SilInterfaceError as exc:
        conn.send(("interface", str(exc)))
        return
    except faults as exc:  # pil: a fault in a C++ constructor or hil_sil_describe
        conn.send(("interface", str(exc)))
        return
    except BaseException as exc:  # noqa: BLE001 (sent to the parent, which raises it)
        conn.send(("error", _portable(exc)))
        return
    conn.send(("ok", worker.info))
    while True:
        try:
            op, args = conn.recv()
        except (EOFError, OSError):
            return
        if op == "close":
            conn.send(("ok", None))
            return
        try:
            result = getattr(worker, f"op_{op}")(*args)
        except faults as exc:
            # a finding of the emulated core (pil:) is the device's own failure, named as such
            conn.send(("processor fault" if processor_finding(exc) else "fault", str(exc)))
            return  # the firmware's state can no longer be trusted: the next request gets a new process
        except BaseException as exc:  # noqa: BLE001
            conn.send(("error", _portable(exc)))
            continue
        conn.send(("ok", result))


class _Duplex:
    """Two one-way pipe ends as one connection (what ``multiprocessing.Pipe`` would give, over
    descriptors a plain subprocess inherits)."""

    def __init__(self, reader, writer):
        self.reader, self.writer = reader, writer

    def recv(self):
        return self.reader.recv()

    def send(self, obj) -> None:
        self.writer.send(obj)

    def poll(self, timeout: float = 0.0) -> bool:
        return self.reader.poll(timeout)

    def close(self) -> None:
        self.reader.close()
        self.writer.close()

    @property
    def closed(self) -> bool:
        return self.reader.closed


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it pickles, else a RuntimeError carrying its text and traceback."""
    import pickle

    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}\n{''.join(traceback.format_exception(exc))}")


if __name__ == "__main__":  # python -m hil.sil.worker READ_FD WRITE_FD RECORD_FILE LIBRARY KIND TARGET (hil.sil.link)
    import sys
    from multiprocessing.connection import Connection

    read_fd, write_fd, record_file, library_path, firmware_kind, target_file = (sys.argv[1:7] + ["sil", ""])[:6]
    main(_Duplex(Connection(int(read_fd), writable=False), Connection(int(write_fd), readable=False)),
         np.memmap(record_file, dtype=np.float64, mode="r+", shape=(5,)), library_path, firmware_kind, target_file)
