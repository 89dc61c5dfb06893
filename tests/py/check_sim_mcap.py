#!/usr/bin/env python3
"""Independent check of a g1viz-simulated MCAP session with the official Python readers
(`mcap` + `mcap-ros2-support`): the file must decode with the schemas it embeds, and a few
fields must hold physically plausible values that agree with the truth sidecar.

Usage: check_sim_mcap.py SESSION.mcap SESSION.truth.json
Exit code 0 = all checks passed; 3 = the python modules are missing; 1 = a check failed
(python itself exits with 2 when it cannot open the script: that must not read as a skip).
"""
import json
import sys

try:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
except ImportError as e:  # the Rust test skips on this exit code
    print(f"missing python module: {e}", file=sys.stderr)
    sys.exit(3)


def main(path, truth_path):
    truth = json.load(open(truth_path))
    failures = []

    def check(cond, what):
        if not cond:
            failures.append(what)

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        check(header.profile == "ros2", f"profile {header.profile!r}")
        summary = reader.get_summary()
        check(summary is not None and summary.statistics is not None, "summary with statistics")
        schemas = {s.name: s for s in summary.schemas.values()}
        for name in ["unitree_hg/msg/LowState", "unitree_hg/msg/LowCmd", "unitree_hg/msg/BmsState",
                     "unitree_hg/msg/MainBoardState"]:
            check(name in schemas and schemas[name].encoding == "ros2msg", f"schema {name}")
        check(len(summary.chunk_indexes) > 0, "chunk indexes")
        check(all(ci.compression == "zstd" for ci in summary.chunk_indexes), "zstd chunks")
        topics = {c.id: c.topic for c in summary.channels.values()}
        stats_counts = {topics[k]: v for k, v in summary.statistics.channel_message_counts.items()}

        counts = {}
        q_lo = [1e9] * 7
        q_hi = [-1e9] * 7
        mbs_idle = []
        bms_all = []
        last_t = {}
        tick_prev = None
        first_traj = min(t["t_traj_start_ns"] for t in truth["trials"]) if truth["trials"] else None
        for schema, channel, message, msg in reader.iter_decoded_messages():
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            check(message.log_time >= last_t.get(topic, 0), f"{topic} time-ordered")
            last_t[topic] = message.log_time
            if topic == "/lowstate":
                check(len(msg.motor_state) == 35, "35 motor slots")
                for i in range(7):
                    q = msg.motor_state[15 + i].q
                    q_lo[i] = min(q_lo[i], q)
                    q_hi[i] = max(q_hi[i], q)
                if tick_prev is not None:
                    check(msg.tick - tick_prev == 10, "tick advances 10 ms")
                tick_prev = msg.tick
                check(msg.motor_state[29].mode == 0, "slot 29 unused")
                w = msg.imu_state.quaternion
                check(abs(sum(v * v for v in w) - 1.0) < 1e-4, "unit quaternion")
            elif topic == "/arm_sdk":
                check(abs(msg.motor_cmd[29].q - 1.0) < 1e-6, "arm_sdk weight 1")
                check(msg.motor_cmd[15].kp == 400.0 and msg.motor_cmd[15].kd == 12.0, "PD gains")
            elif topic == "/lf/mainboardstate":
                v, a = msg.value[0], msg.value[1]
                check(48.0 < v < 54.5, f"MBS voltage {v}")
                if first_traj is not None and message.log_time < first_traj - 500_000_000:
                    mbs_idle.append(v * a)
            elif topic == "/lf/bmsstate":
                bms_all.append(msg.bmsvoltage[0] * msg.current * 1e-6)

    mc = truth["message_counts"]
    for topic, key in [("/lowstate", "lowstate"), ("/arm_sdk", "arm_sdk"), ("/lf/bmsstate", "bms"),
                       ("/lf/mainboardstate", "mbs")]:
        check(counts.get(topic, 0) == mc[key], f"{topic}: {counts.get(topic)} messages, truth {mc[key]}")
        check(stats_counts.get(topic, 0) == mc[key], f"{topic}: statistics count")
    duration = truth["session"]["duration_s"]
    rate = counts.get("/lowstate", 0) / duration
    check(abs(rate - 100.0) < 1.0, f"/lowstate rate {rate:.2f} Hz")
    # Each moved joint covers its waypoints; the ranges must stay inside the URDF limits.
    limits = [(-3.0892, 2.6704), (-1.5882, 2.2515), (-2.618, 2.618), (-1.0472, 2.0944),
              (-1.9722, 1.9722), (-1.6144, 1.6144), (-1.6144, 1.6144)]
    for i in range(7):
        check(limits[i][0] <= q_lo[i] and q_hi[i] <= limits[i][1], f"joint {i} q in URDF limits")
        wps = [w[i] for t in truth["trials"] for w in t["waypoints_rad"]]
        if wps:
            check(abs(min(min(wps), 0.0) - q_lo[i]) < 0.01, f"joint {i} min q {q_lo[i]:.3f} vs waypoints {min(wps):.3f}")
            check(abs(max(max(wps), 0.0) - q_hi[i]) < 0.01, f"joint {i} max q {q_hi[i]:.3f} vs waypoints {max(wps):.3f}")
    if mbs_idle:
        mean = sum(mbs_idle) / len(mbs_idle)
        check(abs(mean - 120.0) < 2.0, f"MBS idle power {mean:.2f} W (expected ≈ 120 W)")
    if bms_all:
        mean = sum(bms_all) / len(bms_all)
        check(125.0 < mean < 160.0, f"BMS mean power {mean:.2f} W (expected ≈ 135 W + motion)")

    if failures:
        for f in failures[:20]:
            print("FAIL:", f)
        sys.exit(1)
    print(f"ok: {counts} mbs_idle={sum(mbs_idle) / max(len(mbs_idle), 1):.2f} W")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
