"""Read a generated session back with the python mcap / mcap_ros2 decoder and compare it with what
the generator meant to write (NAME.expect.json from `generate --expect`) and with NAME.truth.json.

python3 -m indgen check DIR/NAME [--full]   (--full: walk every message for order/sequence/CRC)
"""
import json
import struct
import zlib

import numpy as np


def _close(a, b, tol):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= tol))


def check(base, full=False):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    truth = json.load(open(base + ".truth.json"))
    try:
        exp = json.load(open(base + ".expect.json"))
    except FileNotFoundError:
        exp = None
    problems = []
    notes = []
    f = open(base + ".mcap", "rb")
    r = make_reader(f, decoder_factories=[DecoderFactory()])
    hdr = r.get_header()
    if hdr.profile != "ros2":
        problems.append(f"profile {hdr.profile!r}")
    s = r.get_summary()
    topics = {c.id: c.topic for c in s.channels.values()}
    tid = {v: k for k, v in topics.items()}
    key = {"/lowstate": "lowstate", "/arm_sdk": "arm_sdk", "/lf/bmsstate": "bms", "/lf/mainboardstate": "mbs"}
    for cid, n in s.statistics.channel_message_counts.items():
        if truth["message_counts"][key[topics[cid]]] != n:
            problems.append(f"count {topics[cid]} {n} != truth {truth['message_counts'][key[topics[cid]]]}")
    comp = {ci.compression for ci in s.chunk_indexes}
    if comp != {"zstd"}:
        problems.append(f"chunk compression {comp}")
    if any(not ci.message_index_offsets for ci in s.chunk_indexes):
        problems.append("chunk without message indexes")
    for sc in s.schemas.values():
        if sc.encoding != "ros2msg":
            problems.append(f"schema encoding {sc.encoding}")
    notes.append(f"{s.statistics.message_count} messages, {len(s.chunk_indexes)} zstd chunks, "
                 f"{len(s.schemas)} schemas, channels {sorted(topics.values())}")

    # ---- sampled messages: decode and compare with the expected values ----
    if exp is not None:
        want = {}
        for k, lst in exp.items():
            for e in lst:
                want[(k, e["log_time"])] = e
        times = sorted({t for (_, t) in want})
        # read only around the sampled times (message indexes make this cheap)
        found = 0
        fac_cache = {}
        for t in times:
            for sch, ch, msg, dm in r.iter_decoded_messages(start_time=t, end_time=t + 1):
                k = key[ch.topic]
                e = want.get((k, msg.log_time))
                if e is None:
                    continue
                found += 1
                if msg.sequence != e["sequence"]:
                    problems.append(f"{k} seq {msg.sequence} != {e['sequence']}")
                if msg.publish_time != msg.log_time:
                    problems.append(f"{k} publish_time != log_time")
                if k == "lowstate":
                    ms = dm.motor_state
                    ok = (dm.tick == e["tick"]
                          and _close([ms[i].q for i in range(15, 22)], e["q_arm"], 0)
                          and _close([ms[i].dq for i in range(15, 22)], e["dq_arm"], 0)
                          and _close([ms[i].tau_est for i in range(15, 22)], e["tau_arm"], 0)
                          and _close([list(ms[i].temperature) for i in range(15, 22)], e["temp_arm"], 0)
                          and _close([ms[i].vol for i in range(29)], e["vol"], 0)
                          and _close([m.q for m in ms], e["q_all"], 0)
                          and _close([m.tau_est for m in ms], e["tau_all"], 0)
                          and _close(dm.imu_state.gyroscope, e["gyro"], 0)
                          and _close(dm.imu_state.accelerometer, e["acc"], 0)
                          and _close(dm.imu_state.quaternion, e["quat"], 0)
                          and _close(dm.imu_state.rpy, e["rpy"], 0)
                          and dm.imu_state.temperature == e["imu_temp"] and dm.crc == e["crc"]
                          and all(ms[i].mode == 1 for i in range(29)) and all(ms[i].mode == 0 for i in range(29, 35))
                          and list(dm.version) == [0, 1] and dm.mode_machine == 5)
                    crc_ok = zlib.crc32(msg.data[4:4 + 2084]) == struct.unpack_from("<I", msg.data, 4 + 2084)[0]
                    tr = e["true"]
                    phys = (_close([ms[i].q for i in range(15, 22)], tr["q"], 6e-4)
                            and _close([ms[i].dq for i in range(15, 22)], tr["qd"], 0.025)
                            and _close([ms[i].tau_est for i in range(15, 22)], tr["tau"], 0.4)
                            and _close([ms[i].temperature[0] for i in range(15, 22)], tr["Tw"], 0.5 + 1e-6)
                            and _close([ms[i].temperature[1] for i in range(15, 22)], tr["Th"], 0.5 + 1e-6)
                            and abs(np.mean([ms[i].vol for i in range(29)]) - tr["V_bus"]) < 0.06)
                    if not ok:
                        problems.append(f"lowstate @{msg.log_time}: decoded fields differ from the written values")
                    if not crc_ok:
                        problems.append(f"lowstate @{msg.log_time}: crc")
                    if not phys:
                        problems.append(f"lowstate @{msg.log_time}: recorded values far from the true state")
                elif k == "arm_sdk":
                    mc = dm.motor_cmd
                    ok = (_close([mc[i].q for i in range(15, 22)], e["q_arm"], 0)
                          and _close([mc[i].dq for i in range(15, 22)], e["dq_arm"], 0)
                          and _close([mc[i].q for i in range(15, 22)], e["true_q_cmd"], 1e-6)
                          and all(mc[i].kp == 400 and mc[i].kd == 12 and mc[i].mode == 1 for i in range(15, 22))
                          and mc[29].q == 1.0 and dm.crc == e["crc"]
                          and zlib.crc32(msg.data[4:4 + 996]) == dm.crc)
                    if not ok:
                        problems.append(f"arm_sdk @{msg.log_time}: decoded fields differ")
                elif k == "mbs":
                    ok = (_close(dm.value, e["value"], 0) and _close(dm.fan_state, e["fan_state"], 0)
                          and _close(dm.temperature, e["temperature"], 0))
                    p = dm.value[0] * dm.value[1]
                    # quantisation: 0.01 V x ~2.4 A + 1 mA x 53 V -> < 0.1 W
                    if abs(p - e["true_avg_W"]) > 0.1:
                        problems.append(f"mbs @{msg.log_time}: V*I {p:.3f} vs meant {e['true_avg_W']:.3f} W")
                    if not ok:
                        problems.append(f"mbs @{msg.log_time}: decoded fields differ")
                elif k == "bms":
                    ok = (dm.bmsvoltage[0] == e["bmsvoltage0"] and dm.current == e["current"]
                          and dm.soc == e["soc"] and _close(dm.cell_vol[:13], e["cell_vol"], 0)
                          and _close(dm.temperature[:4], e["temperature"], 0) and dm.version_high == 1)
                    if not ok:
                        problems.append(f"bms @{msg.log_time}: decoded fields differ")
        n_want = len(want)
        notes.append(f"decoded and compared {found}/{n_want} sampled messages "
                     f"({', '.join(f'{k} {len(v)}' for k, v in exp.items())})")
        if found != n_want:
            problems.append(f"found {found} of {n_want} sampled messages")

    # ---- whole file: time order, per-topic sequence, CRCs (raw, no decoding) ----
    if full:
        last_t = -1
        last_seq = {}
        n = 0
        bad_order = 0
        bad_seq = 0
        bad_crc = 0
        for sch, ch, msg in r.iter_messages(log_time_order=False):
            n += 1
            if msg.log_time < last_t:
                bad_order += 1
            last_t = msg.log_time
            sq = last_seq.get(ch.id, -1)
            if msg.sequence != sq + 1:
                bad_seq += 1
            last_seq[ch.id] = msg.sequence
            if ch.topic == "/lowstate" and n % 50 == 1:
                d = msg.data
                if zlib.crc32(d[4:2088]) != struct.unpack_from("<I", d, 2088)[0]:
                    bad_crc += 1
        notes.append(f"full walk: {n} messages in file order, {bad_order} out of time order, "
                     f"{bad_seq} sequence gaps, {bad_crc} bad CRCs (every 50th LowState)")
        if bad_order or bad_seq or bad_crc:
            problems.append("full walk found order/sequence/CRC problems")
    for x in notes:
        print("  " + x)
    for p in problems[:30]:
        print("  PROBLEM " + p)
    print(f"{base}: {'OK' if not problems else f'{len(problems)} problems'}")
    return not problems
