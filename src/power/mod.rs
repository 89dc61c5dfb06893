//! The paper's linear-in-parameters power model of the 7-joint arm:
//!
//! P_net = Σ_i [a_i τ_i q̇_i + b_i (τ_i² − τ̄0_i²) + c_i |q̇_i| + d_i q̇_i²] + Σ_{i<j} e_ij |q̇_i||q̇_j|
//!
//! Parameter order everywhere (vectors, regressors, model.json): a0..a6, b0..b6, c0..c6,
//! d0..d6, then e_ij for i<j in lexicographic order (e01, e02, …, e56).

use crate::{N_JOINTS, N_PARAMS};

mod model_file;
pub use model_file::{
    DatasetMetrics, DominantTerm, FilterRecord, ModelFile, ModelFileError, ModelMetrics,
    ModelProblem, Provenance, SCHEMA_VERSION, SessionRef, SolverRecord, TrialCounts,
    load_model_for,
};

/// Number of pairwise interaction terms.
pub const N_PAIRS: usize = N_JOINTS * (N_JOINTS - 1) / 2;

/// The joint pairs (i, j), i < j, in parameter order.
pub const PAIRS: [(usize, usize); N_PAIRS] = {
    let mut out = [(0, 0); N_PAIRS];
    let mut k = 0;
    let mut i = 0;
    while i < N_JOINTS {
        let mut j = i + 1;
        while j < N_JOINTS {
            out[k] = (i, j);
            k += 1;
            j += 1;
        }
        i += 1;
    }
    out
};

/// Parameters of the arm power model. Units: a [-], b [W/(Nm)²], c [W·s/rad], d [W·s²/rad²], e [W·s²/rad²].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PowerModel {
    /// Inverse gear efficiency per joint (scales mechanical power τq̇).
    pub a: [f64; N_JOINTS],
    /// Copper-loss coefficient per joint (scales Δτ² = τ² − τ̄0²).
    pub b: [f64; N_JOINTS],
    /// Coulomb-friction coefficient per joint (scales |q̇|).
    pub c: [f64; N_JOINTS],
    /// Viscous-friction coefficient per joint (scales q̇²).
    pub d: [f64; N_JOINTS],
    /// Pairwise interaction coefficients in [`PAIRS`] order (scale |q̇_i||q̇_j|).
    pub e: [f64; N_PAIRS],
}

/// Fill the 49-element regressor φ for one sample: [τq̇ (7), Δτ² (7), |q̇| (7), q̇² (7), |q̇_i||q̇_j| (21)].
/// `tau0_sq` is the per-joint mean squared torque of the trial's static pre-idle window.
#[inline]
pub fn regressor_into(
    tau: &[f64; N_JOINTS],
    dq: &[f64; N_JOINTS],
    tau0_sq: &[f64; N_JOINTS],
    phi: &mut [f64; N_PARAMS],
) {
    for i in 0..N_JOINTS {
        phi[i] = tau[i] * dq[i];
        phi[N_JOINTS + i] = tau[i] * tau[i] - tau0_sq[i];
        phi[2 * N_JOINTS + i] = dq[i].abs();
        phi[3 * N_JOINTS + i] = dq[i] * dq[i];
    }
    for (k, &(i, j)) in PAIRS.iter().enumerate() {
        phi[4 * N_JOINTS + k] = dq[i].abs() * dq[j].abs();
    }
}

impl PowerModel {
    /// The parameters identified in the paper (its Tables "Identified Power Model Parameters"
    /// and "Identified Pairwise Interaction Coefficients").
    pub const PAPER: PowerModel = PowerModel {
        a: [1.0; N_JOINTS],
        b: [0.4184, 0.3563, 0.2799, 0.3942, 0.0000, 0.3768, 0.0000],
        c: [0.0000, 1.2767, 0.0000, 0.0324, 0.0000, 0.3464, 0.0000],
        d: [0.6467, 0.0000, 0.2749, 0.0000, 1.0282, 1.2004, 1.7848],
        // (0,1) (0,2) (0,3) (0,4) (0,5) (0,6) (1,2) (1,3) (1,4) (1,5) (1,6)
        // (2,3) (2,4) (2,5) (2,6) (3,4) (3,5) (3,6) (4,5) (4,6) (5,6)
        e: [
            0.0000, 0.0000, 0.9090, 0.0000, 0.0000, 0.4365, 0.0000, 1.1053, 0.1039, 0.1034, 0.5111,
            0.4054, 0.0554, 0.0050, 0.8613, 0.0000, 0.0000, 0.0591, 0.3417, 0.0000, 0.2936,
        ],
    };

