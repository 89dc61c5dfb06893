"""ROS 2 CDR (XCDR1, little endian) layouts of the unitree_hg messages, filled per block in numpy.

Every message here has a fixed size (no unbounded sequences), so a block of N messages is an
(N, record_size) uint8 array; each field is a strided numpy view into it. A record is a complete
MCAP Message record: opcode(1) length(8) channel(2) sequence(4) log_time(8) publish_time(8), then
the 4-byte CDR encapsulation header 00 01 00 00 and the CDR body. Offsets below are body offsets
(CDR alignment is relative to the body start).
"""
import os

import numpy as np

from . import shared_dir

MSG_DIR = os.path.join(shared_dir(), "msg", "unitree_hg")
SCHEMA_NAMES = {
    "LowState": "unitree_hg/msg/LowState",
    "LowCmd": "unitree_hg/msg/LowCmd",
    "BmsState": "unitree_hg/msg/BmsState",
    "MainBoardState": "unitree_hg/msg/MainBoardState",
}
DEPS = {"LowState": ["IMUState", "MotorState"], "LowCmd": ["MotorCmd"], "BmsState": [], "MainBoardState": []}

# body sizes (without the encapsulation header)
LOWSTATE_BODY, LOWCMD_BODY, BMS_BODY, MBS_BODY = 2088, 1000, 164, 72
LOWSTATE_SIZE, LOWCMD_SIZE, BMS_SIZE, MBS_SIZE = (b + 4 for b in (LOWSTATE_BODY, LOWCMD_BODY, BMS_BODY, MBS_BODY))
REC_HDR = 31  # MCAP message record header
ENC = 4       # CDR encapsulation header
BODY0 = REC_HDR + ENC


def _msg_text(name):
    with open(os.path.join(MSG_DIR, name + ".msg")) as f:
        t = f.read()
    return t.rstrip("\n") + "\n"


def schema_text(name):
    """ROS 2 concatenated schema: the type's text, then each dependency after a line of 80 '='."""
    parts = [_msg_text(name)]
    for d in DEPS[name]:
        parts.append("=" * 80 + "\n" + f"MSG: unitree_hg/{d}\n" + _msg_text(d))
    return "".join(parts)


class Block:
    """N records of one or more messages laid out back to back in one row (e.g. a LowState record
    followed by its LowCmd record). `view(base, off, dtype, shape, strides)` returns an (N, *shape)
    writable view of a field at body offset `off` of the message whose record starts at `base`."""

    def __init__(self, n, row_size):
        self.n = n
        self.row = row_size
        # one spare row, so that the strided views of an empty block (a last simulation block too
        # short to hold a 1 Hz reading) still fit their buffer
        self.buf = np.zeros((n + 1, row_size), np.uint8)

    def view(self, base, off, dtype, shape=(), strides=None):
        dt = np.dtype(dtype)
        if strides is None:
            strides = []
            s = dt.itemsize
            for d in reversed(shape):
                strides.insert(0, s)
                s *= d
        return np.ndarray((self.n,) + tuple(shape), dtype=dt, buffer=self.buf,
                          offset=base + BODY0 + off, strides=(self.row,) + tuple(strides))

    def header(self, base, channel_id, body_size, seq, log_ns):
        rec = REC_HDR + ENC + body_size
        b = self.buf
        b[:, base] = 0x05
        np.ndarray((self.n,), "<u8", b, base + 1, (self.row,))[:] = rec - 9
        np.ndarray((self.n,), "<u2", b, base + 9, (self.row,))[:] = channel_id
        np.ndarray((self.n,), "<u4", b, base + 11, (self.row,))[:] = seq
        np.ndarray((self.n,), "<u8", b, base + 15, (self.row,))[:] = log_ns
        np.ndarray((self.n,), "<u8", b, base + 23, (self.row,))[:] = log_ns  # publish = log = sensor time
        b[:, base + REC_HDR + 1] = 0x01  # encapsulation: 00 01 00 00 (CDR little endian)
        return rec


