"""The simulated chain's lockstep cycle in three compiled calls: the two packets a control loop
sends an arm every cycle, each handled whole by one call instead of the parser, the chain's handlers and
one compiled call per stage.

- `sync_write_goal`: a Sync Write of Goal Current (or Goal Position), checked (header, length, CRC, no byte
  stuffing, address and size) and written into the servo memories of the servos that hear it (refused
  beyond each one's Current Limit, or outside the position limits in Position mode, as servo_rules refuses
  them, and while its Bus Watchdog has expired), then the lockstep tick: every servo's watchdog, the
  servos' commands (chain_kernel.commands) and, when the plant's compiled kernel takes them as they are,
  the whole plant step (plant_kernel.step_arm) on the plant's packed state;
- `sense`: the plant's reading (chain_kernel.reading, from the noise the plant drew) quantised into every
  servo's Present items (chain_kernel.sensors_into);
- `fast_sync_read`: a Fast Sync Read, checked as above, answered by every addressed servo from its memory
  row (chain_kernel.fast_status).

Each one either does exactly what the general path (crane_io.sim.chain with its Python handlers, the
plant's step_command and read_arrays) does for the packet, or does nothing and says so (-1), and the
general path takes the packet: anything unusual (another instruction or address, a servo that is missing,
has no Fast Sync Read or whose watchdog expired, a read of Indirect Data, a servo in a position mode on an
integrated joint, the servo health model, a stuffed packet) stays there. tests/test_chain_fast.py drives both
with the same packets.

They call the chain_kernel functions (compiled here again) and plant_kernel's compiled step_arm from compiled
code, without numba's per-call argument handling in between, with the same IEEE operations (no fastmath).

Servo state (`sst`, one row per servo, crane_io.sim.servo's columns): last contact time, watchdog expired,
on the bus, answers Fast Sync Read. Plant state (`kst`, crane_io.sim.arm_plant's packed layout): angles,
velocities, motor torques of the integrated joints, then angles, velocities, currents of the held ones.
`klay` (int64): integrated joints n, held joints k, parameter columns, cogging terms, the offsets of geo,
par, cog, scal, hpar in `kpk` (float64), then the integrated joints' servo indices, then the held ones'.
"""

from __future__ import annotations

import numpy as np

from crane_io.dynamixel.control_table import INDIRECT_PER_SET, INDIRECT_SETS, X_SERIES
from crane_io.dynamixel.units import SECONDS_PER_WATCHDOG_LSB
from crane_io.sim import chain_kernel, noise_kernel, plant_kernel
from crane_io.sim.servo import MEMORY_SIZE, S_CONTACT, S_EXPIRED, S_FAST_READ, S_ON_BUS
from crane_io.sim.servo_rules import EXTENDED_GOAL_RANGE

# the X-series addresses (the chain uses these kernels for servos laid out so: chain_paths.fast_layout)
ID_AT, BAUD_AT = X_SERIES["id"].address, X_SERIES["baud_rate"].address
TORQUE_AT, MODE_AT = X_SERIES["torque_enable"].address, X_SERIES["operating_mode"].address
GC_AT, GP_AT = X_SERIES["goal_current"].address, X_SERIES["goal_position"].address
LIMIT_AT, HW_AT = X_SERIES["current_limit"].address, X_SERIES["hardware_error_status"].address
WD_AT, PRESENT_AT = X_SERIES["bus_watchdog"].address, X_SERIES["present_current"].address
TICK_AT, SUPPLY_AT = X_SERIES["realtime_tick"].address, X_SERIES["present_input_voltage"].address
THRESHOLD_AT, SRL_AT = X_SERIES["moving_threshold"].address, X_SERIES["status_return_level"].address
MAX_POS_AT, MIN_POS_AT = X_SERIES["max_position_limit"].address, X_SERIES["min_position_limit"].address
# (crane_io.dynamixel.control_table) the modes whose Goal Position range servo_rules.goal_error checks
MODE_POSITION, MODE_EXTENDED, MODE_CURRENT_BASED = 3, 4, 5
EXTENDED_GOAL = EXTENDED_GOAL_RANGE
INST_SYNC_WRITE, INST_FAST_SYNC_READ = 0x83, 0x8A
L_N, L_K, L_PC, L_NC, L_GEO, L_PAR, L_COG, L_SCAL, L_HPAR, L_PD0, L_IDX = range(11)
# what sync_write_goal and sync_write_read return: nothing done (the general path takes the packet), no servo
# hears it; written and the plant stepped (and, sync_write_read, read into every servo's memory); written, the
# plant not stepped (the caller steps it); sync_write_read: stepped, read into scratch only (the caller sets
# the sensors from it)
DECLINED, UNHEARD, STEPPED, WRITTEN, STEPPED_UNSENSED = -1, 0, 1, 2, 3
_TABLE = chain_kernel.CRC_TABLE_U16
_MEMORY_SIZE = MEMORY_SIZE
# the Indirect Data areas (crane_io.sim.servo_indirect): first address and one past the last
(_k1, _a1, IND1_AT), (_k2, _a2, IND2_AT) = INDIRECT_SETS
IND1_END, IND2_END = IND1_AT + INDIRECT_PER_SET, IND2_AT + INDIRECT_PER_SET
_WD_LSB = SECONDS_PER_WATCHDOG_LSB
_GEO_COLS, _HELD_COLS = plant_kernel.GEO_COLS, plant_kernel.HELD_COLS


