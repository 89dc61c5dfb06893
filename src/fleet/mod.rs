//! `g1viz fleet`: per-robot, per-period power models of many sessions' row tables (Parquet, as
//! `g1viz export rows` writes them), and their drift.
//!
//! The heavy part — sums over millions of rows — is a streamed scan of the Parquet files
//! ([`Tables`], only the needed columns read): per group of `--by` keys the trials' first
//! moments (Σy, Σφ, σ_ω) and the group's normal equations ΦᵀΦ, Φᵀy, yᵀy, n. The same sums are
//! written as portable SQL ([`sql`]; `--save-sql` writes each query beside our result, and
//! `examples/fleet_sql_crosscheck.py` runs them unchanged on DuckDB and Spark). Each group is
//! then solved here, with identification's own filters ([`crate::trial::Cascade`]): the IMU
//! filter over the group's trials, then the 3σ residual passes, the groups in step so that each
//! pass costs one scan (the normal equations of the trials a pass rejects, subtracted from the
//! group's). Memory holds per-trial moments and per-group normal equations, never rows.
//! [`drift`] then follows each robot's parameters over the periods.

pub mod drift;
pub mod report;
pub mod sql;
pub mod synth;
#[cfg(feature = "viz")]
pub mod viz;

use std::collections::{BTreeMap, HashSet};
use std::fmt::Write as _;
use std::fs::File;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use arrow_array::{Float64Array, Int64Array, StringArray, UInt32Array};
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;

use crate::N_PARAMS;
use crate::lsq::Gram;
use crate::rows::{column, phi_column};
use crate::trial::{Cascade, RejectReason, Rejection, TrialStat};
pub use sql::{Key, Pick, TrialId};

/// The row tables of a fleet: Parquet files from `g1viz export rows`.
pub struct Tables {
    /// The files, in path order.
    pub files: Vec<PathBuf>,
    /// The arm's joint names from the first file's metadata (None: it names none).
    pub joint_names: Option<Vec<String>>,
}

fn parquet_files(dir: &Path, out: &mut Vec<PathBuf>) -> Result<()> {
    for e in std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))? {
        let p = e?.path();
        if p.is_dir() {
            parquet_files(&p, out)?;
        } else if p.extension().is_some_and(|x| x == "parquet") {
            out.push(p);
        }
    }
    Ok(())
}

/// One row as the scan sees it.
struct ScanRow<'a> {
    robot: &'a str,
    session: &'a str,
    trial: u32,
    t_ns: i64,
    y: f64,
    phi: [f64; N_PARAMS],
    sigma_omega: f64,
}

impl Tables {
    /// `paths`: Parquet files, or folders searched recursively for `*.parquet` (a dataset
    /// partitioned as ROBOT/DAY.parquet). Every path must exist and hold at least one file.
    pub fn open(paths: &[PathBuf]) -> Result<Tables> {
        let mut files = Vec::new();
        for p in paths {
            if p.is_dir() {
                let before = files.len();
                parquet_files(p, &mut files)?;
                if files.len() == before {
                    bail!("{}: no .parquet files in the folder", p.display());
                }
            } else if p.exists() {
                files.push(p.clone());
            } else {
                bail!("{}: no such file or folder", p.display());
            }
        }
        files.sort();
        files.dedup();
        let Some(first) = files.first() else {
            bail!("no row tables given");
        };
        let joint_names = crate::rows::table_joint_names(first)?;
        Ok(Tables { files, joint_names })
    }

