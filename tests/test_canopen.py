"""CANopen face of the virtual controller (CiA 301 conformance) and the CANopen link, over python-can's
in-process ``virtual`` bus."""

import itertools
import math
import struct
import time

import canopen
import numpy as np
import pytest
from canopen.sdo.exceptions import SdoAbortedError

from bldc.contract import ADC_PERIOD_S, Fault, Strategy
from bldc.motor import steady_state
from hil.bench.lockstep import LockstepBench
from hil.calibration.campaign import station_corrections
from hil.controller.virtual import VirtualController
from hil.dut.canopen_device import CanopenDevice
from hil.dut.canopen_link import CanopenLink
from hil.dut.in_process import InProcessLink
from hil.dut.link import LinkError, LinkTimeout
from hil.dut.eds import SHIPPED_EDS, shipped_eds_text
from plant_models import paper_bench

CONFIG = paper_bench(with_deviations=True)
_channels = itertools.count()


@pytest.fixture(scope="module")
def corrections():
    return station_corrections(CONFIG, seed=0)


@pytest.fixture(params=[False, True], ids=["notifier-threads", "inline"])
def pair(request):
    """A device and the link on one virtual channel: through python-can's notifier threads, and
    with each frame taken in the sending thread as ``--dut virtual:canopen`` runs them."""
    channel = f"co{next(_channels)}"
    vc = VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA, speed_setpoint_rpm=6000.0)
    dev = CanopenDevice(vc, node_id=5, channel=channel, inline=request.param)
    link = CanopenLink(node_id=5, channel=channel, timeout_s=0.5, inline=request.param)
    yield vc, dev, link
    link.close()
    dev.close()


def test_the_shipped_eds_is_generated_from_the_shipped_profile():
    """The profile is the one source of the built-in map; the EDS is written from it."""
    assert SHIPPED_EDS.read_text() == shipped_eds_text(), (
        "regenerate: python -m hil.dut.eds hil/dut/profiles/virtual-canopen.toml -o "
        "hil/dut/profiles/virtual-canopen.eds"
    )


def test_lockstep_over_canopen_is_identical_to_in_process(pair, corrections):
    vc, dev, link = pair
    runs = []
    for lk in (
        link,
        InProcessLink(VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA, speed_setpoint_rpm=6000.0)),
    ):
        lk.download_calibration(corrections)
        b = LockstepBench(CONFIG, lk, initial_speed_rpm=6000.0, duty=steady_state(CONFIG.motor, 6000.0)["duty"])
        b.run_setpoints([6000.0, 6300.0], hold_s=0.1, settle_s=0.05)
        runs.append(b.sim.commutations())
    a, c = runs
    assert len(a) > 200
    np.testing.assert_array_equal(a.t_s, c.t_s)
    np.testing.assert_array_equal(a.sector, c.sector)


def test_identity_and_every_object_reads_back_with_its_declared_type(pair):
    _, _, link = pair
    ident = link.identity()
    assert ident == {
        "vendor_id": 0x0B1D,
        "product_code": 0x00480001,
        "revision": 0x00010000,
        "serial": 1,
        "device_type": 0x192,
        "firmware": "vc-0.1.0",
    }
    od = link.node.object_dictionary
    checked = 0
    for obj in od.values():
        for var in obj.values() if not isinstance(obj, canopen.objectdictionary.ODVariable) else [obj]:
            if not var.readable:
                continue
            value = link.read(
                var.index, var.subindex if not isinstance(obj, canopen.objectdictionary.ODVariable) else None
            )
            if var.data_type in canopen.objectdictionary.INTEGER_TYPES:
                assert isinstance(value, int), (hex(var.index), var.subindex)
            elif var.data_type in canopen.objectdictionary.FLOAT_TYPES:
                assert isinstance(value, float), (hex(var.index), var.subindex)
            else:
                assert isinstance(value, str)
            checked += 1
    assert checked > 40


def abort_of(link, fn):
    with pytest.raises(SdoAbortedError) as info:
        fn()
    return info.value.code


