"""The electrical plant in virtual time: run it with a commutation source and read what a bench sees."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bldc.contract import Command
from bldc.hall import SECTOR_OF_CODE, SENSOR_POSITION_DEG_E
from bldc.params import ConfigError
from bldc.units import rad_per_s_to_rpm, rpm_to_rad_per_s

from . import effects as fx
from . import _kernel as K
from . import layout as L
from .edgelog import EdgeLog, join_ideal
from .plant import CompiledPlant, PlantConfig
from .sensor import set_targets


class RawHallCommutation:
    """The naive controller: commutate on every captured Hall edge, from the Hall code."""

    mode = L.MODE_RAW_HALL

    def __init__(self, latency_s: float = 0.0):
        self.latency_s = latency_s


class OracleCommutation:
    """Ideal commutation from the true rotor angle (the reference no controller can beat)."""

    mode = L.MODE_ORACLE
    latency_s = 0.0


@dataclass
class Samples:
    """Fixed-rate signals as a scope or DAQ would record them; true and measured currents."""

    t_s: np.ndarray
    i_true_a: np.ndarray      #: (n, 3)
    i_meas_a: np.ndarray      #: (n, 3) through the current sensors
    u_v: np.ndarray           #: (n, 3) terminal voltages to ground (PWM-averaged)
    speed_rpm: np.ndarray
    theta_m_deg: np.ndarray   #: true mechanical angle, unwrapped
    duty: np.ndarray
    sector: np.ndarray
    bemf_v: np.ndarray        #: (n, 3) true phase back-EMF
    torque_n_m: np.ndarray    #: electromagnetic torque

    @property
    def theta_e_deg(self) -> np.ndarray:
        return self._pole_pairs * self.theta_m_deg

    _pole_pairs: int = 2


@dataclass
class Commutations:
    """Every sector change the plant executed, with the true rotor angle at that instant."""

    t_s: np.ndarray
    sector: np.ndarray
    theta_e_deg: np.ndarray  #: true electrical angle, unwrapped
    direction: np.ndarray

    @property
    def error_deg_e(self) -> np.ndarray:
        """Angle error against the ideal commutation angle, positive = late (trails).

        Forward, sector s starts at 60 s; reverse (rotor turning backwards), sector s is
        entered at its upper boundary 60 (s + 1)."""
        ideal = np.where(self.direction > 0, 60.0 * self.sector, 60.0 * (self.sector + 1))
        return self.direction * (np.mod(self.theta_e_deg - ideal + 180.0, 360.0) - 180.0)

    def __len__(self) -> int:
        return int(self.t_s.size)


@dataclass
class Energy:
    electrical_in_j: float
    copper_loss_j: float
    mechanical_j: float
    load_j: float


class Simulation:
    """One run of the electrical plant, advanced in virtual time by :meth:`run_until`."""

    def __init__(
        self,
        config: PlantConfig,
        source=None,
        *,
        duty: float = 0.5,
        initial_speed_rpm: float = 0.0,
        initial_angle_deg_m: float = 0.0,
        direction: int = 1,
        sample_rate_hz: float = 100e3,
        max_step_s: float | None = None,
        seed: int = 0,
        capacity: int = 1 << 16,
    ):
        for name, value, ok in (
            ("duty", duty, 0.0 <= duty <= 1.0),
            ("initial_speed_rpm", initial_speed_rpm, initial_speed_rpm >= 0.0),
            ("initial_angle_deg_m", initial_angle_deg_m, True),
            ("sample_rate_hz", sample_rate_hz, sample_rate_hz > 0.0),
            ("max_step_s", max_step_s if max_step_s is not None else 1e-6, max_step_s is None or max_step_s > 0.0),
        ):
            if not isinstance(value, (int, float)) or not math.isfinite(value) or not ok:
                raise ConfigError(f"Simulation.{name}", f"invalid value {value!r}")
        if direction not in (1, -1):
            raise ConfigError("Simulation.direction", f"must be +1 or -1, got {direction!r}")
        self.config = config
        self.plant: CompiledPlant = config.compile()
        self.source = source if source is not None else OracleCommutation()
        self.rng = np.random.default_rng(seed)
        self.seed = seed
        cp = self.plant
        sample_period = 1.0 / sample_rate_hz
        p = np.zeros(L.N_PARAMS)
        for index, name in L.PLANT_PARAMS:
            p[index] = getattr(cp, name)
        run = {"sample_period_s": sample_period, "max_step_s": max_step_s if max_step_s is not None else sample_period,
               "latency_s": getattr(self.source, "latency_s", 0.0)}
        for index, name in L.RUN_PARAMS:
            p[index] = run[name]
        self.p = p
        self.sample_period_s = sample_period
        # the sensor layer's narrow interface to the kernel: one switching-angle table and one
        # current -> lag table (hall_field.py writes both alongside the library's effects)
        self.switch_table = np.ascontiguousarray(cp.switch_table_deg_e())
        self.arm_table = tuple(np.ascontiguousarray(a, dtype=float) for a in cp.armature_table())
        st = np.zeros(L.N_FSTATE)
        ist = np.zeros(L.N_ISTATE, dtype=np.int64)
        st[L.S_THETA_M] = math.radians(initial_angle_deg_m)
        st[L.S_OMEGA_M] = direction * rpm_to_rad_per_s(initial_speed_rpm)  # a magnitude, turning the driven way
        st[L.S_DUTY] = duty
        st[L.S_NEXT_SAMPLE] = 0.0
        st[L.S_SAMPLE_T0] = 0.0
        ist[L.I_DIR] = direction
        ist[L.I_MODE] = getattr(self.source, "mode", L.MODE_EXTERNAL)
        self.st, self.ist = st, ist
        self.noise = self.rng.standard_normal(1 << 16)
        self.cmds = np.zeros((4096, 4))
        self.pending = np.zeros((L.MAX_PENDING, L.N_EDGE_COLS))
        self.current_ring = np.zeros((L.CURRENT_RING, 4))
        # output buffers: the kernel writes each row before anything reads it (rows below the
        # counts in ist), so they are not zeroed (zeroing 40 MB of reused memory took 3.6 ms,
        # a quarter of a simulated second at 15,000 rpm), as _flush's fresh buffers are not
        self._edges = np.empty((capacity, L.N_EDGE_COLS))
        self._ideal = np.empty((capacity, L.N_IDEAL_COLS))
        self._samples = np.empty((capacity, L.N_SAMPLE_COLS))
        self._comm = np.empty((capacity, 4))
        self._comm_chunks: list[np.ndarray] = []
        self._edge_chunks: list[np.ndarray] = []
        self._ideal_chunks: list[np.ndarray] = []
        self._sample_chunks: list[np.ndarray] = []
        self._samples_flushed = 0  #: samples moved from the buffer into _sample_chunks
        self._segment_marks: list[tuple[float, int]] = []
        self._init_sensors()

    # --- set-up ----------------------------------------------------------------------------
    def _init_sensors(self):
        the = self.plant.pole_pairs * math.degrees(self.st[L.S_THETA_M])
        for x in range(3):
            m = math.floor((the - SENSOR_POSITION_DEG_E[x]) / 180.0)
            self.ist[L.I_IDEAL_REGION + x] = m
            # raw region: the one whose switching angles bracket the present angle
            for _ in range(4):
                self.ist[L.I_RAW_REGION + x] = m
                set_targets(self.p, self.st, self.ist, self.switch_table, self.noise, x)
                if the >= self.st[L.S_FWD_TARGET + x]:
                    m += 1
                elif the < self.st[L.S_REV_TARGET + x]:
                    m -= 1
                else:
                    break
            self.ist[L.I_SEEN + x] = 1 if self.ist[L.I_RAW_REGION + x] % 2 == 0 else 0
        n = math.floor(the / 60.0)
        self.ist[L.I_ORACLE_N] = n
        if self.ist[L.I_MODE] == L.MODE_ORACLE:
            self.ist[L.I_SECTOR] = n % 6
        else:
            code = self.ist[L.I_SEEN] * 4 + self.ist[L.I_SEEN + 1] * 2 + self.ist[L.I_SEEN + 2]
            self.ist[L.I_SECTOR] = SECTOR_OF_CODE[code]

    # --- control -----------------------------------------------------------------------------
    @property
    def t_s(self) -> float:
        return float(self.st[L.S_T])

    @property
    def speed_rpm(self) -> float:
        return float(rad_per_s_to_rpm(self.st[L.S_OMEGA_M]))

    @property
    def sector(self) -> int:
        return int(self.ist[L.I_SECTOR])

    def _through_current_sensors(self, i_a: float, i_b: float, i_c: float) -> float:
        """Mean |i| of three phase currents as the current sensors measure them (gain, offset; no
        noise). Scalar arithmetic: it runs once per edge in the lockstep loop, where numpy's
        per-call overhead on three values was a tenth of the whole edge's cost."""
        cs = self.config.current_sensor
        total = 0.0
        for k, i in enumerate((i_a, i_b, i_c)):
            total += abs(i * (1.0 + cs.gain_error[k]) + cs.offset_a[k])
        return total / 3.0

    def _sensed(self, i_true_a: np.ndarray) -> np.ndarray:
        """Phase currents (rows of three) as the current sensors measure them: gain and offset (the
        array form of ``_through_current_sensors``; no noise)."""
        cs = self.config.current_sensor
        return i_true_a * (1.0 + np.asarray(cs.gain_error)) + np.asarray(cs.offset_a)

    def measured_mean_abs_current_a(self) -> float:
        """Mean |i| over the phases now, through the current sensors: what a controller's ADC reads
        at this instant."""
        st = self.st
        return self._through_current_sensors(float(st[L.S_IA]), float(st[L.S_IB]), float(st[L.S_IC]))

    @property
    def samples_taken(self) -> int:
        """Samples recorded since the start (flushed ones included): an index into ``samples()``."""
        return self._samples_flushed + int(self.ist[L.I_N_SAMPLES])

    def _sample_rows_since(self, first_sample: int) -> np.ndarray:
        """Sample rows from index ``first_sample`` (``samples_taken`` counting) to now, across
        buffer flushes."""
        n_buffer = int(self.ist[L.I_N_SAMPLES])
        parts = [self._samples[max(first_sample - self._samples_flushed, 0):n_buffer]]
        end = self._samples_flushed
        for chunk in reversed(self._sample_chunks):  # the window's part that was flushed, if any
            if end <= first_sample:
                break
            start = end - chunk.shape[0]
            parts.insert(0, chunk[max(first_sample - start, 0):])
            end = start
        return np.concatenate(parts) if len(parts) > 1 else parts[0]

    def sensed_samples_since(self, first_sample: int, until_s: float) -> np.ndarray:
        """The phase-current sensors' outputs (rows of three, A) of the samples from index
        ``first_sample`` on taken at or before ``until_s``."""
        if self.samples_taken <= first_sample:
            return np.empty((0, 3))
        rows = self._sample_rows_since(first_sample)
        return self._sensed(rows[rows[:, 0] <= until_s, 1:4])

    def adc_conversions_at(self, t_s: np.ndarray) -> np.ndarray:
        """The phase-current sensors' outputs (rows of three, A) at the instants ``t_s`` of the
        recent past: the plant's current history, linear between step starts, held at its oldest
        row (``CURRENT_RING`` rows) and at the present."""
        ring, mask = self.current_ring, L.CURRENT_RING - 1
        n = int(self.ist[L.I_RING_N])
        first = max(n - L.CURRENT_RING, 0)
        # from the newest row at or before the earliest instant asked for (the same interpolation:
        # every instant has the same two rows around it): an edge's window reaches a few dozen rows
        # back, and copying and searching all 512 was a tenth of a lockstep edge's cost
        earliest = float(np.min(t_s)) if np.size(t_s) else self.t_s
        start = n - 1
        while start > first and ring[start & mask, 0] > earliest:
            start -= 1
        rows = ring[np.arange(start, n) & mask] if n > first else ring[:0]
        rows = rows[rows[:, 0] < self.t_s]
        st = self.st
        history = np.empty((rows.shape[0] + 1, 4))  # the present closes the history
        history[:-1] = rows
        history[-1] = (self.t_s, st[L.S_IA], st[L.S_IB], st[L.S_IC])
        currents = np.empty((np.size(t_s), 3))
        for j in range(3):
            currents[:, j] = np.interp(t_s, history[:, 0], history[:, 1 + j])
        return self._sensed(currents)

    def set_duty(self, duty: float) -> None:
        if not math.isfinite(duty) or not 0.0 <= duty <= 1.0:
            raise ConfigError("duty", f"must be in [0, 1], got {duty!r}")
        self.st[L.S_DUTY] = duty

    #: the largest load step ``set_load_scale`` takes: a pump whose load torque triples at the same
    #: speed (a valve from nearly shut to open) is a bench fault, not a disturbance
    MAX_LOAD_SCALE = 3.0

    def set_load_scale(self, scale: float) -> None:
        """The pump's load torque ``scale`` times the plant's own at every speed from now on (the
        fan coefficient scaled: a valve opening, the flow rising): a load disturbance a speed loop
        with integral action must reject."""
        if not math.isfinite(scale) or not 0.0 < scale <= self.MAX_LOAD_SCALE:
            raise ConfigError("load scale", f"must be within (0, {self.MAX_LOAD_SCALE:g}], got {scale!r}")
        self.p[L.P_FAN] = self.plant.fan_coefficient_n_m_s2 * scale

    def set_edge_jitter(self, time_rms_s: float) -> None:
        """The Hall edges' RMS time jitter from the next edge on: a step of the edge noise in mid-run,
        which an adaptive filter must track (the ``edge_jitter`` effect sets it from the start)."""
        high = fx.EdgeJitter.__dataclass_fields__["time_rms_s"].metadata["high"]  # the effect library's bound
        if not math.isfinite(time_rms_s) or not 0.0 <= time_rms_s <= high:
            raise ConfigError("edge jitter time_rms_s", f"must be within [0, {high:g}] s, got {time_rms_s!r}")
        self.p[L.P_JIT_T] = time_rms_s

    @property
    def edge_jitter_s(self) -> float:
        """The Hall edges' RMS time jitter now (plant truth)."""
        return float(self.p[L.P_JIT_T])

    def mark_segment(self, index: int) -> None:
        """Edges captured from now on belong to operating segment ``index``."""
        self._segment_marks.append((self.t_s, index))

    def schedule(self, command: Command) -> None:
        if command.at_s < self.t_s - 1e-12:
            raise ValueError(f"command at {command.at_s} s is in the past (plant time {self.t_s} s)")
        head, count = int(self.ist[L.I_CMD_HEAD]), int(self.ist[L.I_CMD_COUNT])
        values = (command.at_s, -2 if command.sector is None else command.sector,
                  -1 if command.duty is None else command.duty, command.direction or 0)
        if head == count:  # queue drained: start again at the top
            head = count = 0
            self.ist[L.I_CMD_HEAD] = 0
        if count < self.cmds.shape[0] and (count == head or command.at_s >= self.cmds[count - 1, 0]):
            self.cmds[count] = values  # the usual case: commands arrive in time order
            self.ist[L.I_CMD_COUNT] = count + 1
            return
        live = self.cmds[head:count].copy()
        row = np.array([values])
        live = np.concatenate([live, row])
        live = live[np.argsort(live[:, 0], kind="stable")]
        if live.shape[0] > self.cmds.shape[0]:
            raise RuntimeError("more than 4096 commands pending")
        self.cmds[: live.shape[0]] = live
        self.ist[L.I_CMD_HEAD] = 0
        self.ist[L.I_CMD_COUNT] = live.shape[0]

    def run_until(self, t_stop_s: float) -> None:
        while (edge := self.step_until(t_stop_s)) is not None:
            edge["current_a"] = self.measured_mean_abs_current_a()
            for cmd in self.source.on_edge(edge, self) or ():
                self.schedule(cmd)
        self._flush()

    def step_until(self, t_stop_s: float) -> dict | None:
        """Advance to ``t_stop_s``, or to the next captured edge when one comes first: its record
        (capture and conditioned instants, sensor, polarity, the instant now), else None. The
        edges' own loop (``run_until``), or a source that keeps its own events between them (the
        firmware's interrupts, ``hil.sil``)."""
        while True:
            reason = K.run(
                self.p, self.st, self.ist, self.switch_table, self.arm_table[0], self.arm_table[1], self.noise,
                self.cmds, self.pending, self._edges, self._ideal, self._samples, self._comm, self.current_ring,
                float(t_stop_s),
            )
            if reason == L.STOP_TIME:
                return None
            if reason == L.STOP_EDGE:
                n = int(self.ist[L.I_N_EDGES])
                row = self._edges[n - 1]
                edge = {
                    "t_capture_s": float(row[L.E_T_CAPTURE]),
                    "t_conditioned_s": float(row[L.E_T_COND]),
                    "sensor": int(row[L.E_SENSOR]),
                    "rising": bool(row[L.E_RISING]),
                    "now_s": self.t_s,
                }
                if n >= self._edges.shape[0]:
                    self._flush()
                return edge
            if reason == L.STOP_NOISE:
                # a new array, not written in place: a checkpoint may hold the one before
                self.noise = self.rng.standard_normal(self.noise.size)
                self.ist[L.I_NOISE] = 0
                continue
            self._flush()  # STOP_FULL

    _LOGS = (("_edges", "_edge_chunks", L.I_N_EDGES), ("_ideal", "_ideal_chunks", L.I_N_IDEAL),
             ("_samples", "_sample_chunks", L.I_N_SAMPLES), ("_comm", "_comm_chunks", L.I_N_COMM))

    def checkpoint(self) -> tuple:
        """The plant's state now, for :meth:`restore`: a source that steps the plant ahead and may
        find it went too far (a firmware's interrupt returned, and its outputs took effect, before
        the instant the plant reached: ``hil.sil.peripherals``). Small copies (the state vectors,
        the edges in flight, the current ring); the logs by their counts, the noise by reference."""
        logs = tuple((getattr(self, buf), len(getattr(self, chunks))) for buf, chunks, _ in self._LOGS)
        return (self.st.copy(), self.ist.copy(), self.pending.copy(), self.current_ring.copy(), self.noise,
                self.rng.bit_generator.state, self._samples_flushed, logs)

    def restore(self, checkpoint: tuple) -> None:
        """Back to a :meth:`checkpoint` of this run taken since the last command was scheduled: the
        same steps from there give the same run."""
        st, ist, pending, ring, noise, rng_state, flushed, logs = checkpoint
        for (name, chunks_name, idx), (buf, n_chunks) in zip(self._LOGS, logs):
            chunks = getattr(self, chunks_name)
            if len(chunks) > n_chunks:  # flushed since: the rows the checkpoint counted are in the first new chunk
                n = int(ist[idx])
                buf[:n] = chunks[n_chunks][:n]
                del chunks[n_chunks:]
            setattr(self, name, buf)
        self.st[:], self.ist[:], self.pending[:], self.current_ring[:] = st, ist, pending, ring
        self.noise = noise
        self.rng.bit_generator.state = rng_state
        self._samples_flushed = flushed

    def _flush(self):
        for name, chunks_name, idx in self._LOGS:
            chunks = getattr(self, chunks_name)
            n = int(self.ist[idx])
            if not n:
                continue
            if name == "_samples":
                self._samples_flushed += n
            buf = getattr(self, name)
            if 2 * n >= buf.shape[0]:
                # at least half full: hand the buffer over and write on into a new one (copying
                # 100 kHz samples out was a third of the plant's run time); a short tail is
                # copied, so many small flushes never pin a whole buffer each
                chunks.append(buf[:n])
                setattr(self, name, np.empty_like(buf))
            else:
                chunks.append(buf[:n].copy())
            self.ist[idx] = 0

    # --- results -----------------------------------------------------------------------------
    def edge_count(self) -> int:
        """How many edges the plant has logged (``len(edges())`` without building the log)."""
        return sum(c.shape[0] for c in self._edge_chunks) + int(self.ist[L.I_N_EDGES])

    def edges(self) -> EdgeLog:
        self._flush()
        if not self._edge_chunks:
            return EdgeLog.empty()
        e = np.concatenate(self._edge_chunks)
        ideal = np.concatenate(self._ideal_chunks) if self._ideal_chunks else np.zeros((0, 4))
        t_ideal = join_ideal(e[:, [L.E_BOUNDARY, L.E_SENSOR, L.E_DIR]], e[:, L.E_T_RAW], ideal)
        segment = np.full(e.shape[0], -1, dtype=np.int64)
        for t_mark, index in self._segment_marks:
            segment[e[:, L.E_T_COND] >= t_mark] = index
        return EdgeLog(
            t_capture_s=e[:, L.E_T_CAPTURE], t_conditioned_s=e[:, L.E_T_COND], t_raw_s=e[:, L.E_T_RAW],
            t_ideal_s=t_ideal, sensor=e[:, L.E_SENSOR].astype(np.int64), rising=e[:, L.E_RISING] > 0.5,
            boundary=e[:, L.E_BOUNDARY].astype(np.int64), pole=e[:, L.E_POLE].astype(np.int64),
            direction=e[:, L.E_DIR].astype(np.int64), theta_e_switch_deg=e[:, L.E_THETA_RAW],
            theta_e_capture_deg=e[:, L.E_THETA_CAPTURE], speed_rpm=e[:, L.E_SPEED_RPM],
            mean_abs_current_a=e[:, L.E_CURRENT], segment=segment,
        )

    def commutations(self) -> "Commutations":
        self._flush()
        c = np.concatenate(self._comm_chunks) if self._comm_chunks else np.zeros((0, 4))
        return Commutations(
            t_s=c[:, 0], sector=c[:, 1].astype(np.int64), theta_e_deg=c[:, 2], direction=c[:, 3].astype(np.int64)
        )

    def samples(self) -> Samples:
        self._flush()
        s = _joined(self._sample_chunks, L.N_SAMPLE_COLS)
        cs = self.config.current_sensor
        i_true = s[:, 1:4]
        noise_rng = np.random.default_rng([self.seed, 1])
        i_meas = self._sensed(i_true)
        if cs.noise_rms_a > 0:
            i_meas = i_meas + cs.noise_rms_a * noise_rng.standard_normal(i_true.shape)
        out = Samples(
            t_s=s[:, 0], i_true_a=i_true, i_meas_a=i_meas, u_v=s[:, 4:7], speed_rpm=s[:, 7],
            theta_m_deg=s[:, 8], duty=s[:, 9], sector=s[:, 10].astype(np.int64), bemf_v=s[:, 11:14],
            torque_n_m=s[:, 14],
        )
        out._pole_pairs = self.plant.pole_pairs
        return out

    def energy(self) -> Energy:
        st = self.st
        return Energy(float(st[L.S_E_IN]), float(st[L.S_E_CU]), float(st[L.S_E_MECH]), float(st[L.S_E_LOAD]))


def simulate(config: PlantConfig, duration_s: float, source=None, **kwargs) -> Simulation:
    sim = Simulation(config, source, **kwargs)
    sim.run_until(duration_s)
    return sim


def _joined(chunks: list[np.ndarray], columns: int) -> np.ndarray:
    """The chunks as one array, read-only: a single chunk (a run that fit its buffer, as the
    lockstep bench's do) is handed out as it is, since the simulation never writes a chunk again;
    several are joined once (12 MB a simulated second at 100 kHz) and kept joined."""
    if not chunks:
        return np.zeros((0, columns))
    if len(chunks) == 1:
        out = chunks[0].view()
    else:
        out = np.concatenate(chunks)
        chunks[:] = [out]  # the next call hands out the same array
    out.flags.writeable = False
    return out