    /// Every row of `target`, file by file, batch by batch (only the needed columns decoded).
    fn scan(&self, target: &str, f: &mut dyn FnMut(&ScanRow)) -> Result<()> {
        for path in &self.files {
            let file = File::open(path).with_context(|| format!("opening {}", path.display()))?;
            let builder = ParquetRecordBatchReaderBuilder::try_new(file)
                .with_context(|| format!("{}: not a Parquet file", path.display()))?;
            let mut names: Vec<String> = [
                "robot",
                "session",
                "trial",
                "t_ns",
                "target",
                "y_w",
                "sigma_omega",
            ]
            .map(String::from)
            .to_vec();
            names.extend((0..N_PARAMS).map(phi_column));
            let mask =
                ProjectionMask::columns(builder.parquet_schema(), names.iter().map(String::as_str));
            let reader = builder
                .with_projection(mask)
                .with_batch_size(8192)
                .build()
                .with_context(|| format!("reading {}", path.display()))?;
            for batch in reader {
                let b = batch.with_context(|| format!("reading {}", path.display()))?;
                let cols = (|| {
                    let num = |n: &str| column::<Float64Array>(&b, n);
                    anyhow::Ok((
                        column::<StringArray>(&b, "robot")?,
                        column::<StringArray>(&b, "session")?,
                        column::<UInt32Array>(&b, "trial")?,
                        column::<Int64Array>(&b, "t_ns")?,
                        column::<StringArray>(&b, "target")?,
                        num("y_w")?,
                        num("sigma_omega")?,
                        (0..N_PARAMS)
                            .map(|p| num(&phi_column(p)))
                            .collect::<Result<Vec<_>>>()?,
                    ))
                })()
                .with_context(|| format!("in {}", path.display()))?;
                let (robot, session, trial, t_ns, tgt, y, sigma, phi) = cols;
                for k in 0..b.num_rows() {
                    if tgt.value(k) != target {
                        continue;
                    }
                    f(&ScanRow {
                        robot: robot.value(k),
                        session: session.value(k),
                        trial: trial.value(k),
                        t_ns: t_ns.value(k),
                        y: y.value(k),
                        phi: std::array::from_fn(|p| phi[p].value(k)),
                        sigma_omega: sigma.value(k),
                    });
                }
            }
        }
        Ok(())
    }
}

/// What `g1viz fleet` groups and filters.
#[derive(Debug, Clone)]
pub struct FleetOptions {
    /// Grouping keys (`--by`).
    pub by: Vec<Key>,
    /// Power target of the rows used (`mbs` / `bms`).
    pub target: String,
    /// Identification's filter cascade, applied per group.
    pub cascade: Cascade,
}

/// One trial's first moments in one group.
#[derive(Debug, Clone)]
struct TrialMoments {
    id: TrialId,
    n: f64,
    sy: f64,
    s: [f64; N_PARAMS],
    sigma_omega: f64,
}

/// The fitted model of one group.
#[derive(Debug, Clone, serde::Serialize)]
pub struct GroupFit {
    /// Values of the `--by` keys, in their order.
    pub key: Vec<String>,
    /// Rows in the group / used in the final fit.
    pub rows: usize,
    /// Rows used.
    pub rows_used: usize,
    /// Trials in the group.
    pub trials: usize,
    /// Trials the filters rejected (session index into `sessions`).
    pub rejections: Vec<Rejection>,
    /// The group's (robot, session) pairs, the sessions `rejections` index.
    pub sessions: Vec<(String, String)>,
    /// First and last reading [ns since the epoch].
    pub t_ns: (i64, i64),
    /// θ (49; empty when the fit failed).
    pub theta: Vec<f64>,
    /// Standard errors (None at a bound).
    pub std_err: Vec<Option<f64>>,
    /// R² and RMSE [W] of the final fit on its rows.
    pub r2: f64,
    /// RMSE [W].
    pub rmse: f64,
    /// Why the group has no model.
    pub error: Option<String>,
}

/// Every group's model and the SQL that produced their sums.
#[derive(Debug, Clone)]
pub struct FleetFit {
    /// Grouping keys.
    pub by: Vec<Key>,
    /// Groups in key order.
    pub groups: Vec<GroupFit>,
    /// Each query run, with its name, text and result as CSV (for `--save-sql`).
    pub queries: Vec<(String, String, String)>,
}

#[derive(Default)]
struct Work {
    trials: Vec<TrialMoments>,
    sessions: Vec<(String, String)>,
    total: Sums,
    /// Normal equations (and Σy) of the rejected trials, subtracted from `total`.
    removed: Vec<(TrialId, Gram, f64)>,
    rejections: Vec<Rejection>,
    error: Option<String>,
    done: bool,
}

impl Work {
    fn session_index(&self, id: &TrialId) -> usize {
        self.sessions
            .iter()
            .position(|(r, s)| *r == id.0 && *s == id.1)
            .unwrap_or(usize::MAX)
    }

    fn id_of(&self, r: &Rejection) -> TrialId {
        let (robot, session) = self.sessions[r.session].clone();
        (robot, session, r.trial as u32)
    }

    fn kept(&self) -> (Gram, f64) {
        let (mut g, mut sy) = (self.total.gram.clone(), self.total.sy);
        for (_, r, s) in &self.removed {
            g = g.minus(r);
            sy -= s;
        }
        (g, sy)
    }

    /// Rejected trials whose normal equations are not yet removed.
    fn pending(&self) -> Vec<TrialId> {
        self.rejections
            .iter()
            .map(|r| self.id_of(r))
            .filter(|id| !self.removed.iter().any(|(x, _, _)| x == id))
            .collect()
    }

