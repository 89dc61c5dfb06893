"""The grammar of concealed physics: a seed draws 0-2 effects (>= 20 % nulls), each a mechanism x
form x field/state x magnitude, and `Physics` adds them to an indgen session through its hook.

Written from physics and the diagnoser's *advertised* mechanism ids (the `hypotheses` list that
`g1viz diagnose --json` prints), not from its formulas. Every effect also carries what a claim
must say to name it (`expect`): library ids of its mechanism, recorded fields it follows, words
of the loss term it changes, or the meter it is an artefact of.

Magnitudes are log-uniform in watts from well below to well above detection, bounded by physics
where a bound is stated: a library mechanism's coefficient is at most the physical limit `LIMITS`
states from the robot's public figures (URDF efforts, torque constants, winding metals, energy),
in this generator's own units; a modulated term changes by at most its own size at the state's
nominal change (`Physics.REL_CAP`, g = 1). Not bounded sample by sample (known, stated): a
power-law library form is bounded on its RMS, not at its peaks; a modulated term's linear or
exponential shape goes past g = 1 where the state moves past its nominal range (u > 1), and below
0 where a state falls (u < 0) — there a state scaling the transmitted power can act as a gain.
"""
import math

import numpy as np

# Library mechanisms the diagnoser advertises (ids as printed in diagnosis.json), grouped where
# two ids are forms of one mechanism.
LIBRARY = {
    "braking": ["braking"], "gear_friction": ["gear_friction"], "electronics": ["electronics_nm", "drive_loss"],
    "bus": ["bus_power", "bus_loss"], "thermal": ["thermal", "thermal_driving"], "stribeck": ["stribeck"],
    "balance_leak": ["balance_leak"], "latency": ["latency"], "payload": ["payload"],
}
# The library's power mechanisms in their linear form, for the oracle's question "could another
# mechanism be it?" (`Physics.rivals`): per joint, or pooled where the mechanism is one term
RIVALS = [("braking", 7), ("gear_friction", 7), ("electronics", 7), ("thermal", 7), ("stribeck", 7),
          ("bus", 1), ("balance_leak", 1)]
N_RIVAL_COLS = sum(n for _, n in RIVALS)
ARM = list(range(15, 22))
Q_RANGE = np.array([[-1.6, 0.8], [0.05, 1.4], [-1.2, 1.2], [-0.6, 1.6], [-1.4, 1.4], [-1.2, 1.2], [-1.2, 1.2]])

# Slow and fast states: name -> (recorded fields, or [] when unrecorded; per joint?). Their
# normalised value u is 0 at the session start and about 1 over a 0.5 h session's change.
STATES = {
    "winding_temp": (lambda j: [f"/lowstate.motor_state[{ARM[j]}].temperature[0]"], True),
    "housing_temp": (lambda j: [f"/lowstate.motor_state[{ARM[j]}].temperature[1]"], True),
    "board_temp": (lambda j: ["/lf/mainboardstate.temperature[0]", "/lf/mainboardstate.temperature[1]"], False),
    "fan": (lambda j: ["/lf/mainboardstate.fan_state[0]", "/lf/mainboardstate.fan_state[1]"], False),
    "soc": (lambda j: ["/lf/bmsstate.soc"], False),
    "pack_temp": (lambda j: [f"/lf/bmsstate.temperature[{k}]" for k in range(4)], False),
    "imu_temp": (lambda j: ["/lowstate.imu_state.temperature"], False),
    "joint_pos": (lambda j: [f"/lowstate.motor_state[{ARM[j]}].q"], True),
    "ambient": (lambda j: [], False),       # not recorded (rises ~1 K/h)
    "hidden_ou": (lambda j: [], False),     # not recorded: humidity-like slow state
    "hidden_mode": (lambda j: [], False),   # not recorded: a mode switching a few times an hour
}
SLOW_STATES = [s for s in STATES if s != "joint_pos"]
TERMS = {  # base loss terms a state may modulate, and words a claim naming them uses
    "copper": ["copper", "τ²", "winding", "resist"],
    "coulomb": ["coulomb", "|q̇|"],
    "viscous": ["viscous", "q̇²"],
    "mech_drive": ["transmitted", "mechanical", "efficien", "driving", "τ·q̇", "τq̇", "gear friction"],
    "mech_brake": ["braking", "regenerat", "transmitted", "mechanical", "efficien"],
}
METER_WORDS = ["meter", "sensor", "artefact", "artifact", "gain", "offset", "calibrat", "window"]
FORMS_SHAPE = ["linear", "power", "exponential", "threshold", "one_sided"]