    /// The parameter vector θ in the documented order.
    pub fn to_vector(&self) -> [f64; N_PARAMS] {
        let mut v = [0.0; N_PARAMS];
        v[..N_JOINTS].copy_from_slice(&self.a);
        v[N_JOINTS..2 * N_JOINTS].copy_from_slice(&self.b);
        v[2 * N_JOINTS..3 * N_JOINTS].copy_from_slice(&self.c);
        v[3 * N_JOINTS..4 * N_JOINTS].copy_from_slice(&self.d);
        v[4 * N_JOINTS..].copy_from_slice(&self.e);
        v
    }

    /// Build a model from θ in the documented order.
    pub fn from_vector(v: &[f64; N_PARAMS]) -> Self {
        let mut m = PowerModel {
            a: [0.0; N_JOINTS],
            b: [0.0; N_JOINTS],
            c: [0.0; N_JOINTS],
            d: [0.0; N_JOINTS],
            e: [0.0; N_PAIRS],
        };
        m.a.copy_from_slice(&v[..N_JOINTS]);
        m.b.copy_from_slice(&v[N_JOINTS..2 * N_JOINTS]);
        m.c.copy_from_slice(&v[2 * N_JOINTS..3 * N_JOINTS]);
        m.d.copy_from_slice(&v[3 * N_JOINTS..4 * N_JOINTS]);
        m.e.copy_from_slice(&v[4 * N_JOINTS..]);
        m
    }

    /// Predicted net arm power [W] for one sample. No allocation: cheap enough for an RL reward loop
    /// (`examples/bench_solve.rs` times it and counts heap allocations: none; ~14 M calls/s on one core in
    /// the dev profile, where this crate is built at opt-level 1).
    ///
    /// `tau0_sq` is the per-joint mean squared torque at rest in the reference posture (the trial's
    /// pre-idle window in the paper); pass the squared gravity torques of the home posture when the
    /// episode has no recorded idle window.
    ///
    /// An energy penalty for an RL reward, one call per control step:
    ///
    /// ```
    /// use g1viz::power::PowerModel;
    ///
    /// let model = PowerModel::PAPER; // or ModelFile::load(path)?.model()
    /// let tau0_sq = [4.0, 0.25, 0.1, 1.0, 0.0, 0.01, 0.0]; // (N·m)² at the home posture
    /// let dt = 0.01; // 100 Hz control
    /// let mut energy_j = 0.0;
    /// for step in 0..100 {
    ///     let t = step as f64 * dt;
    ///     let tau = [2.0, 0.5, 0.3, 1.0 + t, 0.0, 0.1, 0.0]; // joint torques [N·m]
    ///     let dq = [0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.2]; // joint speeds [rad/s]
    ///     let watts = model.predict(&tau, &dq, &tau0_sq);
    ///     energy_j += watts * dt;
    ///     let reward_energy_term = -0.01 * watts * dt;
    ///     assert!(reward_energy_term.is_finite());
    /// }
    /// assert!(energy_j > 0.0);
    /// ```
    #[inline]
    pub fn predict(
        &self,
        tau: &[f64; N_JOINTS],
        dq: &[f64; N_JOINTS],
        tau0_sq: &[f64; N_JOINTS],
    ) -> f64 {
        let mut p = 0.0;
        for i in 0..N_JOINTS {
            p += self.a[i] * tau[i] * dq[i]
                + self.b[i] * (tau[i] * tau[i] - tau0_sq[i])
                + self.c[i] * dq[i].abs()
                + self.d[i] * dq[i] * dq[i];
        }
        for (k, &(i, j)) in PAIRS.iter().enumerate() {
            p += self.e[k] * dq[i].abs() * dq[j].abs();
        }
        p
    }
}