@pytest.mark.parametrize(
    "request_, code",
    [
        ("read 0x6000", 0x06020000),
        ("read 0x2010:0x20", 0x06090011),
        ("write 0x1000", 0x06010002),
        ("read 0x2011", 0x06010001),
        ("write 0x2000 = 7", 0x06090030),
        ("write 0x2001 = -5", 0x06090030),
        ("write 0x2000 with 4 bytes", 0x06070010),
    ],
)
def test_sdo_abort_codes(pair, request_, code):
    _, _, link = pair
    sdo = link.node.sdo
    fns = {
        "read 0x6000": lambda: sdo.upload(0x6000, 0),
        "read 0x2010:0x20": lambda: sdo.upload(0x2010, 0x20),
        "write 0x1000": lambda: sdo.download(0x1000, 0, struct.pack("<I", 1)),
        "read 0x2011": lambda: sdo.upload(0x2011, 0),
        "write 0x2000 = 7": lambda: sdo.download(0x2000, 0, bytes([7])),
        "write 0x2001 = -5": lambda: sdo.download(0x2001, 0, struct.pack("<f", -5.0)),
        "write 0x2000 with 4 bytes": lambda: sdo.download(0x2000, 0, struct.pack("<I", 1)),
    }
    assert abort_of(link, fns[request_]) == code
    assert link.read(0x2000) == 3  # still serving well-formed requests


def test_abort_echoes_the_requested_index(pair):
    _, _, link = pair
    frames = []
    link.network.subscribe(0x585, lambda cid, data, ts: frames.append(bytes(data)))
    link.read(0x1018, 1)  # leave a previous index behind
    with pytest.raises(SdoAbortedError):
        link.node.sdo.upload(0x6000, 3)
    time.sleep(0.05)
    cmd, index, sub, code = struct.unpack("<BHBI", frames[-1])
    assert (cmd, index, sub, code) == (0x80, 0x6000, 3, 0x06020000)


def test_heartbeat_period_matches_0x1017(pair):
    _, _, link = pair
    link.write(0x1017, None, 50)
    stamps = []
    link.network.subscribe(0x705, lambda cid, data, ts: stamps.append(time.monotonic()))
    time.sleep(1.1)
    intervals = np.diff(stamps[1:])
    assert len(intervals) >= 15
    assert np.median(intervals) == pytest.approx(0.050, rel=0.05)


def test_fault_sends_emcy_and_sets_error_register_and_history(pair):
    vc, dev, link = pair
    assert link.read(0x1001) == 0
    vc.raise_fault(Fault.MISSING_EDGE, 1.0)
    ts, frame = link.emcy.get(timeout=1.0)
    code, register = struct.unpack_from("<HB", frame)
    assert code == Fault.MISSING_EDGE and register & 0x01
    assert link.read(0x1001) & 0x81 == 0x81
    assert link.read(0x1003, 0) == 1 and link.read(0x1003, 1) == Fault.MISSING_EDGE
    with pytest.raises(LinkError, match="0x06090030"):
        link.write(0x1003, 0, 1)
    link.write(0x1003, 0, 0)
    assert link.read(0x1003, 0) == 0


def test_invalid_calibration_is_refused_with_emcy(pair, corrections):
    vc, dev, link = pair
    bad = corrections.__class__.from_json_dict(corrections.to_json_dict())
    bad.conditioning_delay_s["rise"] = 1e-3  # beyond the 500 us the controller accepts (MAX_CONDITIONING_DELAY_S)
    with pytest.raises(LinkError, match="0x06090030"):
        link.download_calibration(bad)
    _, frame = link.emcy.get(timeout=1.0)
    assert struct.unpack_from("<H", frame)[0] == Fault.INVALID_CALIBRATION