def _params_end(pkt, inst, max_length):
    """The end of an unstuffed instruction packet's parameters (they start at 8), when `pkt` is exactly one
    whole packet with the instruction `inst` for the broadcast ID, a LEN the parser accepts, a good CRC and
    no byte stuffing in its parameters; else -1."""
    n = len(pkt)
    if n < 10 or pkt[0] != 0xFF or pkt[1] != 0xFF or pkt[2] != 0xFD or pkt[3] != 0x00:
        return -1
    length = np.int64(pkt[5]) | (np.int64(pkt[6]) << 8)
    if length < 3 or length > max_length or n != 7 + length or pkt[4] != 0xFE or pkt[7] != inst:
        return -1
    crc = np.int64(0)
    for i in range(n - 2):
        crc = chain_kernel_crc_byte(crc, pkt[i], _TABLE)
    if crc != (np.int64(pkt[n - 2]) | (np.int64(pkt[n - 1]) << 8)):
        return -1
    for i in range(8, n - 4):
        if pkt[i] == 0xFF and pkt[i + 1] == 0xFF and pkt[i + 2] == 0xFD:
            return -1
    return n - 2


def _row_of(mem, sst, baud_code, sid):
    """The first servo row that hears the host (on the bus; its Baud Rate code `baud_code`, or any when -1)
    and has the ID `sid`; -1 when none."""
    for r in range(mem.shape[0]):
        if (sst[r, S_ON_BUS] != 0.0 and (baud_code < 0 or mem[r, BAUD_AT] == baud_code)
                and mem[r, ID_AT] == sid):
            return r
    return -1


def _anyone_hears(mem, sst, baud_code):
    for r in range(mem.shape[0]):
        if sst[r, S_ON_BUS] != 0.0 and (baud_code < 0 or mem[r, BAUD_AT] == baud_code):
            return True
    return False


