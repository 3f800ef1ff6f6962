"""The defect classes that have a magnitude, swept: each requirement's power is the smallest
magnitude of its class that it catches (docs/qualify.md, "Power").

    python -m hil qualify --sensitivity --defects tools/power_defects.py \\
        --only "$(python tools/power_defects.py)" --json power.json --table power.md

Commutation timing: an uncompensated gate latency (the catalogue seeds 5 and 25 us). Model input:
Eq. 8's cycle-mean current scaled (the catalogue seeds 0, the signed sum; 3, the phases summed;
1000, mA).
"""

from hil.qualify.defects import CycleCurrentScaled, GateLatency, defect

LATENCIES_US = (1.0, 2.0, 3.0)
CURRENT_SCALES = (0.5, 0.8, 1.25, 2.0)
NAMES = []

for _us in LATENCIES_US:
    NAMES.append(f"power-gate-latency-{_us:g}us")
    defect(NAMES[-1], f"{_us:g} us of gate-driver latency not compensated", "commutation-timing")(
        type(f"GateLatency{_us:g}".replace(".", "_"), (GateLatency,),
             {"__annotations__": {"latency_s": float}, "latency_s": _us * 1e-6}))
for _k in CURRENT_SCALES:
    NAMES.append(f"power-cycle-current-x{_k:g}")
    defect(NAMES[-1], f"Eq. 8's cycle-mean current input {_k:g} times the measured one", "model-input")(
        type(f"CycleCurrentX{_k:g}".replace(".", "_"), (CycleCurrentScaled,),
             {"__annotations__": {"scale": float}, "scale": _k}))

if __name__ == "__main__":
    print(",".join(NAMES))
