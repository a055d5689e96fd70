"""The host's control-cycle shortcuts give what the general paths give: the bus's fast read of the Present
block (the reply converted by the plain codec straight from its bytes) against the reader's general path,
and the recorder's row writer (whole blocks of members copied in one step) against `append` of a dict."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from dynamixel_sdk import COMM_SUCCESS
from fakes import FlipCrcByte, OverloadBit

from collect.recorder import SessionRecorder
from crane_io import session_format as sf
from crane_io.dynamixel.codec import PlainCodec
from crane_io.dynamixel.faults import CommunicationError, ServoFaultError
from crane_io.sim import simulated_arm
from crane_io.sim.protocol import fast_status_packet
from tests.sim_bus import capture_writes, open_bus

NAMES = [f"joint{i}" for i in range(1, 8)] + ["gripper"]


@pytest.fixture
def sim():
    arm = simulated_arm()
    yield arm
    arm.close()


def _bus(sim):
    return open_bus(sim)


def _present(current: int, velocity: int, position: int) -> bytes:
    return (current & 0xFFFF).to_bytes(2, "little") + (velocity & 0xFFFFFFFF).to_bytes(4, "little") \
        + (position & 0xFFFFFFFF).to_bytes(4, "little")


EXTREMES = [(-32768, -(2 ** 31), -(2 ** 31)), (32767, 2 ** 31 - 1, 2 ** 31 - 1), (0, 0, 0), (-1, -1, -1),
            (1, 1, 2048), (123, -4567, 4095), (-600, 300, 2047), (5, -5, 1 << 20)]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_state_of_a_fast_reply_equals_the_general_paths(sim, seed):
    """Raw readings from the whole int16/int32 range: the same rad, rad/s and A, bit for bit."""
    rng = np.random.default_rng(seed)
    with _bus(sim) as bus:
        bus.read_state()
        for k in range(20):
            raws = EXTREMES if k == 0 else [
                (int(rng.integers(-32768, 32768)), int(rng.integers(-2 ** 31, 2 ** 31)),
                 int(rng.integers(-2 ** 31, 2 ** 31))) for _ in bus.ids]
            reply = fast_status_packet([(0, sid, _present(*r)) for sid, r in zip(bus.ids, raws)])
            assert len(reply) == 8 + 14 * 8  # not byte-stuffed
            out = np.empty((3, 8))
            assert PlainCodec(bus._ph, 8).present_state(reply, out) is False  # told no expected reply
            codec = PlainCodec(bus._ph, 8)
            bus._reader.use_codec(codec)
            assert codec.present_state(reply, out)
            fast = bus._fast_state(out, 1.5)
            reader = bus._reader
            reader.packet = None  # the general path: the data_dict blocks, unpacked with struct
            for sid, r in zip(bus.ids, raws):
                reader.data_dict[sid] = bytearray(_present(*r))
            reader.errors = dict.fromkeys(bus.ids, 0)
            general = bus._state_from(reader, 1.5, True, True)
            for field in ("position", "velocity", "current"):
                a, b = getattr(fast, field), getattr(general, field)
                assert a.dtype == b.dtype == np.float64 and a.shape == b.shape == (8,)
                assert a.tobytes() == b.tobytes(), field
            assert fast.t == general.t and fast.fast


def test_the_fast_read_takes_the_usual_reply_and_leaves_the_rest_to_the_general_path(sim):
    with _bus(sim) as bus:
        bus.write_goal_current(np.full(8, 0.1))
        first = bus.read_state()  # the first fast read goes the SDK's way and keeps the request
        assert first.fast and bus.stats.fast is True
        reader = bus._reader
        result, reply = reader.fast_read()
        assert result == COMM_SUCCESS and reply is not None and reader.packet is reply
        assert reader.errors == dict.fromkeys(bus.ids, 0) and reader.last_result
        # a reply with a CRC error: the general path's verdict (corrupt), retried by the bus
        with FlipCrcByte(sim.chain, once=True):
            result, reply = reader.fast_read()
        assert result != COMM_SUCCESS and reply is None and reader.packet is None
        retries = bus.stats.retries
        with FlipCrcByte(sim.chain, once=True):
            bus.read_state()
        assert bus.stats.retries == retries + 1
        # a status error byte (the alert bit) is the general path's: ServoFaultError
        with OverloadBit(sim.chain, 5), pytest.raises(ServoFaultError):
            bus.read_state()


def test_a_reader_whose_servos_changed_asks_them_the_sdks_way(sim):
    with _bus(sim) as bus:
        bus.read_state()
        reader = bus._reader
        reader.removeParam(bus.ids[-1])
        result, reply = reader.fast_read()
        assert result == COMM_SUCCESS and reply is None  # the SDK's fastSyncRead, with 7 servos
        assert sorted(reader.errors) == sorted(bus.ids[:-1])
        result, reply = reader.fast_read()
        assert result == COMM_SUCCESS and reply is not None and len(reply) == 8 + 14 * 7


def test_a_failing_fast_read_still_raises_after_the_retries(sim):
    with _bus(sim) as bus:
        bus.read_state()
        with FlipCrcByte(sim.chain), pytest.raises(CommunicationError):
            bus.read_state()
        assert bus.stats.failures == 1


def test_goal_current_limits_follow_a_changed_current_limit(sim):
    with _bus(sim) as bus:
        sent = bus.write_goal_current(np.full(8, 100.0))
        j = bus.current_joints[0]
        assert sent[j] == pytest.approx(bus.current_limits[j], abs=3e-3)
        bus.current_limits[j] = 0.5
        sent = bus.write_goal_current(np.full(8, 100.0))
        assert sent[j] <= 0.5 and sent[j] == pytest.approx(0.5, abs=3e-3)
        assert sent.dtype == np.float64 and sent.shape == (8,)
        assert all(sent[i] == 0.0 for i in bus.position_joints)


# ---- the recorder's row writer ------------------------------------------------------------------------
KEYS = tuple(sf.arm_path(arm, m.name) for arm in sf.ARMS for m in sf.ARM_MEMBERS) + tuple(
    sf.timing_path(m.name) for m in sf.TIMING_MEMBERS)


def _values(rng, k):
    out = []
    for key in KEYS:
        if key.startswith(sf.TIMING):
            out.append(bool(k % 3 == 0) if key.endswith("overrun") else float(rng.normal()))
        elif key.endswith("/t"):
            out.append(k * 0.002)
        else:
            v = rng.normal(size=8)
            v[rng.integers(8)] = np.nan if k % 5 == 0 else v[0]
            out.append(v)
    return out


@pytest.mark.parametrize("lockstep", [True, False])
def test_the_row_writer_writes_the_file_append_writes(tmp_path, lockstep):
    class Clock:
        t = 0.0

        def __call__(self):
            return self.t

    files = {}
    for how in ("append", "writer"):
        clock = Clock()
        rng = np.random.default_rng(7)
        path = tmp_path / f"{how}.h5"
        rec = SessionRecorder(path, joint_names=NAMES, rate_hz=500.0, source="sim", lockstep=lockstep,
                              clock=clock)
        write = rec.row_writer(KEYS)
        for k in range(700):  # whole chunks, and in real time partly filled ones (clock jumps)
            values = _values(rng, k)
            if how == "append":
                rec.append(dict(zip(KEYS, values)))
            else:
                write(values)
            clock.t += 0.002 if k % 100 else 1.0
        rec.close()
        with h5py.File(path, "r") as f:
            files[how] = {key: (f[key].dtype.str, f[key].shape, f[key][()].tobytes()) for key in KEYS}
    assert files["append"] == files["writer"]


def test_the_row_writer_takes_values_a_row_assignment_takes(tmp_path):
    rec = SessionRecorder(tmp_path / "s.h5", joint_names=NAMES, rate_hz=500.0, source="sim", lockstep=True)
    write = rec.row_writer(KEYS)
    values = _values(np.random.default_rng(0), 1)
    values[KEYS.index("leader/tau_res")] = 0.25  # a scalar: broadcast over the row
    values[KEYS.index("follower/q")] = [1.0] * 8  # a list
    write(values)
    assert np.all(rec._buf["leader/tau_res"][0] == np.float32(0.25))
    assert np.all(rec._buf["follower/q"][0] == 1.0)
    values[KEYS.index("leader/dq")] = np.zeros(3)  # a wrong length: the row assignment's error
    with pytest.raises(ValueError):
        write(values)
    rec.close(complete=False)


# ---- the recorder's whole chunks, filtered outside HDF5 ----------------------------------------------
def _raw_chunks(path) -> dict:
    """Every stored chunk of every per-cycle dataset: (filter mask, bytes) by (dataset, first row)."""
    out = {}
    with h5py.File(path, "r") as f:
        for key in KEYS:
            ds = f[key]
            for row in range(0, ds.shape[0], ds.chunks[0]):
                out[key, row] = ds.id.read_direct_chunk((row,) + (0,) * (ds.ndim - 1))
    return out


def _session_rows(path, direct: bool, rows: int = 3 * 250 + 40):
    rec = SessionRecorder(path, joint_names=NAMES, rate_hz=500.0, source="sim", lockstep=True)
    if not rec._direct:  # checked when the recorder was made: another zlib than HDF5's, say
        rec.close(complete=False)
        pytest.skip("chunk_bytes does not give HDF5's bytes here: HDF5 filters every chunk itself")
    rec._direct = direct
    write = rec.row_writer(KEYS)
    rng = np.random.default_rng(3)
    for k in range(rows):
        write(_values(rng, k))
    rec.close()


def test_whole_chunks_are_stored_as_hdf5_stores_them(tmp_path):
    _session_rows(tmp_path / "hdf5.h5", direct=False)
    _session_rows(tmp_path / "here.h5", direct=True)
    ours, theirs = _raw_chunks(tmp_path / "here.h5"), _raw_chunks(tmp_path / "hdf5.h5")
    assert ours.keys() == theirs.keys() and len(ours) == 4 * len(KEYS)
    assert ours == theirs
    assert any(len(data) % 2 for _mask, data in ours.values())  # odd lengths: Fletcher-32's last byte
    with h5py.File(tmp_path / "here.h5", "r") as f:
        assert f["follower/q"].fletcher32 and f["follower/q"].shape == (790, 8)


def test_a_filter_that_does_not_give_hdf5s_bytes_is_not_used(tmp_path, monkeypatch):
    from collect import chunk_filter

    monkeypatch.setattr(chunk_filter, "FILTER_CHECKS", {})
    monkeypatch.setattr(chunk_filter, "chunk_bytes", lambda data: b"not a chunk")
    rec = SessionRecorder(tmp_path / "s.h5", joint_names=NAMES, rate_hz=500.0, source="sim", lockstep=True)
    assert not rec._direct
    write = rec.row_writer(KEYS)
    rng = np.random.default_rng(0)
    for k in range(300):
        write(_values(rng, k))
    rec.close()
    with h5py.File(tmp_path / "s.h5", "r") as f:
        assert f["leader/t"].shape == (300,) and np.array_equal(f["leader/t"][()], np.arange(300) * 0.002)


def test_fletcher32_folds_like_hdf5():
    from crane_io.h5check import fletcher32 as _fletcher32

    assert _fletcher32(b"") == 0 and _fletcher32(b"\x00\x00\x00") == 0
    assert _fletcher32(b"\xff\xff") == (0xFFFF << 16) | 0xFFFF  # 65535: folded to 65535, not 0
    assert _fletcher32(b"\x01\x02\x03") == (((0x0102 + 0x0102 + 0x0300) % 65535) << 16) | (0x0102 + 0x0300)


# ---- the goal writes' CRC from tables --------------------------------------------------------------------
@pytest.mark.parametrize("n", [0, 1, 3, 9, 21, 64])
def test_a_crc_from_tables_equals_the_crc_of_the_whole_packet(n):
    from crane_io.dynamixel.packets import crc16

    rng = np.random.default_rng(n)
    head = bytes((0xFF, 0xFF, 0xFD, 0x00, 0xFE, (n + 7) & 0xFF, 0, 0x83, 102, 0, 2, 0))
    tabled = crc16.fixed_prefix(head, n)
    for _ in range(300):
        params = bytes(rng.integers(0, 256, n, dtype=np.uint8))
        assert tabled(params) == crc16(head + params) == _sdk_crc(head + params)
    assert tabled(bytes(n)) == _sdk_crc(head + bytes(n))
    assert tabled(b"\xff" * n) == _sdk_crc(head + b"\xff" * n)


def _sdk_crc(data: bytes) -> int:
    """dynamixel-sdk's own byte-wise CRC."""
    from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler

    return Protocol2PacketHandler().updateCRC(0, list(data), len(data))