def sync_write_goal(pkt, mem, sst, baud_code, max_length, now, cmds, plant_on, bi_mask, kst, ext, hext,
                       hmat, arm, kpk, klay, h, n_sub, dt):
    """A Sync Write of Goal Current or Goal Position on the lockstep clock at chain time `now` (see the module
    docstring).
    Returns -1: not such a packet, nothing done; 0: no servo hears it, nothing done; 1: written, the plant
    stepped by dt (`plant_on`: the plant's arguments are given; the caller advances the clocks and reads the
    plant); 2: written, the plant not stepped (the caller steps it: a case the plant kernel hands back)."""
    end = _params_end(pkt, INST_SYNC_WRITE, max_length)
    if end < 12:  # four parameter bytes at least
        return -1
    address = np.int64(pkt[8]) | (np.int64(pkt[9]) << 8)
    size = np.int64(pkt[10]) | (np.int64(pkt[11]) << 8)
    if not ((address == GC_AT and size == 2) or (address == GP_AT and size == 4)):
        return -1
    if not _anyone_hears(mem, sst, baud_code):
        return 0
    nb = end - 12
    for k in range(12, 12 + nb - nb % (1 + size), 1 + size):
        r = _row_of(mem, sst, baud_code, pkt[k])
        if r < 0:
            continue
        sst[r, S_CONTACT] = now
        if sst[r, S_EXPIRED] != 0.0:  # refused while the watchdog has expired
            continue
        m = mem[r]
        if size == 2:  # Goal Current: refused beyond +-Current Limit (Data Limit Error)
            value = np.int64(pkt[k + 1]) | (np.int64(pkt[k + 2]) << 8)
            if value & 0x8000:
                value -= 0x10000
            limit = chain_kernel_get_u(m, LIMIT_AT, 2)
            if -limit <= value <= limit:
                chain_kernel_put(m, GC_AT, value, 2)
        else:  # Goal Position: refused outside the position limits in Position mode (Data Limit Error),
            # outside +-EXTENDED_GOAL in the extended position modes (Data Range Error)
            value = (np.int64(pkt[k + 1]) | (np.int64(pkt[k + 2]) << 8) | (np.int64(pkt[k + 3]) << 16)
                     | (np.int64(pkt[k + 4]) << 24))
            if value & 0x80000000:
                value -= 0x100000000
            mode = m[MODE_AT]
            if mode == MODE_POSITION:
                ok = chain_kernel_get_u(m, MIN_POS_AT, 4) <= value <= chain_kernel_get_u(m, MAX_POS_AT, 4)
            elif mode == MODE_EXTENDED or mode == MODE_CURRENT_BASED:
                ok = -EXTENDED_GOAL <= value <= EXTENDED_GOAL
            else:
                ok = True
            if ok:
                chain_kernel_put(m, GP_AT, value & 0xFFFFFFFF, 4)
    # the lockstep tick: the watchdogs at the chain's time, the commands, the plant
    expired = np.int64(0)
    for r in range(mem.shape[0]):
        if sst[r, S_EXPIRED] == 0.0 and mem[r, TORQUE_AT] == 1:
            raw = np.int64(mem[r, WD_AT])
            if 0 < raw < 128 and now - sst[r, S_CONTACT] > raw * _WD_LSB + 1e-9:
                sst[r, S_EXPIRED] = 1.0
        if sst[r, S_EXPIRED] != 0.0:
            expired |= np.int64(1) << r
    mask = chain_kernel_commands(mem, expired, cmds, TORQUE_AT, MODE_AT, GC_AT, GP_AT, LIMIT_AT)
    if not plant_on or mask & bi_mask:
        return WRITTEN
    n, k = klay[L_N], klay[L_K]
    pc, nc = klay[L_PC], klay[L_NC]
    geo = kpk[klay[L_GEO]:klay[L_GEO] + n * _GEO_COLS].reshape((n, _GEO_COLS))
    par = kpk[klay[L_PAR]:klay[L_PAR] + n * pc].reshape((n, pc))
    cog = kpk[klay[L_COG]:klay[L_COG] + nc * 4].reshape((nc, 4))
    scal = kpk[klay[L_SCAL]:klay[L_SCAL] + 6]
    hpar = kpk[klay[L_HPAR]:klay[L_HPAR] + k * _HELD_COLS].reshape((k, _HELD_COLS))
    pd0 = kpk[klay[L_PD0]:klay[L_PD0] + n * 6].reshape((n, 6))
    b = 3 * n
    out = plant_kernel_step_arm(kst[0:n], kst[n:2 * n], kst[b:b + k], kst[b + k:b + 2 * k], cmds, pd0, ext,
                                hext, h, n_sub, dt, hmat, geo, arm, par, cog, scal, hpar)
    for i in range(out.shape[0]):
        kst[i] = out[i]
    return STEPPED