    fn fit(&self) -> Result<crate::lsq::Fit> {
        let (g, _) = self.kept();
        if g.n < N_PARAMS {
            bail!(
                "{} rows left after filtering, fewer than the {N_PARAMS} parameters",
                g.n
            );
        }
        crate::identify::fit_normal(&g).context("constrained least squares")
    }
}

/// Sums of one (group, trial) or one group: the normal equations, Σy, the reading times.
#[derive(Clone)]
struct Sums {
    gram: Gram,
    sy: f64,
    t_ns: (i64, i64),
}

impl Default for Sums {
    fn default() -> Sums {
        Sums {
            gram: Gram::zeros(N_PARAMS),
            sy: 0.0,
            t_ns: (i64::MAX, i64::MIN),
        }
    }
}

impl Sums {
    fn add(&mut self, r: &ScanRow) {
        self.gram.add_row(&r.phi, r.y);
        self.sy += r.y;
        self.t_ns = (self.t_ns.0.min(r.t_ns), self.t_ns.1.max(r.t_ns));
    }

    /// A CSV line: the key cells, then as [`sql::normal_equations`] names them (n, t_min, t_max,
    /// sy, yy, h_i, g_i_j).
    fn csv(&self, key: &[String], trial: Option<&TrialId>, out: &mut String) {
        csv_key(key, trial, out);
        let g = &self.gram;
        let _ = write!(
            out,
            "{},{},{},{},{}",
            g.n, self.t_ns.0, self.t_ns.1, self.sy, g.yy
        );
        for i in 0..N_PARAMS {
            let _ = write!(out, ",{}", g.h[i]);
        }
        for i in 0..N_PARAMS {
            for j in i..N_PARAMS {
                let _ = write!(out, ",{}", g.g[(i, j)]);
            }
        }
        out.push('\n');
    }
}

fn csv_header(by: &[Key], per_trial: bool, values: &[String]) -> String {
    let mut h: Vec<String> = by.iter().map(|k| k.name().to_string()).collect();
    if per_trial {
        h.extend(sql::TRIAL_COLUMNS.map(|c| format!("trial_{c}")));
    }
    h.extend(values.iter().cloned());
    h.join(",") + "\n"
}

fn csv_text(v: &str) -> String {
    if v.contains([',', '"', '\n']) {
        format!("\"{}\"", v.replace('"', "\"\""))
    } else {
        v.to_string()
    }
}

fn csv_key(key: &[String], trial: Option<&TrialId>, out: &mut String) {
    let mut cells: Vec<String> = key.iter().map(|k| csv_text(k)).collect();
    if let Some((r, s, t)) = trial {
        cells.extend([csv_text(r), csv_text(s), t.to_string()]);
    }
    out.push_str(&cells.join(","));
    out.push(',');
}

fn normal_columns() -> Vec<String> {
    let mut v: Vec<String> = ["n", "t_min", "t_max", "sy", "yy"]
        .map(String::from)
        .to_vec();
    v.extend((0..N_PARAMS).map(|i| format!("h_{i}")));
    for i in 0..N_PARAMS {
        v.extend((i..N_PARAMS).map(|j| format!("g_{i}_{j}")));
    }
    v
}

/// The normal equations of the picked trials, per (group, trial): one scan.
fn trial_sums(
    tables: &Tables,
    by: &[Key],
    target: &str,
    only: &[TrialId],
) -> Result<BTreeMap<(Vec<String>, TrialId), Sums>> {
    let wanted: HashSet<(&str, &str, u32)> = only
        .iter()
        .map(|(r, s, t)| (r.as_str(), s.as_str(), *t))
        .collect();
    let mut out: BTreeMap<(Vec<String>, TrialId), Sums> = BTreeMap::new();
    tables.scan(target, &mut |r| {
        if !wanted.contains(&(r.robot, r.session, r.trial)) {
            return;
        }
        let id = (r.robot.to_string(), r.session.to_string(), r.trial);
        out.entry((key_of(by, r), id)).or_default().add(r);
    })?;
    Ok(out)
}

/// The free parameters' (`free`: the bounded fit's standard errors) standard errors from the
/// unconstrained covariance of the excited columns. The bounded fit's own are conditional on
/// its active set: where a correlated neighbour sits at its bound they take it as known, and
/// come out too small. Projecting onto the bounds moves θ no farther from the truth (in ΦᵀΦ's
/// metric) than the unconstrained estimate is, so these bound its error (docs/fleet.md, Drift).
fn widened_se(g: &Gram, free: &[Option<f64>]) -> Vec<Option<f64>> {
    let cols: Vec<usize> = (0..g.columns()).filter(|&j| g.g[(j, j)] > 0.0).collect();
    let mut sub = g.clone();
    (sub.g, sub.h) = (
        g.g.select_rows(&cols).select_columns(&cols),
        g.h.select_rows(&cols),
    );
    let se = sub.solve_with_se().map(|(_, se)| se);
    let mut out = vec![None; g.columns()];
    for (k, &j) in cols.iter().enumerate() {
        out[j] = free[j].and(se.as_ref().map(|se| se[k]));
    }
    out
}