def test_a_sync_write_packet_carries_the_crc_of_its_bytes():
    from crane_io.dynamixel.packets import CranePacketHandler

    ph = CranePacketHandler()
    rng = np.random.default_rng(5)
    for _ in range(200):
        params = [b for sid in (2, 3, 5) for b in (sid, *rng.integers(0, 256, 2).tolist())]
        packet = ph.sync_write_packet(102, 2, params)
        if packet is None:  # needs byte stuffing: the SDK's way
            continue
        body = packet[:-2]
        assert _sdk_crc(body) == packet[-2] | (packet[-1] << 8)


def test_the_goal_position_packet_and_values_are_the_group_sync_writes(sim):
    """The goal position write built directly: the bytes GroupSyncWrite sends and the values of the
    array formulas (units.rad_to_position of np.clip, units.position_to_rad)."""
    from dynamixel_sdk import GroupSyncWrite

    from crane_io.dynamixel import units

    with _bus(sim) as bus:
        sent_packets = capture_writes(bus)
        rng = np.random.default_rng(2)
        for k in range(40):
            rad = rng.uniform(-4, 4, 8)
            if k == 0:
                rad[bus.position_joints[0]] = -0.0
            if k == 1:
                # ties: half to even
                rad[:] = (np.round(rng.uniform(-500, 500, 8)) + 0.5) * units.RAD_PER_PULSE
            sent = bus.write_goal_position(rad)
            ref = GroupSyncWrite(bus._port, bus._ph, 116, 4)
            expect = np.zeros(8)
            for i in bus.position_joints:
                raw = int(units.rad_to_position(np.clip(rad[i], bus.lower[i], bus.upper[i])))
                expect[i] = float(units.position_to_rad(raw))
                ref.addParam(bus.ids[i], list((raw & 0xFFFFFFFF).to_bytes(4, "little")))
            assert ref.txPacket() == COMM_SUCCESS
            assert sent_packets[-2] == sent_packets[-1]
            assert sent.tobytes() == expect.tobytes()


