//! Trial segmentation from the data alone (no markers, no truth file).
//!
//! The paper's protocol repeats: pre-idle at home (q = 0) → trajectory (smooth-step segments,
//! possibly with short dwells) → post-idle (constant posture, 2 s) → return home. The
//! segmenter classifies every sample of a *reference* stream as idle or moving — the `/arm_sdk`
//! command stream when present (idle = constant command), otherwise the measured `/lowstate`
//! joint velocities (idle = smoothed speed below a noise-scaled threshold) — groups the samples
//! into runs, and matches the run pattern `home-idle, motion, posture-idle, motion, home-idle`.
//! Every stretch that does not fit (session starting or ending mid-trial, a motion that never
//! settles, a too-short pre-idle, …) is reported in [`Segmentation::unmatched`] with a reason.
//!
//! With the command stream, motion on- and offsets are located to well below one sample period:
//! near a smooth-step boundary the displacement grows quadratically in time, so two samples fix
//! the instant the reference left (or reached) its idle value.

use super::TrialWindow;
use crate::N_JOINTS;
use crate::signals::Recording;

/// Which stream the segmenter reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum SegmentSource {
    /// The command stream when the session has one, otherwise the measured joint states.
    Auto,
    /// The `/arm_sdk` command stream (idle = constant command).
    Command,
    /// The measured `/lowstate` joint velocities and positions.
    State,
}

/// Tuning of the segmenter. Defaults follow the paper's protocol.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct SegmentOptions {
    /// Stream to segment.
    pub source: SegmentSource,
    /// Nominal pre-idle duration [s]: the pre-idle window is the last `pre_idle_s` of the home idle.
    pub pre_idle_s: f64,
    /// Shortest home idle accepted as a pre-idle [s] (a baseline needs at least one power reading).
    pub min_pre_idle_s: f64,
    /// Shortest constant posture accepted as the post-idle [s]; shorter ones are dwells inside the trajectory.
    pub min_post_idle_s: f64,
    /// A posture is "home" when every joint is within this distance of 0 [rad].
    pub home_tol_rad: f64,
    /// A joint "moved" when its reference spans more than this over the trajectory [rad].
    pub moved_tol_rad: f64,
    /// Measured-state source only: speed threshold floor [rad/s] (raised automatically for noisy data).
    pub state_speed_threshold: f64,
}

impl Default for SegmentOptions {
    fn default() -> Self {
        SegmentOptions {
            source: SegmentSource::Auto,
            pre_idle_s: 2.0,
            min_pre_idle_s: 1.0,
            min_post_idle_s: 1.5,
            home_tol_rad: 0.02,
            moved_tol_rad: 0.02,
            state_speed_threshold: 0.02,
        }
    }
}

/// A stretch of the session that does not fit the protocol.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Stretch {
    /// Start [s].
    pub t0: f64,
    /// End [s].
    pub t1: f64,
    /// Why it was not accepted as a trial.
    pub reason: String,
}

/// Result of [`segment`].
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct Segmentation {
    /// Trials in time order.
    pub trials: Vec<TrialWindow>,
    /// Stretches with motion that are not trials, each with a reason.
    pub unmatched: Vec<Stretch>,
    /// The stream that was segmented ("command" or "state"; empty when the session has no samples).
    pub source: String,
}

/// Idle or moving run of consecutive reference samples.
#[derive(Debug, Clone, Copy)]
struct Run {
    moving: bool,
    /// Boundary times (refined for idle/moving transitions).
    t0: f64,
    t1: f64,
    /// Sample index range [i0, i1] (inclusive).
    i0: usize,
    i1: usize,
    /// Idle runs only: every joint within the home tolerance.
    home: bool,
}

impl Run {
    fn duration(&self) -> f64 {
        self.t1 - self.t0
    }
}

/// The reference stream the runs are built from.
struct Reference<'a> {
    t: &'a [f64],
    q: &'a [[f64; N_JOINTS]],
    moving: Vec<bool>,
    /// Sub-sample boundary location is possible (exact, noise-free reference).
    exact: bool,
}

