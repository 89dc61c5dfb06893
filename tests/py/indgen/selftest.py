"""Self-checks of the generator's physics and message layout: `python3 -m indgen selftest`."""
import json
import os

import numpy as np

from . import shared_dir
from .dynamics import ArmModel


def check_static(model, rng, n=20):
    """Static torques = gradient of the potential energy (central finite differences)."""
    q = rng.uniform(np.array(model.lower) * 0.8, np.array(model.upper) * 0.8, size=(n, 7))
    tau = model.rnea(q, np.zeros_like(q), np.zeros_like(q))
    h = 1e-6
    grad = np.zeros_like(q)
    for k in range(7):
        dq = np.zeros(7)
        dq[k] = h
        grad[:, k] = (model.potential(q + dq) - model.potential(q - dq)) / (2 * h)
    return float(np.abs(tau - grad).max())


def check_energy(model, rng, T=3.0, dt=1e-4):
    """Power balance over a smooth multi-joint trajectory: integral(tau.qd) dt = dT + dV."""
    t = np.arange(0.0, T + dt / 2, dt)
    A = rng.uniform(0.3, 0.9, 7)
    w = rng.uniform(1.0, 3.0, 7)
    ph = rng.uniform(0, 2 * np.pi, 7)
    q = A * np.sin(w * t[:, None] + ph)
    qd = A * w * np.cos(w * t[:, None] + ph)
    qdd = -A * w * w * np.sin(w * t[:, None] + ph)
    tau = model.rnea(q, qd, qdd)
    p = (tau * qd).sum(1)
    work = np.sum(0.5 * (p[1:] + p[:-1])) * dt
    E = model.kinetic(q[[0, -1]], qd[[0, -1]]) + model.potential(q[[0, -1]])
    dE = E[1] - E[0]
    # also the instantaneous form: d(T+V)/dt = tau.qd at the middle sample
    i = len(t) // 2
    Em = model.kinetic(q[i - 1:i + 2], qd[i - 1:i + 2]) + model.potential(q[i - 1:i + 2])
    dEdt = (Em[2] - Em[0]) / (2 * dt)
    return float(work), float(dE), float(dEdt), float(p[i])


def check_payload(rng):
    """A payload held in the hand adds its weight's moment (static) and nothing when it is 0."""
    m0 = ArmModel()
    m1 = ArmModel(payload_kg=0.5)
    q = np.zeros((1, 7))
    t0 = m0.rnea(q, q, q)[0]
    t1 = m1.rnea(q, q, q)[0]
    # at home the hand centre is below/ahead of the shoulder: the pitch joint carries m*g*x_arm
    Rw, pw = m0.fk_bodies(q)
    pos = pw[0, 6] + Rw[0, 6] @ m1.payload_pos
    axis_w = Rw[0, 0] @ m0.z[0]
    expect = np.cross(pos - pw[0, 0], np.array([0, 0, 0.5 * 9.81])) @ axis_w
    return float(t1[0] - t0[0]), float(expect)


def check_cdr():
    """CDR layouts against the sizes of the shared recordings' messages."""
    from . import cdr
    sizes = {"LowState": cdr.LOWSTATE_SIZE, "LowCmd": cdr.LOWCMD_SIZE, "BmsState": cdr.BMS_SIZE,
             "MainBoardState": cdr.MBS_SIZE}
    return sizes == {"LowState": 2092, "LowCmd": 1004, "BmsState": 168, "MainBoardState": 76}, sizes