def test_a_chunk_hdf5_refuses_is_written_by_hdf5_and_the_rest_too(tmp_path, monkeypatch):
    from collect import chunk_filter

    rec = SessionRecorder(tmp_path / "s.h5", joint_names=NAMES, rate_hz=500.0, source="sim", lockstep=True)
    if not rec._direct:
        rec.close(complete=False)
        pytest.skip("chunk_bytes does not give HDF5's bytes here: HDF5 filters every chunk itself")
    calls = []
    original = chunk_filter.chunk_bytes

    def refused(data):
        calls.append(1)
        if len(calls) == 30:  # a few datasets into the second chunk
            raise OSError("no direct chunk writes here")
        return original(data)

    monkeypatch.setattr(chunk_filter, "chunk_bytes", refused)
    write = rec.row_writer(KEYS)
    rng = np.random.default_rng(1)
    rows = [_values(rng, k) for k in range(800)]
    for values in rows:
        write(values)
    rec.close()
    assert not rec._direct and len(calls) == 30
    with h5py.File(tmp_path / "s.h5", "r") as f:
        for key in ("leader/q", "follower/tau_res", "timing/period"):
            got = f[key][()]
            expect = np.array([v[KEYS.index(key)] for v in rows], dtype=f[key].dtype)
            assert got.shape[0] == 800 and got.tobytes() == expect.tobytes(), key