/// The groups' keys of a row (the values of the `--by` keys, in their order).
fn key_of(by: &[Key], r: &ScanRow) -> Vec<String> {
    by.iter()
        .map(|k| k.value(r.robot, r.session, r.t_ns))
        .collect()
}

/// Step 1, one scan: the groups with their trials' moments and normal equations (and the two
/// queries that compute them), their sessions, and the IMU filter's rejections.
fn scan_groups(
    tables: &Tables,
    opts: &FleetOptions,
    queries: &mut Vec<(String, String, String)>,
) -> Result<BTreeMap<Vec<String>, Work>> {
    let (by, target) = (&opts.by, opts.target.as_str());
    let mut groups: BTreeMap<Vec<String>, Work> = BTreeMap::new();
    let mut moments: BTreeMap<(Vec<String>, TrialId), TrialMoments> = BTreeMap::new();
    tables.scan(target, &mut |r| {
        let key = key_of(by, r);
        let id = (r.robot.to_string(), r.session.to_string(), r.trial);
        let m = moments
            .entry((key.clone(), id.clone()))
            .or_insert_with(|| TrialMoments {
                id,
                n: 0.0,
                sy: 0.0,
                s: [0.0; N_PARAMS],
                sigma_omega: f64::NEG_INFINITY,
            });
        m.n += 1.0;
        m.sy += r.y;
        for (a, v) in m.s.iter_mut().zip(&r.phi) {
            *a += v;
        }
        m.sigma_omega = m.sigma_omega.max(r.sigma_omega);
        groups.entry(key).or_default().total.add(r);
    })?;
    if groups.is_empty() {
        bail!("no rows of target {target} in the tables");
    }
    let mut csv = csv_header(by, true, &{
        let mut v: Vec<String> = ["n", "sigma_omega", "sy"].map(String::from).to_vec();
        v.extend((0..N_PARAMS).map(|p| format!("s_{p}")));
        v
    });
    for ((key, id), m) in &moments {
        csv_key(key, Some(id), &mut csv);
        let _ = write!(csv, "{},{},{}", m.n, m.sigma_omega, m.sy);
        for v in &m.s {
            let _ = write!(csv, ",{v}");
        }
        csv.push('\n');
    }
    queries.push(("moments".to_string(), sql::moments(by, target), csv));
    let mut csv = csv_header(by, false, &normal_columns());
    for (key, w) in &groups {
        w.total.csv(key, None, &mut csv);
    }
    let q = sql::normal_equations(by, false, Pick::All, target);
    queries.push(("normal_equations".to_string(), q, csv));
    for ((key, _), m) in moments {
        let w = groups.entry(key).or_default();
        let id = &m.id;
        if !w.sessions.iter().any(|(x, y)| *x == id.0 && *y == id.1) {
            w.sessions.push((id.0.clone(), id.1.clone()));
        }
        w.trials.push(m);
    }
    for w in groups.values_mut() {
        w.sessions.sort();
        let sigmas: Vec<TrialStat> = w
            .trials
            .iter()
            .map(|t| TrialStat::new(w.session_index(&t.id), t.id.2 as usize, t.sigma_omega))
            .collect();
        w.rejections = opts.cascade.imu(&sigmas);
    }
    Ok(groups)
}

/// Step 2, residual pass `pass` of one group: fit its kept trials, reject by mean residual;
/// the group is done when nothing more is rejected (or its fit fails).
fn residual_pass(w: &mut Work, pass: usize, opts: &FleetOptions) {
    let theta = match w.fit().and_then(|f| f.theta49()) {
        Ok(t) => t,
        Err(e) => {
            w.error = Some(format!("{e:#}"));
            w.done = true;
            return;
        }
    };
    let residuals: Vec<TrialStat> = w
        .trials
        .iter()
        .filter(|t| {
            let s = w.session_index(&t.id);
            !crate::trial::is_rejected(&w.rejections, s, t.id.2 as usize)
        })
        .map(|t| {
            let predicted: f64 = theta.iter().zip(&t.s).map(|(a, b)| a * b).sum();
            let mean = (t.sy - predicted) / t.n;
            TrialStat::new(w.session_index(&t.id), t.id.2 as usize, mean)
        })
        .collect();
    let mut rejections = std::mem::take(&mut w.rejections);
    w.done = !opts.cascade.residual_pass(pass, &mut rejections, residuals);
    w.rejections = rejections;
}