# ---- LowState body layout -------------------------------------------------------------------
# version u32[2] @0; mode_pr u8 @8; mode_machine u8 @9; tick u32 @12; imu: quaternion f32[4] @16,
# gyroscope f32[3] @32, accelerometer f32[3] @44, rpy f32[3] @56, temperature i16 @68;
# motor_state[k]: mode u8 @70 (k=0) / @68+56k (k>=1); q f32 @72+56k, dq +4, ddq +8, tau_est +12,
# temperature i16[2] +16, vol f32 +20, sensor u32[2] +24, motorstate u32 +32, reserve u32[4] +36;
# wireless_remote u8[40] @2028; reserve u32[4] @2068; crc u32 @2084.
def motor_q_off(k):
    return 72 + 56 * k


def motor_mode_off(k):
    return 70 if k == 0 else 68 + 56 * k


class LowStateFields:
    def __init__(self, blk, base):
        v = blk.view
        self.version = v(base, 0, "<u4", (2,))
        self.mode_pr = v(base, 8, "u1")
        self.mode_machine = v(base, 9, "u1")
        self.tick = v(base, 12, "<u4")
        self.quat = v(base, 16, "<f4", (4,))
        self.gyro = v(base, 32, "<f4", (3,))
        self.acc = v(base, 44, "<f4", (3,))
        self.rpy = v(base, 56, "<f4", (3,))
        self.imu_temp = v(base, 68, "<i2")
        q0 = motor_q_off(0)
        self.q = v(base, q0, "<f4", (35,), (56,))
        self.dq = v(base, q0 + 4, "<f4", (35,), (56,))
        self.ddq = v(base, q0 + 8, "<f4", (35,), (56,))
        self.tau = v(base, q0 + 12, "<f4", (35,), (56,))
        self.temp = v(base, q0 + 16, "<i2", (35, 2), (56, 2))
        self.vol = v(base, q0 + 20, "<f4", (35,), (56,))
        self.modes = [v(base, motor_mode_off(k), "u1") for k in range(35)]
        self.crc = v(base, 2084, "<u4")


# ---- LowCmd: mode_pr u8 @0, mode_machine u8 @1, motor_cmd[k]: mode u8 @2 (k=0) / @28k,
# q f32 @4+28k, dq +4, tau +8, kp +12, kd +16, reserve u32 +20; reserve u32[4] @980; crc @996.
class LowCmdFields:
    def __init__(self, blk, base):
        v = blk.view
        self.mode_pr = v(base, 0, "u1")
        self.mode_machine = v(base, 1, "u1")
        self.q = v(base, 4, "<f4", (35,), (28,))
        self.dq = v(base, 8, "<f4", (35,), (28,))
        self.tau = v(base, 12, "<f4", (35,), (28,))
        self.kp = v(base, 16, "<f4", (35,), (28,))
        self.kd = v(base, 20, "<f4", (35,), (28,))
        self.modes = [v(base, 2 if k == 0 else 28 * k, "u1") for k in range(35)]
        self.crc = v(base, 996, "<u4")


# ---- BmsState: version_high u8 @0, version_low @1, fn @2, cell_vol u16[40] @4, bmsvoltage u32[3] @84,
# current i32 @96, soc u8 @100, soh u8 @101, temperature i16[12] @102, cycle u16 @126,
# manufacturer_date u16 @128, bmsstate u32[5] @132, reserve u32[3] @152.
class BmsFields:
    def __init__(self, blk, base):
        v = blk.view
        self.version_high = v(base, 0, "u1")
        self.version_low = v(base, 1, "u1")
        self.fn = v(base, 2, "u1")
        self.cell_vol = v(base, 4, "<u2", (40,))
        self.bmsvoltage = v(base, 84, "<u4", (3,))
        self.current = v(base, 96, "<i4")
        self.soc = v(base, 100, "u1")
        self.soh = v(base, 101, "u1")
        self.temperature = v(base, 102, "<i2", (12,))
        self.cycle = v(base, 126, "<u2")
        self.manufacturer_date = v(base, 128, "<u2")


# ---- MainBoardState: fan_state u16[6] @0, temperature i16[6] @12, value f32[6] @24, state u32[6] @48.
class MbsFields:
    def __init__(self, blk, base):
        v = blk.view
        self.fan_state = v(base, 0, "<u2", (6,))
        self.temperature = v(base, 12, "<i2", (6,))
        self.value = v(base, 24, "<f4", (6,))
        self.state = v(base, 48, "<u4", (6,))