def test_nmt_states_and_boot_up_after_reset(pair, corrections):
    vc, dev, link = pair
    boots = []
    link.network.subscribe(0x705, lambda cid, data, ts: boots.append(bytes(data)) if bytes(data) == b"\x00" else None)
    link.network.send_message(0, bytes([0x81, 5]))  # reset node
    time.sleep(0.1)
    assert boots, "no boot-up message after NMT reset"
    assert dev.state == "PRE-OPERATIONAL"
    with pytest.raises(LinkTimeout, match="no TPDO reply"):  # PDOs are not processed outside OPERATIONAL
        link.edge({"t_capture_s": 0.001, "sensor": 0, "rising": True, "current_a": 1.0})
    link.network.send_message(0, bytes([0x01, 5]))
    time.sleep(0.02)
    assert link.edge({"t_capture_s": 0.002, "sensor": 0, "rising": True, "current_a": 1.0}) is not None
    link.network.send_message(0, bytes([0x02, 5]))  # stopped: no SDO either
    time.sleep(0.02)
    with pytest.raises(LinkTimeout, match="no SDO answer"):
        link.read(0x1000)


def test_dead_controller_gives_a_precise_error_within_the_timeout(corrections):
    channel = f"co{next(_channels)}"
    dev = CanopenDevice(VirtualController(CONFIG.motor), node_id=7, channel=channel)
    link = CanopenLink(node_id=7, channel=channel, timeout_s=0.3)
    dev.close()
    t = time.monotonic()
    with pytest.raises(LinkTimeout, match="node 7.*within 0.3 s"):
        link.edge({"t_capture_s": 0.001, "sensor": 0, "rising": True, "current_a": 1.0})
    with pytest.raises(LinkTimeout, match="no SDO answer"):
        link.read(0x1000)
    assert time.monotonic() - t < 1.5
    link.close()


# --- robustness: malformed frames ------------------------------------------------------------------

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

FRAMES = st.lists(
    st.tuples(st.sampled_from([0x000, 0x205, 0x605, 0x185, 0x705, 0x085]), st.binary(min_size=0, max_size=8)),
    min_size=100,
    max_size=100,
)


@pytest.fixture(scope="module")
def fuzz_pair():
    channel = f"co{next(_channels)}"
    vc = VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA)
    dev = CanopenDevice(vc, node_id=5, channel=channel)
    link = CanopenLink(node_id=5, channel=channel, timeout_s=1.0)
    errors = []
    import logging

    level = logging.getLogger("canopen").level
    logging.getLogger("canopen").setLevel(
        logging.CRITICAL
    )  # malformed segments are logged by the library, then aborted
    yield vc, dev, link, errors
    logging.getLogger("canopen").setLevel(level)
    link.close()
    dev.close()


@settings(max_examples=100, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(FRAMES)
def _fuzz(fuzz_pair, frames):
    vc, dev, link, _ = fuzz_pair
    for cob, data in frames:
        link.network.send_message(cob, data)
    # no wait for the device to answer the malformed requests: a late answer to one of them
    # names another object and the link's SDO client drops it (MuxCheckedSdoClient)
    link.network.send_message(0, bytes([0x01, 5]))  # malformed traffic may legitimately have stopped or reset it
    time.sleep(0.002)
    # well-formed requests still answered, each with its own content (no stale answer)
    assert link.read(0x1000) == 0x192
    assert link.read(0x1018, 4) == 1
    assert link.read(0x2000) in (0, 1, 2, 3)
    assert isinstance(link.edge({"t_capture_s": 0.001, "sensor": 0, "rising": True, "current_a": 1.0}), list)


def test_ten_thousand_malformed_frames_do_not_break_the_device(fuzz_pair):
    vc, dev, link, _ = fuzz_pair
    _fuzz(fuzz_pair)  # 100 examples x 100 frames
    assert not dev.network.notifier.stopped
    # alive and correct after 10,000 malformed frames: identity, an edge round trip, a download
    assert link.identity()["firmware"] == "vc-0.1.0"
    assert isinstance(link.edge({"t_capture_s": 1e3, "sensor": 1, "rising": True, "current_a": 1.0}), list)


def test_a_late_answer_to_another_request_is_not_taken_for_this_one():
    """canopen 2.4.1 takes the first frame on the response COB-ID; a late abort for another
    object (here 0x2000:01) must neither be raised for a read of 0x1000:00 nor hide its answer."""
    from canopen.sdo.client import SdoClient
    from canopen.sdo.exceptions import SdoAbortedError

    from hil.dut.canopen_link import MuxCheckedSdoClient

    stale_abort = bytes([0x80, 0x00, 0x20, 0x01]) + (0x06020000).to_bytes(4, "little")
    answer = bytes([0x43, 0x00, 0x10, 0x00]) + (0x192).to_bytes(4, "little")
    request = bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])

    class Net:
        def send_message(self, cob_id, data):
            pass

    def client(cls):
        c = cls(0x605, 0x585, None)
        c.network = Net()
        c.RESPONSE_TIMEOUT = 0.2
        c.send_request(request)
        c.responses.put(stale_abort)
        c.responses.put(answer)
        return c

    with pytest.raises(SdoAbortedError):  # the library as it is: the stale abort is raised
        client(SdoClient).read_response()
    assert client(MuxCheckedSdoClient).read_response() == answer
    own_abort = bytes([0x80, 0x00, 0x10, 0x00]) + (0x06010002).to_bytes(4, "little")
    c = client(MuxCheckedSdoClient)
    c.responses = type(c.responses)()
    c.responses.put(own_abort)
    with pytest.raises(SdoAbortedError):  # its own abort still raises
        c.read_response()