/// Split a session into protocol trials. Never fails: a session without a single trial gives an
/// empty `trials` and the reasons in `unmatched`.
pub fn segment(rec: &Recording, opts: &SegmentOptions) -> Segmentation {
    let use_command = match opts.source {
        SegmentSource::Command => true,
        SegmentSource::State => false,
        SegmentSource::Auto => rec.command.t.len() >= 2,
    };
    let reference = if use_command {
        command_reference(rec)
    } else {
        state_reference(rec, opts)
    };
    let source = if use_command { "command" } else { "state" };
    if reference.t.len() < 2 {
        let mut seg = Segmentation {
            source: source.into(),
            ..Default::default()
        };
        if !reference.t.is_empty() || !rec.state.t.is_empty() {
            seg.unmatched.push(Stretch {
                t0: 0.0,
                t1: 0.0,
                reason: format!("too few {source} samples to segment"),
            });
        }
        return seg;
    }
    let runs = merge_runs(build_runs(&reference, opts), opts);
    let mut seg = match_trials(&runs, opts);
    seg.source = source.into();
    for trial in &mut seg.trials {
        describe_trial(rec, &reference, trial, opts);
    }
    seg
}

fn command_reference(rec: &Recording) -> Reference<'_> {
    let c = &rec.command;
    let n = c.t.len().min(c.q.len());
    // A float32 command at rest repeats exactly; the first sample of a smooth step already moves
    // by ~1e-5 rad, far above float32 rounding (~1e-7 rad), so 1e-3 rad/s separates the two.
    const SPEED_EPS: f64 = 1e-3;
    let step = |k: usize| {
        let dt = (c.t[k] - c.t[k - 1]).max(1e-6);
        (0..N_JOINTS).fold(0.0f64, |m, j| m.max((c.q[k][j] - c.q[k - 1][j]).abs())) / dt
    };
    // A sample moves when its velocity command is non-zero or it differs from both neighbours
    // (a sample equal to the next one is where the reference came to rest, even if it differs
    // from the previous one; at a waypoint junction both differences are non-zero).
    let moving = (0..n)
        .map(|k| {
            let dq_cmd =
                c.dq.get(k)
                    .map_or(0.0, |d| d.iter().fold(0.0f64, |m, v| m.max(v.abs())));
            let before = k == 0 || step(k) > SPEED_EPS;
            let after = k + 1 == n || step(k + 1) > SPEED_EPS;
            dq_cmd > SPEED_EPS || (before && after && n > 1)
        })
        .collect();
    Reference {
        t: &c.t[..n],
        q: &c.q[..n],
        moving,
        exact: true,
    }
}

fn state_reference<'a>(rec: &'a Recording, opts: &SegmentOptions) -> Reference<'a> {
    let s = &rec.state;
    let n = s.t.len().min(s.q.len()).min(s.dq.len());
    // Peak joint speed smoothed over 7 samples (±30 ms at 100 Hz).
    const HALF: usize = 3;
    let speed: Vec<f64> = (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(HALF), (k + HALF).min(n - 1));
            (0..N_JOINTS)
                .map(|j| (a..=b).map(|m| s.dq[m][j]).sum::<f64>().abs() / (b - a + 1) as f64)
                .fold(0.0, f64::max)
        })
        .collect();
    // Velocity noise σ from sample-to-sample differences (robust: median |Δq̇| / (0.6745·√2));
    // at any instant most joints are still, so the median sees noise, not motion. 8σ of the
    // 7-sample mean keeps idle stretches idle on noisier robots than the floor assumes.
    let mut diffs: Vec<f64> = (1..n)
        .flat_map(|k| (0..N_JOINTS).map(move |j| (s.dq[k][j] - s.dq[k - 1][j]).abs()))
        .collect();
    diffs.sort_by(f64::total_cmp);
    let sigma =
        diffs.get(diffs.len() / 2).copied().unwrap_or(0.0) / (0.6745 * std::f64::consts::SQRT_2);
    let threshold = opts
        .state_speed_threshold
        .max(8.0 * sigma / (2.0 * HALF as f64 + 1.0).sqrt());
    let moving = speed.iter().map(|&v| v > threshold).collect();
    Reference {
        t: &s.t[..n],
        q: &s.q[..n],
        moving,
        exact: false,
    }
}