/// Joint-level torque constant [Nm/A] of each arm joint's drive (motor torque constant × gear
/// ratio), used to turn joint torque into drive current for current-based loss terms
/// (shared DC-bus loss, drive-electronics loss). Nominal figures for the G1 arm actuators;
/// the simulator's plant and the diagnosis hypotheses both use these so their physical
/// parameters (e.g. bus resistance in Ω) mean the same thing.
pub const JOINT_TORQUE_CONSTANT: [f64; N_JOINTS] = [1.3, 1.3, 1.3, 1.3, 0.7, 0.7, 0.7];

/// Stribeck velocity v_s [rad/s] at the joint output: the speed scale over which breakaway
/// friction decays (excess ∝ exp(−(q̇/v_s)²)). Shared by the simulator's Stribeck effect and
/// the diagnosis hypothesis so the fitted F_s [Nm] means the same thing in both.
pub const STRIBECK_VELOCITY: f64 = 0.1;

/// The model's terms for one sample (or one averaged regressor row), in watts. Sums to the prediction.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TermBreakdown {
    /// Mechanical power a_i τ_i q̇_i per joint.
    pub mechanical: [f64; N_JOINTS],
    /// Copper loss b_i (τ_i² − τ̄0_i²) per joint (negative when the posture needs less holding torque).
    pub copper: [f64; N_JOINTS],
    /// Coulomb friction c_i |q̇_i| per joint.
    pub coulomb: [f64; N_JOINTS],
    /// Viscous friction d_i q̇_i² per joint.
    pub viscous: [f64; N_JOINTS],
    /// Interaction e_ij |q̇_i||q̇_j| per pair, in [`PAIRS`] order.
    pub interaction: [f64; N_PAIRS],
}

/// Names of the five term categories, in the order of [`TermBreakdown::categories`].
pub const TERM_NAMES: [&str; 5] = ["mechanical", "copper", "Coulomb", "viscous", "interaction"];

impl TermBreakdown {
    /// Sum of the interaction terms [W].
    pub fn interaction_total(&self) -> f64 {
        self.interaction.iter().sum()
    }

    /// Per-category totals over joints: [mechanical, copper, Coulomb, viscous, interaction] ([`TERM_NAMES`]).
    pub fn categories(&self) -> [f64; 5] {
        [
            self.mechanical.iter().sum(),
            self.copper.iter().sum(),
            self.coulomb.iter().sum(),
            self.viscous.iter().sum(),
            self.interaction_total(),
        ]
    }

    /// Total predicted net power [W] (equals [`PowerModel::predict`] for the same inputs).
    pub fn total(&self) -> f64 {
        self.categories().iter().sum()
    }
}

/// Running mean of the five term categories over a dataset (samples or trajectory rows).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TermMeans {
    sums: [f64; 5],
    n: usize,
}

impl TermMeans {
    /// Add one breakdown.
    pub fn add(&mut self, b: &TermBreakdown) {
        for (s, v) in self.sums.iter_mut().zip(b.categories()) {
            *s += v;
        }
        self.n += 1;
    }

    /// Number of breakdowns added.
    pub fn count(&self) -> usize {
        self.n
    }

    /// Mean of each category [W] ([`TERM_NAMES`] order); zeros when empty.
    pub fn means(&self) -> [f64; 5] {
        let n = self.n.max(1) as f64;
        self.sums.map(|s| s / n)
    }

    /// Each category's signed share [%] of the energy turnover, the categories' absolute sum
    /// ([`shares_percent`]): the paper's "mean contribution" (copper 42.4 %, viscous 38.2 %, … on
    /// its hold-out set, where every term is positive). A term that returns energy (mechanical
    /// power while braking, copper below the home-posture load) has a negative share.
    pub fn shares_percent(&self) -> [f64; 5] {
        let s = shares_percent(&self.means());
        std::array::from_fn(|k| s[k])
    }
}