def test_each_edge_window_reaches_as_far_as_the_table_and_the_bus_time_counts_every_frame(pair, corrections):
    """hil-edge/3: after a download, an edge carries the conversions back to the table's largest
    delay and two beyond, not the bound's 52; the link counts each frame both ways, and the bus
    time is 135 bits per 8-byte frame (worst-case stuffing) at 1 Mbit/s."""
    from hil.dut.traffic import can_frame_bits

    vc, dev, link = pair
    link.download_calibration(corrections)
    windows = []
    send = link.edge
    link.edge = lambda edge: (windows.append(len(edge["adc_t_s"]) + 1), send(edge))[1]
    b = LockstepBench(CONFIG, link, initial_speed_rpm=6000.0, duty=steady_state(CONFIG.motor, 6000.0)["duty"])
    b.run_setpoints([6000.0], hold_s=0.05, settle_s=0.02)
    reach = max(link.applied_calibration.conditioning_delay_s.values())
    assert 0 < reach < 50e-6 and len(windows) == b.source.edges == link.traffic.edges > 50
    assert max(windows) == math.ceil(reach / ADC_PERIOD_S) + 3  # with the capture's conversion
    t = link.traffic.as_dict()
    assert t["frames_to_device"] == sum(windows) + 4 * len(windows)  # 3 accumulators and the header
    assert len(windows) <= t["frames_from_device"] <= 4 * len(windows)
    assert can_frame_bits(8) == 135
    frames = t["frames_to_device"] + t["frames_from_device"]
    assert t["bytes_to_device"] + t["bytes_from_device"] == 8 * frames
    assert t["bus_time_s"]["can_1mbit"] == pytest.approx(frames * 135e-6, rel=1e-12)
    assert 0 < t["bus_time_s"]["can_fd_5mbit"] < t["bus_time_s"]["can_1mbit"] / 2


def test_the_short_window_gives_the_full_windows_commutations_to_the_bit(corrections, monkeypatch):
    """The controller reads the same two conversions around its delay whatever the window's
    length: the closed loop with the window reaching only as far as the table is the one with
    the bound's full window, commutation for commutation."""
    import hil.bench.lockstep
    from bldc.contract import MAX_CONDITIONING_DELAY_S

    def run():
        link = InProcessLink(VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA, speed_setpoint_rpm=6000.0))
        link.download_calibration(corrections)
        b = LockstepBench(CONFIG, link, initial_speed_rpm=6000.0, duty=steady_state(CONFIG.motor, 6000.0)["duty"])
        b.run_setpoints([6000.0, 6400.0], hold_s=0.1, settle_s=0.05)
        c = b.sim.commutations()
        return c.t_s, c.error_deg_e

    short = run()
    monkeypatch.setattr(hil.bench.lockstep, "adc_reach_s", lambda link: MAX_CONDITIONING_DELAY_S)
    full = run()
    assert short[0].size > 300
    np.testing.assert_array_equal(short[0], full[0])
    np.testing.assert_array_equal(short[1], full[1])