fn dist(a: &[f64; N_JOINTS], b: &[f64; N_JOINTS]) -> f64 {
    (0..N_JOINTS)
        .map(|j| (a[j] - b[j]).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Instant the reference leaves or reaches `rest` between the moving sample `k` and its
/// neighbour `rest_at` (k − 1 at an onset, k + 1 at an offset), from `k` and the next moving
/// sample beyond it: near a smooth step's end the displacement is A·(t − t0)², so √d is
/// linear in t.
fn refine(r: &Reference, k: usize, rest_at: usize, rest: &[f64; N_JOINTS]) -> f64 {
    let mid = 0.5 * (r.t[rest_at] + r.t[k]);
    let far = (2 * k).wrapping_sub(rest_at);
    if !r.exact || far >= r.t.len() {
        return mid;
    }
    let (s1, s2) = (dist(&r.q[k], rest).sqrt(), dist(&r.q[far], rest).sqrt());
    if s2 <= s1 || !s1.is_finite() || !s2.is_finite() {
        return mid;
    }
    let t = r.t[k] - s1 * (r.t[far] - r.t[k]) / (s2 - s1);
    t.clamp(r.t[k].min(r.t[rest_at]), r.t[k].max(r.t[rest_at]))
}

fn mean_posture(q: &[[f64; N_JOINTS]]) -> [f64; N_JOINTS] {
    let mut m = [0.0; N_JOINTS];
    for row in q {
        for j in 0..N_JOINTS {
            m[j] += row[j];
        }
    }
    m.map(|v| v / q.len().max(1) as f64)
}

fn build_runs(r: &Reference, opts: &SegmentOptions) -> Vec<Run> {
    let n = r.t.len();
    let mut runs: Vec<Run> = Vec::new();
    let mut start = 0;
    for k in 1..=n {
        if k == n || r.moving[k] != r.moving[start] {
            runs.push(Run {
                moving: r.moving[start],
                t0: r.t[start],
                t1: r.t[k - 1],
                i0: start,
                i1: k - 1,
                home: false,
            });
            start = k;
        }
    }
    // Boundaries between runs: located from the idle side's posture.
    for w in 0..runs.len().saturating_sub(1) {
        let (a, b) = (runs[w], runs[w + 1]);
        let t = if a.moving {
            let rest = mean_posture(&r.q[b.i0..=b.i1]);
            refine(r, a.i1, b.i0, &rest)
        } else {
            let rest = mean_posture(&r.q[a.i0..=a.i1]);
            refine(r, b.i0, a.i1, &rest)
        };
        runs[w].t1 = t;
        runs[w + 1].t0 = t;
    }
    for run in runs.iter_mut().filter(|run| !run.moving) {
        let p = mean_posture(&r.q[run.i0..=run.i1]);
        run.home = p.iter().all(|v| v.abs() <= opts.home_tol_rad);
    }
    runs
}

/// Idle runs too short to be a pre- or post-idle (dwells, speed dips at waypoints, noise) are
/// absorbed into the surrounding motion; adjacent runs of the same kind are then joined.
fn merge_runs(runs: Vec<Run>, opts: &SegmentOptions) -> Vec<Run> {
    let last = runs.len().saturating_sub(1);
    let mut out: Vec<Run> = Vec::with_capacity(runs.len());
    for (w, mut run) in runs.into_iter().enumerate() {
        let at_edge = w == 0 || w == last;
        let significant = if run.home { 0.3 } else { opts.min_post_idle_s };
        if !run.moving && !at_edge && run.duration() < significant {
            run.moving = true;
        }
        match out.last_mut() {
            Some(prev) if prev.moving == run.moving && (run.moving || prev.home == run.home) => {
                prev.t1 = run.t1;
                prev.i1 = run.i1;
            }
            _ => out.push(run),
        }
    }
    out
}

fn kind(run: &Run) -> &'static str {
    match (run.moving, run.home) {
        (true, _) => "motion",
        (false, true) => "home idle",
        (false, false) => "posture idle",
    }
}

fn match_trials(runs: &[Run], opts: &SegmentOptions) -> Segmentation {
    let mut seg = Segmentation::default();
    let n = runs.len();
    let is_home = |w: usize| w < n && !runs[w].moving && runs[w].home;
    // Everything before the first home idle that contains motion is a trial cut by the session start.
    let first_home = (0..n).find(|&w| is_home(w)).unwrap_or(n);
    if runs[..first_home].iter().any(|r| r.moving) {
        seg.unmatched.push(Stretch {
            t0: runs[0].t0,
            t1: if first_home < n {
                runs[first_home].t0
            } else {
                runs[n - 1].t1
            },
            reason: if first_home < n {
                "session starts mid-trial (motion before the first rest at home)".into()
            } else {
                format!(
                    "motion but never at rest at home (|q| ≤ {} rad): not the protocol",
                    opts.home_tol_rad
                )
            },
        });
    }
    let mut w = first_home;
    while w < n {
        let next_home = (w + 1..n).find(|&v| is_home(v)).unwrap_or(n);
        let (h, body) = (runs[w], &runs[w + 1..next_home]);
        if body.is_empty() {
            break; // the session ends at rest at home
        }
        let t1 = if next_home < n {
            runs[next_home].t0
        } else {
            runs[n - 1].t1
        };
        let stretch = |reason: String| Stretch {
            t0: h.t1,
            t1,
            reason,
        };
        let shape_ok = body.len() == 3 && body[0].moving && !body[1].moving && body[2].moving;
        if next_home == n {
            let reason = if shape_ok || (body.len() < 3 && body[0].moving) {
                "session ends mid-trial (no return to rest at home)".to_string()
            } else {
                format!(
                    "session ends without returning home after {}",
                    describe(body)
                )
            };
            seg.unmatched.push(stretch(reason));
        } else if !shape_ok {
            seg.unmatched.push(stretch(format!(
                "does not fit pre-idle → trajectory → post-idle (≥ {:.1} s) → return: found {}",
                opts.min_post_idle_s,
                describe(body)
            )));
        } else if h.duration() < opts.min_pre_idle_s {
            seg.unmatched.push(stretch(format!(
                "pre-idle at home lasts {:.2} s (< {:.2} s){}",
                h.duration(),
                opts.min_pre_idle_s,
                if w == 0 {
                    "; session starts during it"
                } else {
                    ""
                }
            )));
        } else {
            seg.trials.push(TrialWindow {
                index: seg.trials.len(),
                t_pre_start: (h.t1 - opts.pre_idle_s).max(h.t0),
                t_traj_start: h.t1,
                t_traj_end: body[1].t0,
                t_post_end: body[1].t1,
                t_return_end: t1,
                joints_moved: Vec::new(),
                qdot_max_cmd: f64::NAN,
                qdot_max_meas: f64::NAN,
            });
        }
        w = next_home;
    }
    seg
}

fn describe(body: &[Run]) -> String {
    let parts: Vec<String> = body
        .iter()
        .map(|r| format!("{} {:.2} s", kind(r), r.duration()))
        .collect();
    parts.join(", ")
}

/// Fill joints moved and peak speeds of a matched trial.
fn describe_trial(rec: &Recording, r: &Reference, trial: &mut TrialWindow, opts: &SegmentOptions) {
    let (a, b) = (trial.t_traj_start, trial.t_traj_end);
    let span = |t: &[f64]| {
        (
            t.partition_point(|&x| x < a),
            t.partition_point(|&x| x <= b),
        )
    };
    let (i0, i1) = span(r.t);
    let mut lo = [f64::INFINITY; N_JOINTS];
    let mut hi = [f64::NEG_INFINITY; N_JOINTS];
    for q in &r.q[i0..i1] {
        for j in 0..N_JOINTS {
            lo[j] = lo[j].min(q[j]);
            hi[j] = hi[j].max(q[j]);
        }
    }
    trial.joints_moved = (0..N_JOINTS)
        .filter(|&j| hi[j] - lo[j] > opts.moved_tol_rad)
        .collect();

    let c = &rec.command;
    if c.t.len() >= 2 {
        let (c0, c1) = span(&c.t);
        let n = c.q.len().min(c.t.len());
        let mut peak = 0.0f64;
        for k in c0.max(1)..c1.min(n) {
            let dt = (c.t[k] - c.t[k - 1]).max(1e-6);
            for j in 0..N_JOINTS {
                let commanded = c.dq.get(k).map_or(0.0, |d| d[j].abs());
                // Some controllers leave dq empty: fall back to the position difference.
                let differenced = (c.q[k][j] - c.q[k - 1][j]).abs() / dt;
                peak = peak.max(if commanded > 0.0 {
                    commanded
                } else {
                    differenced
                });
            }
        }
        trial.qdot_max_cmd = peak;
    }
    let s = &rec.state;
    let (s0, s1) = span(&s.t);
    let n = s.dq.len().min(s.t.len());
    let mut peak = f64::NAN;
    for k in s0.max(1)..s1.min(n.saturating_sub(1)) {
        for j in 0..N_JOINTS {
            let v = (s.dq[k - 1][j] + s.dq[k][j] + s.dq[k + 1][j]).abs() / 3.0;
            peak = if peak.is_nan() { v } else { peak.max(v) };
        }
    }
    trial.qdot_max_meas = peak;
}