def check_cdr_roundtrip():
    """Encode a few messages with indgen.cdr and decode them with mcap_ros2's decoder."""
    try:
        from mcap_ros2.decoder import DecoderFactory
        from mcap.records import Schema
    except ImportError:
        return True, "mcap_ros2 not installed: skipped"
    from . import cdr
    fac = DecoderFactory()
    ok = True
    msgs = cdr.selftest_messages()
    for sid, (name, (data, expect)) in enumerate(msgs.items(), 1):
        sch = Schema(id=sid, name=cdr.SCHEMA_NAMES[name], encoding="ros2msg", data=cdr.schema_text(name).encode())
        dec = fac.decoder_for("cdr", sch)
        m = dec(data)
        for path, val in expect.items():
            obj = m
            for part in path.split("."):
                if "[" in part:
                    nm, ix = part[:-1].split("[")
                    obj = getattr(obj, nm)[int(ix)]
                else:
                    obj = getattr(obj, part)
            if not np.allclose(np.float32(obj), np.float32(val)):
                ok = False
                print("  mismatch", name, path, obj, val)
    return ok, f"{len(msgs)} message types"


def check_bulk_writer():
    """A tiny session: messages read through the chunk/message indexes (seeking reader) equal a
    linear scan of the records (non-seeking reader), are in time order, and their count matches
    the statistics record."""
    import tempfile
    from mcap.reader import NonSeekingReader, SeekingReader
    from .session import generate
    with tempfile.TemporaryDirectory() as d:
        base = os.path.join(d, "tiny")
        generate(base, 99, n_trials=2, effects=["thermal", "rail_load"])
        with open(base + ".mcap", "rb") as f:
            idx = [(c.topic, m.log_time, m.sequence, m.data) for _, c, m in SeekingReader(f).iter_messages()]
        with open(base + ".mcap", "rb") as f:
            lin = [(c.topic, m.log_time, m.sequence, m.data) for _, c, m in NonSeekingReader(f).iter_messages()]
        with open(base + ".mcap", "rb") as f:
            st = SeekingReader(f).get_summary().statistics
    ordered = all(lin[i][1] <= lin[i + 1][1] for i in range(len(lin) - 1))
    return idx == lin and ordered and st.message_count == len(lin), len(lin)


def main():
    rng = np.random.default_rng(0)
    model = ArmModel()
    results = {}
    err = check_static(model, rng)
    results["static_tau_vs_dV_dq_max_abs_Nm"] = err
    ok1 = err < 1e-8  # README: "< 1e-8 Nm"
    work, dE, dEdt, p = check_energy(model, rng)
    results["energy_work_J"] = work
    results["energy_dE_J"] = dE
    results["power_dEdt_W"] = dEdt
    results["power_tau_qd_W"] = p
    ok2 = abs(work - dE) < 1e-4 * max(1.0, abs(dE)) + 1e-4 and abs(dEdt - p) < 1e-3 * max(1.0, abs(p))
    home = model.rnea(np.zeros((1, 7)), np.zeros((1, 7)), np.zeros((1, 7)))[0]
    results["tau_home_Nm"] = home.tolist()
    # the shared truth's home torques (another dynamics code); README: "< 1e-6 Nm"
    with open(os.path.join(shared_dir(), "recordings", "g1_smoke.truth.json")) as f:
        ref = np.array(json.load(f)["plant"]["tau_home_Nm"])
    results["home_vs_shared_truth_max_abs_Nm"] = float(np.abs(home - ref).max())
    ok3 = np.abs(home - ref).max() < 1e-6
    dp, expect = check_payload(rng)
    results["payload_dtau_sh_pitch_Nm"] = dp
    results["payload_expected_Nm"] = expect
    ok4 = abs(dp - expect) < 1e-9 + 1e-9 * abs(expect)
    ok5, sizes = check_cdr()
    ok6, note = check_cdr_roundtrip()
    ok7, nmsg = check_bulk_writer()
    results["bulk_writer_messages"] = nmsg
    results["cdr_sizes"] = sizes
    results["cdr_roundtrip"] = note
    checks = {"static": ok1, "energy": ok2, "home_vs_shared_truth": ok3, "payload": ok4, "cdr_sizes": ok5,
              "cdr_roundtrip": ok6, "mcap_indexes_vs_linear_scan": ok7}
    print(json.dumps(results, indent=1))
    for k, v in checks.items():
        print(f"{k:24s} {'ok' if v else 'FAIL'}")
    if not all(checks.values()):
        raise SystemExit(1)
    print("selftest passed")