def fill_crc(blk, base, body_size, crc_off):
    """crc field = zlib CRC-32 of the CDR body before the field (README convention)."""
    import zlib
    buf = blk.buf
    row = blk.row
    mv = memoryview(buf.reshape(-1))
    start = base + BODY0
    crcs = np.empty(blk.n, np.uint32)
    c32 = zlib.crc32
    for i in range(blk.n):
        o = i * row + start
        crcs[i] = c32(mv[o:o + crc_off])
    blk.view(base, crc_off, "<u4")[:] = crcs


def record_bytes(blk, base, rec_size):
    """(N, rec_size) uint8 view of one message's records in a block."""
    return blk.buf[:blk.n, base:base + rec_size]


def selftest_messages():
    """One encoded message per type plus the values expected after decoding (for the selftest)."""
    out = {}
    b = Block(1, REC_HDR + LOWSTATE_SIZE)
    b.header(0, 1, LOWSTATE_BODY, 7, 123)
    f = LowStateFields(b, 0)
    f.version[:] = [0, 1]
    f.mode_machine[:] = 5
    f.tick[:] = 4242
    f.quat[:] = [1, 0.1, 0.2, 0.3]
    f.imu_temp[:] = 38
    for k in range(29):
        f.modes[k][:] = 1
    f.q[0, :] = np.arange(35) * 0.1
    f.tau[0, :] = -np.arange(35) * 0.2
    f.temp[0, :, 0] = np.arange(35)
    f.temp[0, :, 1] = -np.arange(35)
    f.vol[0, :29] = 53.5
    fill_crc(b, 0, LOWSTATE_BODY, 2084)
    out["LowState"] = (bytes(b.buf[0, REC_HDR:]), {
        "tick": 4242, "mode_machine": 5, "imu_state.quaternion[1]": 0.1, "imu_state.temperature": 38,
        "motor_state[0].mode": 1, "motor_state[34].mode": 0, "motor_state[17].q": 1.7,
        "motor_state[34].tau_est": -6.8, "motor_state[21].temperature[0]": 21,
        "motor_state[21].temperature[1]": -21, "motor_state[28].vol": 53.5, "version[1]": 1})
    b = Block(1, REC_HDR + LOWCMD_SIZE)
    b.header(0, 2, LOWCMD_BODY, 7, 123)
    f = LowCmdFields(b, 0)
    f.mode_machine[:] = 5
    for k in range(15, 22):
        f.modes[k][:] = 1
    f.q[0, :] = np.arange(35) * 0.01
    f.kp[0, 15:22] = 400
    f.kd[0, 15:22] = 12
    f.q[0, 29] = 1.0
    out["LowCmd"] = (bytes(b.buf[0, REC_HDR:]), {
        "mode_machine": 5, "motor_cmd[0].mode": 0, "motor_cmd[15].mode": 1, "motor_cmd[16].q": 0.16,
        "motor_cmd[21].kp": 400, "motor_cmd[21].kd": 12, "motor_cmd[29].q": 1.0})
    b = Block(1, REC_HDR + BMS_SIZE)
    b.header(0, 3, BMS_BODY, 7, 123)
    f = BmsFields(b, 0)
    f.version_high[:] = 1
    f.cell_vol[0, :13] = 4130 + np.arange(13)
    f.bmsvoltage[0, 0] = 53690
    f.current[:] = -2511
    f.soc[:] = 98
    f.soh[:] = 97
    f.temperature[0, :4] = [28, 29, 27, 28]
    f.cycle[:] = 58
    f.manufacturer_date[:] = 2507
    out["BmsState"] = (bytes(b.buf[0, REC_HDR:]), {
        "version_high": 1, "cell_vol[12]": 4142, "bmsvoltage[0]": 53690, "current": -2511, "soc": 98,
        "soh": 97, "temperature[1]": 29, "cycle": 58, "manufacturer_date": 2507})
    b = Block(1, REC_HDR + MBS_SIZE)
    b.header(0, 4, MBS_BODY, 7, 123)
    f = MbsFields(b, 0)
    f.fan_state[0, :2] = [2100, 2080]
    f.temperature[0, :2] = [39, 36]
    f.value[0, :2] = [53.29, 2.253]
    out["MainBoardState"] = (bytes(b.buf[0, REC_HDR:]), {
        "fan_state[1]": 2080, "temperature[0]": 39, "value[0]": 53.29, "value[1]": 2.253, "state[5]": 0})
    return out