# The largest size each library mechanism has on a G1 arm: the coefficient of its linear regressor
# (`Physics.library_base`) at its physical limit, from public figures (decided on branch diag24,
# issue 28; docs/diagnosis.md "How large a mechanism can be"). A drawn magnitude [W RMS] above
# LIMITS × the regressor's RMS over the scaling block is drawn again below it (`Physics._cap`);
# per joint, the joint with the largest weight is at most at the limit; a threshold, one-sided or
# switched form's coefficient is the mechanism's own (bounded the same); for a power form the bound
# is on the RMS: it carries no more power than its mechanism's linear form at the limit (its peaks
# may pass it). No coefficient beyond its limit is drawn, so the scorer needs no rule for an
# "implausible" size.
_URDF_EFFORT_NM = [25, 25, 25, 25, 25, 5, 5]   # urdf/g1_left_arm.urdf <limit effort>, shoulder..wrist
_TORQUE_CONST = [1.3, 1.3, 1.3, 1.3, 0.7, 0.7, 0.7]  # joint torque constants [Nm/A], G1 arm nominal
_BUS_V = 13 * 3.7  # 13 Li-ion cells in series at their nominal 3.7 V
LIMITS = {
    # W lost per W regenerated: at most all of it (return fraction r = 0); r < 0 would be a braking
    # path that draws power, which is the copper loss's, not a return's
    "braking": 1.0,
    # W lost per W transmitted: the arm's gears are backdriven (torque control), so their efficiency
    # is above 50 % and the load-dependent loss is below the transmitted power
    "gear_friction": 1.0,
    # W per Nm: a current-proportional drop of at most 5 V (two bridge devices at <= 2.5 V each,
    # an IGBT's saturation voltage at rated current; a MOSFET's drop is resistive: copper-like)
    # over the largest torque constant (every joint must obey it)
    "electronics": 5.0 / max(_TORQUE_CONST),
    # Ohm: a shared path that would drop the whole bus voltage at the arm's peak current
    # (every joint at its URDF effort: sum of effort / K = 127 A) could not supply it
    "bus": _BUS_V / sum(f / k for f, k in zip(_URDF_EFFORT_NM, _TORQUE_CONST)),
    # 1/K: the largest temperature coefficient of a winding metal (aluminium 0.0043; copper
    # 0.00393 at 20 C, IEC 60028), read against the recorded winding temperature
    "thermal": 0.0043,
    # Nm, one breakaway for every joint: above the weakest joint's peak torque (wrist pitch/yaw,
    # URDF effort 5 Nm) that joint could not start moving
    "stribeck": float(min(_URDF_EFFORT_NM)),
    # W/(rad/s)^2: not a physical limit (the legs' balance power has no public figure per sway);
    # ten times the reference twin's 55.6 (indgen CONTAM), the size this mechanism was written for
    "balance_leak": 556.0,
}


