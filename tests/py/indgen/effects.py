"""Concealed effects: names, physical parameters (chosen a priori from datasheet-like values, not
by trying the tool) and their formulas as written to the truth JSON."""

ALPHA_CU = 0.00393  # 1/K, temperature coefficient of copper resistivity near 20-25 C

EFFECTS = {
    "thermal": {
        # Copper resistance rises 0.393 %/K; the identified b_i is taken as the 25 C value, and the
        # windings run 60-90 C in this plant (warm robot), so b_i is 14-25 % larger than at 25 C.
        "params": {"alpha_per_K": ALPHA_CU, "T_ref_C": 25.0},
        "why": 'Copper resistance rises 0.393 %/K; the identified b_i is taken as the 25 C value, and the windings run 60-90 C in this plant (warm robot), so b_i is 14-25 % larger than at 25 C.',
        "formula": "winding resistance R(T)=R0(1+alpha(Tw-25C)) scales the copper term: "
                   "P_cu,i = b_i(1+alpha(Tw_i-25))tau_i^2, i.e. dP = sum_i b_i alpha (Tw_i-25) tau_i^2 "
                   "(Tw_i = true winding temperature, recorded in temperature[0])",
    },
    "braking": {
        # A BLDC drive regenerating through its inverter returns typically 60-75 % of the shaft
        # power to the bus (copper/switching/diode losses on the way back).
        "params": {"eta": 0.68},
        "why": 'A BLDC drive regenerating through its inverter returns typically 60-75 % of the shaft power to the bus (copper/switching/diode losses on the way back).',
        "formula": "joint electrical power of the mechanical part is eta*tau_i*qd_i when tau_i*qd_i<0 "
                   "(regenerative braking), a_i*tau_i*qd_i otherwise; dP = sum_i (eta-a_i) min(tau_i qd_i, 0)",
    },
    "latency": {
        # Power-monitor ICs + a board MCU + DDS publication: a few hundred ms of pipeline delay.
        "params": {"L_s": 0.3},
        "why": 'Power-monitor ICs + a board MCU + DDS publication: a few hundred ms of pipeline delay.',
        "formula": "MBS reading at t averages rail power over [t-L-W, t-L] instead of [t-W, t] (W = window)",
    },
    "payload": {
        # A 0.5 kg object (a full 0.5 l bottle) held in the Dex3-1 hand at the hand centre.
        "params": {"mass_kg": 0.5, "pos_in_left_wrist_yaw_link_m": [0.12, 0.0, 0.0]},
        "why": 'A 0.5 kg object (a full 0.5 l bottle) held in the Dex3-1 hand at the hand centre.',
        "formula": "point mass m at p in the wrist-yaw (hand) frame added to the hand body of the RNEA; "
                   "true tau (and so tau_est and every tau-dependent power term) includes its weight and "
                   "inertia; the copper term keeps the no-payload home torque in b_i(tau_i^2-tau_home_i^2)",
    },
    "bus_power": {
        # Shared arm supply path: ~1 m twin 20 AWG harness (2 x 33 mOhm) + connectors + fuse + input
        # filter inductor ~ 0.1 Ohm.
        "params": {"R_bus_ohm": 0.1},
        "why": 'Shared arm supply path: ~1 m twin 20 AWG harness (2 x 33 mOhm) + connectors + fuse + input filter inductor ~ 0.1 Ohm.',
        "formula": "dP = R_bus*I_bus^2, I_bus = P_in/V_bus, P_in = sum_i max(P_el,i, 0) where P_el,i = the "
                   "joint's gross electrical input (mechanical term + b_i tau_i^2 + c_i|qd_i| + d_i qd_i^2 + "
                   "half its pair terms + its share of other enabled per-joint effects); V_bus = true bus "
                   "voltage (the recorded vol before noise/quantisation)",
    },
    "electronics_nm": {
        # Conduction/dead-time losses of the inverter scale with |phase current| ~ |tau|/k_t,joint:
        # ~0.7 V effective drop at 1.5-2 Nm/A joint torque constant -> 0.35-0.47 W/Nm.
        "params": {"k_W_per_Nm": 0.4},
        "why": 'Conduction/dead-time losses of the inverter scale with |phase current| ~ |tau|/k_t,joint: ~0.7 V effective drop at 1.5-2 Nm/A joint torque constant -> 0.35-0.47 W/Nm.',
        "formula": "dP = k * sum_i |tau_i| (one k for all joints)",
    },
    "gear_friction": {
        # Harmonic drives lose 10-20 % of the transmitted power in tooth meshing (load dependent).
        "params": {"mu": 0.15},
        "why": 'Harmonic drives lose 10-20 % of the transmitted power in tooth meshing (load dependent).',
        "formula": "dP = mu * sum_i |tau_i|*|qd_i|",
    },
    "grease": {
        # Gear grease base-oil viscosity falls ~2.5 %/K around 40 C (ISO VG 32: 32 cSt at 40 C,
        # 5.4 cSt at 100 C -> ln-slope ~0.03/K); viscous drag is proportional to viscosity.
        "params": {"beta_per_K": 0.025, "T_ref_C": 40.0},
        "why": 'Gear grease base-oil viscosity falls ~2.5 %/K around 40 C (ISO VG 32: 32 cSt at 40 C, 5.4 cSt at 100 C -> ln-slope ~0.03/K); viscous drag is proportional to viscosity.',
        "formula": "viscous term uses the housing temperature Th_i (recorded in temperature[1]): "
                   "d_i qd_i^2 exp(-beta (Th_i - T_ref)); dP = sum_i d_i qd_i^2 (exp(-beta(Th_i-T_ref)) - 1)",
        # The recorded fields the effect follows (for scoring a diagnosis that locates it).
        "fields": [f"/lowstate.motor_state[{k}].temperature[1]" for k in range(15, 22)],
    },
    "rail_load": {
        # Two 12 V 50 mm blowers cooling the main board, 4.5 W each at 5000 rpm; fan affinity law
        # P ~ n^3. Speed steps follow board temperature (fan_state[0], fan_state[1] in MainBoardState).
        "params": {"P_fan_max_W_each": 4.5, "n_max_rpm": 5000.0, "n_fans": 2},
        "why": 'Two 12 V 50 mm blowers cooling the main board, 4.5 W each at 5000 rpm; fan affinity law P ~ n^3. Speed steps follow board temperature (fan_state[0], fan_state[1] in MainBoardState).',
        "formula": "dP = n_fans * P_max * (n/n_max)^3 with n = fan speed level (recorded in "
                   "MainBoardState.fan_state[0] with +-10 rpm noise); levels switch on board "
                   "temperature with hysteresis",
        # Both fans report the level (fan 1 at 0.985 of fan 0's speed).
        "fields": ["/lf/mainboardstate.fan_state[0]", "/lf/mainboardstate.fan_state[1]"],
    },
}
NAMES = list(EFFECTS)