/// Each of `parts` as a signed share [%] of the turnover, their absolute sum: within ±100 %
/// even where the parts nearly cancel (a share of the net sum would then run to ±1000 %); where
/// every part is positive, the share of the total. NaN when every part is zero. The one share
/// computation of `identify`'s term shares and the viewer's term and joint shares (per session
/// and per trial).
pub fn shares_percent(parts: &[f64]) -> Vec<f64> {
    let total: f64 = parts.iter().map(|p| p.abs()).sum();
    parts
        .iter()
        .map(|p| {
            if total != 0.0 {
                100.0 * p / total
            } else {
                f64::NAN
            }
        })
        .collect()
}

/// The loss mechanisms the paper ranks per joint (mechanical power is not a loss).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LossTerm {
    /// Copper loss b_i.
    Copper,
    /// Coulomb friction c_i.
    Coulomb,
    /// Viscous friction d_i.
    Viscous,
}

impl LossTerm {
    /// Lower-case name as in the paper's table.
    pub fn name(self) -> &'static str {
        match self {
            LossTerm::Copper => "copper",
            LossTerm::Coulomb => "Coulomb",
            LossTerm::Viscous => "viscous",
        }
    }
}

impl PowerModel {
    /// Per-term breakdown of [`PowerModel::predict`] for one sample. No allocation.
    #[inline]
    pub fn breakdown(
        &self,
        tau: &[f64; N_JOINTS],
        dq: &[f64; N_JOINTS],
        tau0_sq: &[f64; N_JOINTS],
    ) -> TermBreakdown {
        let mut phi = [0.0; N_PARAMS];
        regressor_into(tau, dq, tau0_sq, &mut phi);
        self.breakdown_from_regressor(&phi)
    }

    /// Per-term breakdown of an (averaged) regressor row φ: the model is linear, so the breakdown of a
    /// trajectory's mean regressor is the mean of its per-sample breakdowns.
    #[inline]
    pub fn breakdown_from_regressor(&self, phi: &[f64; N_PARAMS]) -> TermBreakdown {
        let mut out = TermBreakdown::default();
        for i in 0..N_JOINTS {
            out.mechanical[i] = self.a[i] * phi[i];
            out.copper[i] = self.b[i] * phi[N_JOINTS + i];
            out.coulomb[i] = self.c[i] * phi[2 * N_JOINTS + i];
            out.viscous[i] = self.d[i] * phi[3 * N_JOINTS + i];
        }
        for k in 0..N_PAIRS {
            out.interaction[k] = self.e[k] * phi[4 * N_JOINTS + k];
        }
        out
    }

    /// The paper's "dominant term" of a joint: argmax(b_i, c_i, d_i) (first on ties); `None` when all three
    /// are zero (the joint shows no loss in the data).
    pub fn dominant_term(&self, joint: usize) -> Option<LossTerm> {
        let candidates = [
            (LossTerm::Copper, self.b[joint]),
            (LossTerm::Coulomb, self.c[joint]),
            (LossTerm::Viscous, self.d[joint]),
        ];
        let mut best: Option<(LossTerm, f64)> = None;
        for (term, v) in candidates {
            if v > 0.0 && best.is_none_or(|(_, bv)| v > bv) {
                best = Some((term, v));
            }
        }
        best.map(|(t, _)| t)
    }

    /// Name of parameter `p` of θ: `a0`…`a6`, `b0`…, `c0`…, `d0`…, `e01`…`e56`.
    pub fn param_name(p: usize) -> String {
        match p / N_JOINTS {
            0 => format!("a{p}"),
            1 => format!("b{}", p - N_JOINTS),
            2 => format!("c{}", p - 2 * N_JOINTS),
            3 => format!("d{}", p - 3 * N_JOINTS),
            _ => match PAIRS.get(p - 4 * N_JOINTS) {
                Some((i, j)) => format!("e{i}{j}"),
                None => format!("θ{p}"),
            },
        }
    }
}

/// A model file (`model.json`), or `paper` (when no such file exists) for the paper's tabulated
/// parameters.
pub fn load_model(path: &std::path::Path) -> Result<PowerModel, ModelFileError> {
    if path.as_os_str() == "paper" && !path.exists() {
        return Ok(PowerModel::PAPER);
    }
    Ok(ModelFile::load(path)?.model())
}