def sense(mem, kst, klay, kt, p, raw, flips, signs, vel_sd, cur_sd, z, volt, temp, tick, scratch):
    """ArmPlant.read_arrays' reading of the packed state `kst` with the noise drawn (`p` .. `z`, as
    read_arrays draws them) into scratch (3, servos) (position, velocity, current), then
    chain_kernel.sensors_into every servo's memory with the Realtime Tick `tick`. Returns sensors_into's
    verdict (False: nothing written)."""
    n, k = klay[L_N], klay[L_K]
    b = 3 * n
    bi = klay[L_IDX:L_IDX + n]
    held = klay[L_IDX + n:L_IDX + n + k]
    pos, vel, cur = chain_kernel_reading(kst[0:n], kst[n:2 * n], kst[2 * n:b], kst[b:b + k],
                                         kst[b + k:b + 2 * k], kst[b + 2 * k:b + 3 * k], bi, held, kt,
                                         mem.shape[0], p, raw, flips, signs, vel_sd, cur_sd, z)
    for i in range(mem.shape[0]):
        scratch[0, i], scratch[1, i], scratch[2, i] = pos[i], vel[i], cur[i]
    return chain_kernel_sensors_into(mem, pos, vel, cur, volt, temp, tick, PRESENT_AT, TICK_AT, SUPPLY_AT,
                                     THRESHOLD_AT)


def sync_write_read(pkt, mem, sst, baud_code, max_length, now, cmds, bi_mask, kst, ext, hext, hmat, arm, kpk,
                    klay, h, n_sub, dt, kt, rngp, p, raw_signs, vel_sd, cur_sd, volt, temp, scratch, work):
    """`sync_write_goal` with the plant's arguments and, when it stepped the plant, the reading at now + dt in
    the same call: the noise drawn from the plant's generator as ArmPlant._noise draws it (noise_kernel.draw:
    the same numbers, the same generator state after), then `sense` with the Realtime Tick of now + dt.
    work: float64, 4 x servos at least (the noise). Returns sync_write_goal's -1, 0 or 2 (nothing read,
    nothing drawn); 1: stepped and read into every servo's memory; 3: stepped and read into scratch[:3] but
    sensors_into wrote nothing (the caller sets the sensors from scratch)."""
    n = mem.shape[0]
    if (work.shape[0] < 4 * n or scratch.shape[0] < 3 or scratch.shape[1] < n or rngp.shape[0] < 4
            or (raw_signs and n % 2 != 0)):
        return -1
    r = sync_write_goal(pkt, mem, sst, baud_code, max_length, now, cmds, True, bi_mask, kst, ext, hext, hmat,
                        arm, kpk, klay, h, n_sub, dt)
    if r != STEPPED:
        return r
    draws = (1 if vel_sd > 0 else 0) + (1 if cur_sd > 0 else 0)
    flips, signs, z = work[0:n], work[n:2 * n], work[2 * n:2 * n + draws * n]
    noise_kernel_draw(rngp, n, p, raw_signs, draws, flips, signs, z)
    t = now + dt  # the chain's time after the step, as the caller advances it
    tick = np.int64(t * 1000.0) % 32768
    raw = np.empty(0, dtype=np.uint64)
    done = sense(mem, kst, klay, kt, p, raw, flips, signs, vel_sd, cur_sd, z, volt, temp, tick, scratch)
    return STEPPED if done else STEPPED_UNSENSED


def fast_sync_read(pkt, mem, sst, baud_code, max_length, now, buf):
    """A Fast Sync Read on the lockstep clock at chain time `now`, answered whole: every addressed servo hears
    it, answers Fast Sync Read and has no expired watchdog (then each one's contact time is `now`), and the
    range lies in the memory. Returns the status packet's length << 16 | its CRC, the packet in buf[:length];
    -1 (nothing done) otherwise, or when buf is too short."""
    end = _params_end(pkt, INST_FAST_SYNC_READ, max_length)
    if end < 13:  # four parameter bytes and one ID at least
        return -1
    address = np.int64(pkt[8]) | (np.int64(pkt[9]) << 8)
    length = np.int64(pkt[10]) | (np.int64(pkt[11]) << 8)
    if length <= 0 or address + length > _MEMORY_SIZE:
        return -1
    stop = address + length
    if (address < IND1_END and IND1_AT < stop) or (address < IND2_END and IND2_AT < stop):
        return -1  # Indirect Data (crane_io.sim.servo_indirect): the general path reads what they stand for
    n_ids = end - 12
    if 8 + n_ids * (2 * (2 + length) + 2) > buf.shape[0]:
        return -1
    rows = np.empty(n_ids, dtype=np.int64)
    ids = np.empty(n_ids, dtype=np.int64)
    for j in range(n_ids):
        sid = pkt[12 + j]
        r = _row_of(mem, sst, baud_code, sid)
        if r < 0 or sst[r, S_FAST_READ] == 0.0 or sst[r, S_EXPIRED] != 0.0 or mem[r, SRL_AT] == 0:
            return -1
        rows[j] = r
        ids[j] = sid
    for j in range(n_ids):
        sst[rows[j], S_CONTACT] = now
    packet, crc = chain_kernel_fast_status(mem, rows, ids, address, length, HW_AT, _TABLE)
    size = packet.shape[0]
    for i in range(size):
        buf[i] = packet[i]
    return (np.int64(size) << 16) | crc