def _lu(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def draw_effect(rng):
    """One effect: a dict with kind, mechanism, form, state, magnitude and `expect`."""
    kind = rng.choice(["library", "load", "modulated", "meter"], p=[0.4, 0.2, 0.25, 0.15])
    e = {"kind": str(kind)}
    j = int(rng.integers(7))
    if kind == "library":
        mech = str(rng.choice(list(LIBRARY), p=[0.14, 0.12, 0.14, 0.12, 0.12, 0.1, 0.04, 0.12, 0.1]))
        e["mechanism"] = mech
        if mech == "latency":
            e.update(form="lag", meter="mbs", magnitude=_lu(rng, 0.01, 1.0), unit="s")
        elif mech == "payload":
            e.update(form="point_mass", magnitude=_lu(rng, 0.003, 1.0), unit="kg")
        else:
            form = str(rng.choice(["linear", "power", "threshold", "per_joint", "one_sided", "switched"]))
            e.update(form=form, magnitude=_lu(rng, 0.02, 5.0), unit="W")
            if form == "power":
                e["exponent"] = float(rng.uniform(0.5, 2.0))
            if form == "threshold":
                e["quantile"] = float(rng.uniform(0.3, 0.9))
            if form == "per_joint":
                e["weights"] = rng.uniform(0, 2, 7).round(3).tolist()
            if form == "switched":
                e["state"] = str(rng.choice(SLOW_STATES))
                e["joint"] = j
                e["u0"] = float(rng.uniform(0.2, 0.8))
            if mech == "stribeck":
                e["v_s"] = _lu(rng, 0.03, 0.3)
        e["expect"] = {"ids": LIBRARY[mech], "fields": [], "terms": []}
        if mech == "thermal":  # the copper loss changing with the winding temperatures
            e["expect"].update(fields=[f for k in range(7) for f in STATES["winding_temp"][0](k)],
                               terms=TERMS["copper"])
    elif kind == "load":
        state = str(rng.choice([s for s in STATES if s not in ("ambient", "hidden_ou", "hidden_mode")]))
        e.update(mechanism="rail_load", state=state, joint=j, form=str(rng.choice(FORMS_SHAPE)),
                 magnitude=_lu(rng, 0.03, 5.0) * float(rng.choice([-1, 1], p=[0.3, 0.7])), unit="W")
        _shape_params(rng, e)
        e["expect"] = {"ids": [], "fields": STATES[state][0](j), "terms": []}
    elif kind == "modulated":
        term = str(rng.choice(list(TERMS)))
        state = str(rng.choice(SLOW_STATES))
        e.update(mechanism=f"{term}_x_state", term=term, state=state, joint=j,
                 pooled=bool(rng.random() < 0.5), form=str(rng.choice(FORMS_SHAPE)),
                 magnitude=_lu(rng, 0.03, 5.0) * float(rng.choice([-1, 1])), unit="W")
        # The transmitted power at the session start is already at the plant's efficiency 1 (the
        # paper's a >= 1) and full return: a state can only add a loss to it, never a gain (the
        # sign is set after the draw, so every other draw is unchanged)
        if term in ("mech_drive", "mech_brake"):
            e["magnitude"] = abs(e["magnitude"]) * (1.0 if term == "mech_drive" else -1.0)
        _shape_params(rng, e)
        # the library mechanism that is this term changing: copper with the winding temperature is
        # the thermal drift; a braking loss changing with any state is still the braking asymmetry
        ids = ["thermal"] if (term == "copper" and state == "winding_temp") else []
        ids += ["braking"] if term == "mech_brake" else []
        e["expect"] = {"ids": ids, "fields": STATES[state][0](j), "terms": TERMS[term]}
    else:
        meter = str(rng.choice(["mbs", "bms"]))
        art = str(rng.choice(["gain", "offset", "lag", "window"]))
        e.update(mechanism=f"meter_{art}", meter=meter, artefact=art)
        if art == "gain":
            e.update(form=str(rng.choice(["constant", "drift_time", "follows_board_temp"])),
                     magnitude=_lu(rng, 5e-4, 0.05), unit="relative")
        elif art == "offset":
            e.update(form=str(rng.choice(["step_time", "drift_time", "follows_board_temp"])),
                     magnitude=_lu(rng, 0.03, 5.0), unit="W", u0=float(rng.uniform(0.2, 0.8)))
        elif art == "lag":
            e.update(form="constant", magnitude=_lu(rng, 0.01, 1.0), unit="s")
        else:
            e.update(form="drift_time", magnitude=_lu(rng, 0.01, 0.6), unit="s")
        fields = ["/lf/mainboardstate.temperature[0]", "/lf/mainboardstate.temperature[1]"] \
            if e["form"] == "follows_board_temp" else []
        e["expect"] = {"ids": ["latency"] if (art == "lag" and meter == "mbs") else [], "fields": fields,
                       "terms": [], "meter": meter, "meter_words": METER_WORDS}
    return e


def _shape_params(rng, e):
    if e["form"] == "power":
        e["exponent"] = float(rng.uniform(0.5, 3.0))
    elif e["form"] == "exponential":
        e["rate"] = float(rng.uniform(1.0, 4.0))
    elif e["form"] in ("threshold", "one_sided"):
        e["u0"] = float(rng.uniform(0.2, 0.8))


def draw_session(seed):
    """The concealed physics of session `seed`: a list of 0-2 effects (25 % nulls)."""
    rng = np.random.default_rng([seed, 2801])
    n = int(rng.choice([0, 1, 2], p=[0.25, 0.45, 0.30]))
    effects = [draw_effect(rng) for _ in range(n)]
    if sum(e["mechanism"] == "payload" for e in effects) > 1:
        effects = effects[:1]
    if sum(e["kind"] == "meter" and e["meter"] == "mbs" for e in effects) > 1:
        effects = effects[:1]  # one artefact per meter
    return effects


def shape(form, u, e):
    """g(u) of a form; u ~ 0 at the start, ~1 over the session's change."""
    if form == "linear":
        return u
    if form == "power":
        return np.maximum(u, 0.0) ** e["exponent"]
    if form == "exponential":
        return (np.exp(e["rate"] * u) - 1.0) / (math.exp(e["rate"]) - 1.0)
    if form == "threshold":
        return (u > e["u0"]).astype(float)
    if form == "one_sided":
        return np.maximum(u - e["u0"], 0.0) / max(1e-9, 1.0 - e["u0"])
    raise ValueError(form)


class Physics:
    """indgen hook: adds the drawn effects to the rail (power) or to one meter's readings, and
    keeps, per MBS reading, the window-averaged paper regressors and each effect's true
    contribution for the oracle."""

    W = 0.3  # indgen's reading window

    def __init__(self, effects, seed, duration_s):
        self.effects = effects
        self.seed = seed
        self.rng = np.random.default_rng([seed, 2802])
        self.T = duration_s
        self.coef = [None] * len(effects)
        self.s0 = {}
        self.ou = 0.0
        self.mode = 0
        self.mode_t = []
        self.tail = None
        self.rows = []  # (t, reading, features..., contributions..., window-free remainders...)
        self.rest_cands = {}  # effect -> per block, its remainder beside each candidate window
        self.cur = None
        self.cache = {}
        self.tb_cur = np.zeros(0)
        self.model0 = None
        self.payload_sq = 0.0
        self.payload_n = 0

    # -- states -------------------------------------------------------------------------
    def state(self, name, j, ctx):
        t = ctx["t"]
        if name == "winding_temp":
            s, span = ctx["Tw"][:, j], 15.0
        elif name == "housing_temp":
            s, span = ctx["Th"][:, j], 5.0
        elif name == "board_temp":
            s, span = ctx["Tb"], 6.0
        elif name == "fan":
            return (ctx["fan_rpm"] - 1800.0) / 2400.0
        elif name == "soc":
            s, span = -np.full(len(t), ctx["soc"]), 0.065
        elif name == "pack_temp":
            s, span = np.round(ctx["pack_T"]), 1.0
        elif name == "imu_temp":
            s, span = np.round(ctx["imu_T"]), 1.0
        elif name == "joint_pos":
            lo, hi = Q_RANGE[j]
            return (ctx["q"][:, j] - lo) / (hi - lo)
        elif name == "ambient":
            return t / self.T
        elif name in ("hidden_ou", "hidden_mode"):
            key = (name, float(t[0]))
            if key not in self.cache:
                self.cache[key] = self._ou(t) if name == "hidden_ou" else self._mode(t)
            return self.cache[key]
        else:
            raise ValueError(name)
        key = (name, j)
        if key not in self.s0:
            self.s0[key] = float(s[0])
        return (s - self.s0[key]) / span

    def _ou(self, t):
        out = np.empty(len(t))
        a = math.exp(-0.01 / 600.0)
        w = self.rng.normal(0, math.sqrt(1 - a * a) * 0.5, len(t))
        for i in range(len(t)):
            self.ou = a * self.ou + w[i]
            out[i] = self.ou + 0.5
        return out

    def _mode(self, t):
        out = np.empty(len(t))
        flips = self.rng.random(len(t)) < 0.01 / 400.0
        for i in range(len(t)):
            if flips[i]:
                self.mode ^= 1
                self.mode_t.append(float(t[i]))
            out[i] = self.mode
        return out

    # -- power effects ------------------------------------------------------------------
    def library_base(self, m, e, ctx):
        """A library mechanism's linear regressor (n, 7): its coefficient is the parameter
        `LIMITS` bounds."""
        tau, qd, mech = ctx["tau"], ctx["qd"], ctx["mech"]
        if m == "bus":
            el = ctx["a"] * mech + ctx["b"] * tau * tau + ctx["c"] * np.abs(qd) + ctx["d"] * qd * qd
            return ((np.maximum(el, 0.0).sum(1) / ctx["ocv"]) ** 2)[:, None] * np.ones((1, 7)) / 7.0
        return {"braking": np.maximum(-mech, 0.0), "gear_friction": np.abs(mech), "electronics": np.abs(tau),
                "thermal": ctx["b"] * tau * tau * (ctx["Tw"] - 25.0),
                "stribeck": np.abs(qd) * np.exp(-(qd / e.get("v_s", 0.1)) ** 2),
                "balance_leak": (ctx["sway"] ** 2)[:, None] * np.ones((1, 7)) / 7.0}[m]

    def regressor(self, e, ctx):
        """Per-sample, per-joint (n, 7) or pooled (n,) unscaled contribution of a rail effect."""
        tau, qd, mech = ctx["tau"], ctx["qd"], ctx["mech"]
        m = e.get("mechanism")
        if e["kind"] == "library":
            base = self.library_base(m, e, ctx)
            f = e["form"]
            if f == "power":
                base = base ** e["exponent"]
            elif f == "threshold":
                if "level" not in e:
                    moving = base[base > 1e-6]
                    e["level"] = float(np.quantile(moving, e["quantile"])) if moving.size else 0.0
                base = np.where(base > e["level"], base, 0.0)
            elif f == "per_joint":
                base = base * np.array(e["weights"])
            elif f == "one_sided":
                side = (mech > 0) if m != "braking" else (qd > 0)
                base = np.where(side, base, 0.0)
            elif f == "switched":
                return base * (self.state(e["state"], e["joint"], ctx) > e["u0"])[:, None], base
            return base, base
        if e["kind"] == "load":
            r = shape(e["form"], self.state(e["state"], e["joint"], ctx), e)
            return r, None
        # modulated base loss term
        term = {"copper": ctx["b"] * (tau * tau - ctx["tau_home"] ** 2), "coulomb": ctx["c"] * np.abs(qd),
                "viscous": ctx["d"] * qd * qd, "mech_drive": np.maximum(mech, 0.0),
                "mech_brake": np.minimum(mech, 0.0)}[e["term"]]
        if e["term"] == "copper":
            term = ctx["b"] * tau * tau
        g = shape(e["form"], self.state(e["state"], e["joint"], ctx), e)
        g = g[:, None] if g.ndim == 1 else g
        if not e["pooled"]:
            sel = np.zeros(7)
            sel[e["joint"]] = 1.0
            term = term * sel
        if e["state"] in ("winding_temp", "housing_temp") and e["pooled"]:
            # each joint's own temperature
            g = np.stack([shape(e["form"], self.state(e["state"], k, ctx), e) for k in range(7)], 1)
        return term * g, term

    REL_CAP = 1.0  # a modulated loss term changes by at most 100 % of itself (see `_cap`)

    def _cap(self, i, e, cap):
        """Bound an effect's |magnitude| [W] by `cap`: a modulated term's by REL_CAP × its RMS (its
        relative change at g = 1, the state's nominal range over the session; below 0 a loss would
        turn into a source, and a doubling is the most a slow state does to a loss over a session:
        grease viscosity over ~20 K, copper resistance over ~250 K), a library mechanism's by its
        `LIMITS` × the RMS of its linear regressor. A draw above the cap is drawn again,
        log-uniform over [lo, cap] from its own stream (the truncated log-uniform draw is the same
        distribution), so effects below the cap, and every other draw, are unchanged."""
        if abs(e["magnitude"]) <= cap:
            return
        lo = min(0.03, cap / 10.0)
        r = np.random.default_rng([self.seed, 2803, i])
        e["magnitude_drawn"] = e["magnitude"]
        e["magnitude"] = math.copysign(_lu(r, lo, cap), e["magnitude"])

    def power(self, ctx):
        n = len(ctx["t"])
        total = np.zeros(n)
        contrib = []
        for i, e in enumerate(self.effects):
            c = np.zeros(n)
            if e["kind"] in ("library", "load", "modulated") and e.get("mechanism") not in ("latency", "payload"):
                r, unmod = self.regressor(e, ctx)
                r = r.sum(1) if r.ndim == 2 else r
                if self.coef[i] is None:
                    if unmod is None:
                        self.coef[i] = 1.0
                    else:  # `magnitude` W = the unmodulated term's RMS over the first block
                        # in which it is at least a milliwatt and its joint(s) move: a block
                        # where the joint barely moves would scale the effect by thousands (seed
                        # 2064211334 drained the battery below empty in 15 minutes; in 2004355341
                        # and 769228587 a braking term on a joint that only held in the first
                        # block, 1 mW of sensor noise, made a 4.4 W effect 44 W, and 25,000x)
                        unmod = unmod.sum(1)
                        rms = float(np.sqrt(np.mean(unmod * unmod)))
                        js = [e["joint"]] if e["kind"] == "modulated" and not e["pooled"] else list(range(7))
                        moves = float(np.mean(np.abs(ctx["qd"][:, js]).max(1) > 0.1))
                        if rms > 1e-3 and moves >= 0.05:
                            self.coef[i] = 1.0 / rms
                            if e["kind"] == "modulated":
                                self._cap(i, e, self.REL_CAP * rms)
                            else:  # the mechanism at its physical limit, as RMS watts; per joint,
                                # the joint with the largest weight at it
                                # (a threshold or one-sided form's own coefficient is the
                                # parameter: its RMS at the limit, not the linear form's — 1720811909
                                # drew a one-sided winding drift at α 0.017 1/K under the linear cap)
                                if e["form"] == "per_joint":
                                    lin_rms = rms / max(e["weights"])
                                elif e["form"] == "power":
                                    lin = self.library_base(e["mechanism"], e, ctx).sum(1)
                                    lin_rms = float(np.sqrt(np.mean(lin * lin)))
                                else:
                                    lin_rms = rms
                                e["limit_W"] = LIMITS[e["mechanism"]] * lin_rms
                                self._cap(i, e, e["limit_W"])
                            e["coef_W_per_unit"] = self.coef[i] * e["magnitude"]
                c = e["magnitude"] * (self.coef[i] or 0.0) * r
                total += c
            elif e.get("mechanism") == "payload":
                # indgen's own payload (inside its RNEA): recorded τ carries it, so the power
                # regressors do too; it shows at the torque level (see `payload_torque_rms`)
                self._payload_torque(ctx)
            contrib.append(c)
        # paper regressors (true states) for the oracle
        tau, qd = ctx["tau"], ctx["qd"]
        aq = np.abs(qd)
        pairs = [aq[:, i] * aq[:, k] for i in range(7) for k in range(i + 1, 7)]
        F = np.column_stack([tau * qd, tau * tau - ctx["tau_home"] ** 2, aq, qd * qd] + pairs + contrib
                            + [self.rivals(ctx)])
        self.cur = (ctx["t"], F)
        self.tb_cur = ctx["Tb"]
        self.cache = {}
        return total

    def rivals(self, ctx):
        """(n, N_RIVAL_COLS): every power mechanism of the library in its linear form (`RIVALS`),
        per joint or pooled — what a diagnoser could name instead of an effect."""
        cols = []
        for m, n in RIVALS:
            base = self.library_base(m, {}, ctx)
            cols.append(base if n == 7 else base.sum(1, keepdims=True))
        return np.hstack(cols)

    def _payload_torque(self, ctx):
        from indgen.dynamics import ArmModel
        from indgen.session import PLANT
        if self.model0 is None:
            self.model0 = ArmModel()
        fr = PLANT["joint_friction_in_tau"]
        qd = ctx["qd"]
        nominal = self.model0.rnea(ctx["q"], qd, ctx["qdd"]) + np.array(fr["coulomb_Nm"]) * np.tanh(qd / 0.01) \
            + np.array(fr["viscous_Nms"]) * qd
        dt = ctx["tau"] - nominal
        self.payload_sq += float((dt * dt).sum())
        self.payload_n += dt.size

    def payload_detectability(self):
        """Torque-level gain of knowing the payload: 1 - σ/√(σ² + mean Δτ²), σ = the recorded
        torque noise (indgen's 0.06 Nm per sample)."""
        from indgen.session import PLANT
        s = PLANT["noise"]["tau_Nm"]
        ms = self.payload_sq / max(self.payload_n, 1)
        return 1.0 - s / math.sqrt(s * s + ms), math.sqrt(ms)

    # -- meters ---------------------------------------------------------------------------
    def meter(self, mt, bt, avg, p_mbs, p_bms):
        out = {"mbs": p_mbs.copy(), "bms": p_bms.copy()}
        meter_c = np.zeros((len(mt), len(self.effects)))
        # What a lag leaves beside the best window read at no lag, and a window drift beside the
        # best steady window (`table`): the window is estimated from the data, so only this
        # remainder tells a lag from a longer window, or a drift from a steady one
        lag_rest = {}
        for i, e in enumerate(self.effects):
            if e.get("mechanism") == "latency":
                e = dict(e, meter="mbs", artefact="lag")
            elif e["kind"] != "meter":
                continue
            ts = mt if e["meter"] == "mbs" else bt
            clean = avg(e["meter"], ts, 0.0, self.W)
            u_t = ts / self.T
            art, f = e["artefact"], e["form"]
            if art == "gain":
                g = {"constant": np.ones(len(ts)), "drift_time": u_t,
                     "follows_board_temp": self._board_u(ts)}[f]
                new = clean * (1.0 + e["magnitude"] * g)
            elif art == "offset":
                g = {"step_time": (u_t > e["u0"]).astype(float), "drift_time": u_t,
                     "follows_board_temp": self._board_u(ts)}[f]
                new = clean + e["magnitude"] * g
            elif art == "lag":
                new = avg(e["meter"], ts, e["magnitude"], self.W)
                if e["meter"] == "mbs":
                    lag_rest[i] = [new - avg("mbs", ts, 0.0, w) for w in self._lag0_windows(e)]
            else:
                new = avg(e["meter"], ts, 0.0, self.W + e["magnitude"] * u_t)
                if e["meter"] == "mbs":
                    lag_rest[i] = [new - avg("mbs", ts, 0.0, w) for w in self._steady_windows(e)]
            out[e["meter"]] = out[e["meter"]] + (new - clean)
            if e["meter"] == "mbs":
                meter_c[:, i] = new - clean
        self._rows(mt, out["mbs"], meter_c, lag_rest)
        return out["mbs"], out["bms"]

    def _board_u(self, ts):
        # the board temperature at each reading, from the last block's 100 Hz values
        t, _ = self.cur
        tb = np.interp(ts, t, self.tb_cur) if len(t) else np.zeros(len(ts))
        if "board" not in self.s0:
            self.s0["board"] = float(tb[0]) if len(tb) else 0.0
        return (tb - self.s0["board"]) / 6.0

    STEPS = np.arange(-6, 7) * 0.01  # candidate windows around the nominal rival [s] (indgen's DT)

    def _lag0_windows(self, e):
        """Windows at no lag around the one of a lag's centre (W + 2·lag; ≤ 1.9 s: indgen keeps a
        2 s tail)."""
        return np.clip(self.W + 2.0 * e["magnitude"] + self.STEPS, 0.01, 1.9)

    def _steady_windows(self, e):
        """Steady windows around a drifting window's session mean."""
        return np.clip(self.W + 0.5 * e["magnitude"] + self.STEPS, 0.01, 1.9)

    def _rows(self, mt, reading, meter_c, lag_rest):
        t, F = self.cur
        if self.tail is not None:
            t = np.concatenate([self.tail[0], t])
            F = np.concatenate([self.tail[1], F])
        cs = np.vstack([np.zeros((1, F.shape[1])), np.cumsum(F, 0)])
        i1 = np.searchsorted(t, mt, side="right")
        i0 = np.minimum(np.searchsorted(t, mt - self.W, side="right"), i1 - 1)
        Fw = (cs[i1] - cs[i0]) / (i1 - i0)[:, None]
        k = len(self.effects)
        if k:
            Fw[:, 49:49 + k] += meter_c
        self.rows.append(np.column_stack([mt, reading, Fw, Fw[:, 49:49 + k]]))
        for i, cands in lag_rest.items():
            self.rest_cands.setdefault(i, []).append(np.column_stack(cands))
        self.tail = (t[-200:], F[-200:])

    def table(self):
        """(n_readings, 2 + 49 + k + N_RIVAL_COLS + k): time [s], MBS reading [W], paper
        regressors, effect contributions, the library's mechanisms in linear form (`rivals`), and
        what of each contribution a sensor window estimated from the data cannot absorb (a
        main-board lag's remainder beside the best window at no lag, a window drift's beside the
        best steady window; the contribution itself for every other effect)."""
        k = len(self.effects)
        if not self.rows:
            return np.zeros((0, 51 + 2 * k + N_RIVAL_COLS))
        table = np.vstack(self.rows)
        for i, blocks in self.rest_cands.items():
            # the session's best window: the least remainder over every reading
            c = np.vstack(blocks)
            table[:, 51 + k + N_RIVAL_COLS + i] = c[:, int(np.argmin((c * c).sum(0)))]
        return table