/// Step 3: a group's final fit on its kept trials.
fn final_fit(key: Vec<String>, w: Work) -> GroupFit {
    let (g, sy) = w.kept();
    let mut out = GroupFit {
        key,
        rows: w.total.gram.n,
        rows_used: g.n,
        trials: w.trials.len(),
        rejections: w.rejections.clone(),
        sessions: w.sessions.clone(),
        t_ns: w.total.t_ns,
        theta: Vec::new(),
        std_err: Vec::new(),
        r2: f64::NAN,
        rmse: f64::NAN,
        error: w.error.clone(),
    };
    if out.error.is_none() {
        match w.fit() {
            Ok(fit) => {
                let beta = nalgebra::DVector::from_column_slice(&fit.theta);
                let sse = g.sse(&beta);
                let n = g.n as f64;
                out.r2 = 1.0 - sse / (g.yy - sy * sy / n);
                out.rmse = (sse / n).sqrt();
                out.theta = fit.theta;
                out.std_err = widened_se(&g, &fit.std_err);
            }
            Err(e) => out.error = Some(format!("{e:#}")),
        }
    }
    out
}

/// Fit every group of the tables' rows: one scan for the per-trial moments and the groups'
/// normal equations, the IMU filter, then per residual pass the normal equations of the trials
/// rejected (one scan each), final fit. `progress` hears each stage.
pub fn fit_fleet(
    tables: &Tables,
    opts: &FleetOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<FleetFit> {
    let (by, target) = (&opts.by, opts.target.as_str());
    let mut queries = Vec::new();
    progress(&format!(
        "scanning {} files: moments and normal equations",
        tables.files.len()
    ));
    let mut groups = scan_groups(tables, opts, &mut queries)?;
    let mut pass = 0;
    loop {
        // The normal equations of every trial rejected so far and not yet removed, one scan.
        let pending: Vec<TrialId> = groups.values().flat_map(Work::pending).collect();
        if !pending.is_empty() {
            progress(&format!(
                "scanning: normal equations of {} rejected trials",
                pending.len()
            ));
            let mut csv = csv_header(by, true, &normal_columns());
            for ((key, id), t) in trial_sums(tables, by, target, &pending)? {
                t.csv(&key, Some(&id), &mut csv);
                if let Some(w) = groups.get_mut(&key)
                    && w.pending().contains(&id)
                {
                    w.removed.push((id, t.gram, t.sy));
                }
            }
            let q = sql::normal_equations(by, true, Pick::Only(&pending), target);
            queries.push((format!("rejected_{pass}"), q, csv));
        }
        pass += 1;
        if pass > opts.cascade.passes || groups.values().all(|w| w.done) {
            break;
        }
        progress(&format!(
            "residual pass {pass}: fitting {} groups",
            groups.len()
        ));
        for w in groups.values_mut().filter(|w| !w.done) {
            residual_pass(w, pass, opts);
        }
    }
    progress("final fits");
    let groups = groups.into_iter().map(|(k, w)| final_fit(k, w)).collect();
    Ok(FleetFit {
        by: by.clone(),
        groups,
        queries,
    })
}

impl GroupFit {
    /// The group's key as `robot=r1 week=2917`.
    pub fn label(&self, by: &[Key]) -> String {
        by.iter()
            .zip(&self.key)
            .map(|(k, v)| format!("{}={v}", k.name()))
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// Rejected trials by filter: (IMU, residual, unusable).
    pub fn rejected_by(&self) -> (usize, usize, usize) {
        let count = |r: RejectReason| self.rejections.iter().filter(|x| x.reason == r).count();
        (
            count(RejectReason::ImuSway),
            count(RejectReason::Residual),
            count(RejectReason::Unusable),
        )
    }
}

/// Write every query of `fit` as `NN_name.sql` and its result as `NN_name.csv` into `dir`.
pub fn save_queries(fit: &FleetFit, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    for (k, (name, q, csv)) in fit.queries.iter().enumerate() {
        crate::util::write_atomic(&dir.join(format!("{k:02}_{name}.sql")), q.as_bytes())?;
        crate::util::write_atomic(&dir.join(format!("{k:02}_{name}.csv")), csv.as_bytes())?;
    }
    Ok(())
}