# the chain_kernel and plant_kernel functions these call (compiled in this module's namespace: see compiled())
chain_kernel_crc_byte, chain_kernel_get_u, chain_kernel_put = (chain_kernel._crc_byte, chain_kernel._get_u,
                                                               chain_kernel._put)
chain_kernel_commands, chain_kernel_reading = chain_kernel.commands, chain_kernel.reading
chain_kernel_sensors_into, chain_kernel_fast_status = chain_kernel.sensors_into, chain_kernel.fast_status
plant_kernel_step_arm = plant_kernel.step_arm
noise_kernel_draw = noise_kernel.draw
_ALIASES = ("chain_kernel_crc_byte", "chain_kernel_get_u", "chain_kernel_put", "chain_kernel_commands",
            "chain_kernel_reading", "chain_kernel_sensors_into", "chain_kernel_fast_status",
            "noise_kernel_draw", "plant_kernel_step_arm")
# (the packet: the host's bytes object itself)
_F, _I, _U8, _PKT = "float64[::1]", "int64[::1]", "uint8[::1]", "Bytes(uint8, 1, 'C', readonly=True)"
_M, _S2 = "uint8[:, ::1]", "float64[:, ::1]"
SIGNATURES = {
    "sync_write_goal": (f"({_PKT}, {_M}, {_S2}, int64, int64, float64, {_S2}, boolean, int64, {_F}, "
                           f"{_F}, {_F}, {_F}, {_F}, {_F}, {_I}, float64, int64, float64)",),
    "sense": (f"({_M}, {_F}, {_I}, {_F}, float64, uint64[::1], {_F}, {_F}, float64, float64, {_F}, {_I}, "
              f"{_I}, int64, {_S2})",),
    "fast_sync_read": (f"({_PKT}, {_M}, {_S2}, int64, int64, float64, {_U8})",),
    "sync_write_read": (f"({_PKT}, {_M}, {_S2}, int64, int64, float64, {_S2}, int64, {_F}, {_F}, {_F}, {_F}, "
                        f"{_F}, {_F}, {_I}, float64, int64, float64, {_F}, uint64[::1], float64, boolean, "
                        f"float64, float64, {_I}, {_I}, {_S2}, {_F})",),
}


def compiled():
    """(sync_write_goal, sense, fast_sync_read, sync_write_read) compiled with numba, or None without numba.
    The first call of a process compiles them, or loads them from numba's cache (crane_io.jit)."""
    global _COMPILED
    if _COMPILED is None:
        from crane_io.jit import compile_functions

        # the plant kernel's step_arm as plant_kernel compiled it (its own cache entry: a fresh checkout
        # compiles the dynamics once); the chain kernel's small functions compiled anew, under their own names
        plant = plant_kernel.compiled()
        noise = noise_kernel.namespace()
        ns = dict(vars(chain_kernel))
        ns.update(noise or {})
        ns.update(globals())
        fns = None
        if plant is not None and noise is not None:
            ns["plant_kernel_step_arm"] = plant[0]
            ns["noise_kernel_draw"] = noise["draw"]
            names = ("_quantise", "_put", "_get_u", "_get_s", "_crc_byte", "_frame", *_ALIASES[:-1],
                     "_params_end", "_row_of", "_anyone_hears", "sync_write_goal", "sense", "fast_sync_read",
                     "sync_write_read")
            fns = compile_functions(ns, names, SIGNATURES, qualname_prefix="lockstep_kernel.",
                                    error_model="numpy")
        _COMPILED = False if fns is None else (fns["sync_write_goal"], fns["sense"], fns["fast_sync_read"],
                                               fns["sync_write_read"])
    return _COMPILED or None


_COMPILED = None
