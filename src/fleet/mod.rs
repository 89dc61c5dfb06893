//! `g1viz fleet`: per-robot, per-period power models of many sessions' row tables (Parquet, as
//! `g1viz export rows` writes them), and their drift.
//!
//! The heavy part — sums over millions of rows — is SQL ([`sql`]) run by an embedded engine
//! (Apache DataFusion) over the Parquet files: per group of `--by` keys the trials' first
//! moments (Σy, Σφ, σ_ω), then the group's normal equations ΦᵀΦ, Φᵀy, yᵀy, n. Each group is
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

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use datafusion::arrow::array::{Array, Float64Array};
use datafusion::arrow::datatypes::DataType;
use datafusion::arrow::record_batch::RecordBatch;
use datafusion::common::ScalarValue;
use datafusion::prelude::{ParquetReadOptions, SessionContext};

use crate::N_PARAMS;
use crate::lsq::Gram;
use crate::trial::{Cascade, RejectReason, Rejection, TrialStat};
pub use sql::{Key, Pick, TrialId};

/// An embedded SQL engine with the row tables registered as the table `rows`.
pub struct Engine {
    ctx: SessionContext,
    runtime: tokio::runtime::Runtime,
    /// The arm's joint names from the tables' metadata (None: the tables name none).
    pub joint_names: Option<Vec<String>>,
}

impl Engine {
    /// Register `paths` (Parquet files, or folders searched recursively for `*.parquet`) as one
    /// table `rows`. Every path must exist; the files must share the row table's schema.
    pub fn open(paths: &[PathBuf]) -> Result<Engine> {
        if paths.is_empty() {
            bail!("no row tables given");
        }
        for p in paths {
            if !p.exists() {
                bail!("{}: no such file or folder", p.display());
            }
        }
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .build()
            .context("starting the query engine's runtime")?;
        let ctx = SessionContext::new();
        let urls: Vec<String> = paths
            .iter()
            .map(|p| {
                let abs = std::path::absolute(p)?;
                let mut s = abs.display().to_string();
                if abs.is_dir() && !s.ends_with('/') {
                    s.push('/');
                }
                Ok(s)
            })
            .collect::<std::io::Result<_>>()?;
        let shown = || {
            paths
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let joint_names = runtime.block_on(async {
            let df = ctx
                .read_parquet(
                    urls,
                    ParquetReadOptions {
                        // Keep the schema metadata: the joint names are there.
                        skip_metadata: Some(false),
                        ..Default::default()
                    },
                )
                .await
                .with_context(|| format!("reading the row tables {}", shown()))?;
            let names = df
                .schema()
                .metadata()
                .get(crate::rows::JOINT_NAMES_KEY)
                .and_then(|v| serde_json::from_str::<Vec<String>>(v).ok());
            ctx.register_table("rows", df.into_view())?;
            anyhow::Ok(names)
        })?;
        Ok(Engine {
            ctx,
            runtime,
            joint_names,
        })
    }

    /// Run one query and collect its result.
    pub fn query(&self, sql: &str) -> Result<Vec<RecordBatch>> {
        self.runtime.block_on(async {
            let df = self.ctx.sql(sql).await?;
            Ok(df.collect().await?)
        })
    }
}

/// One result column as numbers (any numeric type the engine returned).
fn numbers(b: &RecordBatch, name: &str) -> Result<Float64Array> {
    let Some(c) = b.column_by_name(name) else {
        bail!("query result has no column {name}");
    };
    let c = datafusion::arrow::compute::cast(c, &DataType::Float64)?;
    Ok(c.as_any()
        .downcast_ref::<Float64Array>()
        .context("cast to Float64")?
        .clone())
}

/// One result cell as text (keys: strings and integers).
fn text(b: &RecordBatch, name: &str, row: usize) -> Result<String> {
    let Some(c) = b.column_by_name(name) else {
        bail!("query result has no column {name}");
    };
    Ok(match ScalarValue::try_from_array(c, row)? {
        ScalarValue::Utf8(Some(s))
        | ScalarValue::LargeUtf8(Some(s))
        | ScalarValue::Utf8View(Some(s)) => s,
        v => v.to_string(),
    })
}

/// A query's result as CSV (header, then one line per row; text quoted when needed).
pub fn to_csv(batches: &[RecordBatch]) -> Result<String> {
    let mut out = String::new();
    let Some(first) = batches.first() else {
        return Ok(out);
    };
    let names: Vec<String> = first
        .schema()
        .fields()
        .iter()
        .map(|f| f.name().clone())
        .collect();
    out.push_str(&names.join(","));
    out.push('\n');
    for b in batches {
        for r in 0..b.num_rows() {
            let cells = names
                .iter()
                .map(|n| {
                    let t = text(b, n, r)?;
                    Ok(if t.contains([',', '"', '\n']) {
                        format!("\"{}\"", t.replace('"', "\"\""))
                    } else {
                        t
                    })
                })
                .collect::<Result<Vec<_>>>()?;
            out.push_str(&cells.join(","));
            out.push('\n');
        }
    }
    Ok(out)
}

/// What `g1viz fleet` groups and filters.
#[derive(Debug, Clone)]
pub struct FleetOptions {
    /// Grouping keys (`--by`).
    pub by: Vec<Key>,
    /// Power target of the rows used (`mbs` / `bms`).
    pub target: String,
    /// An extra SQL predicate on the rows (`--where`), pushed down to the Parquet scan.
    pub filter: Option<String>,
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

struct Work {
    trials: Vec<TrialMoments>,
    sessions: Vec<(String, String)>,
    total: Gram,
    sy: f64,
    t_ns: (i64, i64),
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
        let mut g = self.total.clone();
        let mut sy = self.sy;
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

fn key_of(b: &RecordBatch, by: &[Key], r: usize) -> Result<Vec<String>> {
    by.iter().map(|k| text(b, k.name(), r)).collect()
}

fn trial_of(b: &RecordBatch, r: usize) -> Result<TrialId> {
    let trial = text(b, "trial_trial", r)?;
    Ok((
        text(b, "trial_robot", r)?,
        text(b, "trial_session", r)?,
        trial
            .parse()
            .with_context(|| format!("trial index {trial:?} is not a number"))?,
    ))
}

/// The normal equations in row `r` of a [`sql::normal_equations`] result.
fn gram_of(cols: &NormalColumns, r: usize) -> (Gram, f64) {
    let mut g = Gram::zeros(N_PARAMS);
    for i in 0..N_PARAMS {
        g.h[i] = cols.h[i].value(r);
        for j in i..N_PARAMS {
            let v = cols.g[i * N_PARAMS + j].value(r);
            g.g[(i, j)] = v;
            g.g[(j, i)] = v;
        }
    }
    g.yy = cols.yy.value(r);
    g.n = cols.n.value(r) as usize;
    (g, cols.sy.value(r))
}

struct NormalColumns {
    n: Float64Array,
    sy: Float64Array,
    yy: Float64Array,
    h: Vec<Float64Array>,
    /// Row-major N×N, upper triangle filled.
    g: Vec<Float64Array>,
}

impl NormalColumns {
    fn of(b: &RecordBatch) -> Result<NormalColumns> {
        let empty = Float64Array::from(Vec::<f64>::new());
        let mut g = vec![empty; N_PARAMS * N_PARAMS];
        for i in 0..N_PARAMS {
            for j in i..N_PARAMS {
                g[i * N_PARAMS + j] = numbers(b, &format!("g_{i}_{j}"))?;
            }
        }
        Ok(NormalColumns {
            n: numbers(b, "n")?,
            sy: numbers(b, "sy")?,
            yy: numbers(b, "yy")?,
            h: (0..N_PARAMS)
                .map(|i| numbers(b, &format!("h_{i}")))
                .collect::<Result<_>>()?,
            g,
        })
    }
}

/// Fit every group of the engine's rows: moments, IMU filter, normal equations, residual passes
/// (one scan per pass for the trials it rejects), final fit. `progress` hears each stage.
pub fn fit_fleet(
    engine: &Engine,
    opts: &FleetOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<FleetFit> {
    let by = &opts.by;
    let filter = opts.filter.as_deref();
    let mut queries = Vec::new();
    let mut run = |name: &str, q: String| -> Result<Vec<RecordBatch>> {
        let out = engine
            .query(&q)
            .with_context(|| format!("running the {name} query"))?;
        queries.push((name.to_string(), q, to_csv(&out)?));
        Ok(out)
    };

    progress("scanning: per-trial moments");
    let mut groups: BTreeMap<Vec<String>, Work> = BTreeMap::new();
    for b in run("moments", sql::moments(by, &opts.target, filter))? {
        let (n, sy, sigma) = (
            numbers(&b, "n")?,
            numbers(&b, "sy")?,
            numbers(&b, "sigma_omega")?,
        );
        let s: Vec<Float64Array> = (0..N_PARAMS)
            .map(|p| numbers(&b, &format!("s_{p}")))
            .collect::<Result<_>>()?;
        for r in 0..b.num_rows() {
            let w = groups.entry(key_of(&b, by, r)?).or_insert_with(|| Work {
                trials: Vec::new(),
                sessions: Vec::new(),
                total: Gram::zeros(N_PARAMS),
                sy: 0.0,
                t_ns: (0, 0),
                removed: Vec::new(),
                rejections: Vec::new(),
                error: None,
                done: false,
            });
            let id = trial_of(&b, r)?;
            if !w.sessions.iter().any(|(x, y)| *x == id.0 && *y == id.1) {
                w.sessions.push((id.0.clone(), id.1.clone()));
            }
            w.trials.push(TrialMoments {
                id,
                n: n.value(r),
                sy: sy.value(r),
                s: std::array::from_fn(|p| s[p].value(r)),
                sigma_omega: sigma.value(r),
            });
        }
    }
    if groups.is_empty() {
        bail!(
            "no rows of target {} in the tables{}",
            opts.target,
            filter.map(|f| format!(" where {f}")).unwrap_or_default()
        );
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

    progress("scanning: normal equations per group");
    for b in run(
        "normal_equations",
        sql::normal_equations(by, false, Pick::All, &opts.target, filter),
    )? {
        let cols = NormalColumns::of(&b)?;
        let (t0, t1) = (numbers(&b, "t_min")?, numbers(&b, "t_max")?);
        for r in 0..b.num_rows() {
            let key = key_of(&b, by, r)?;
            let Some(w) = groups.get_mut(&key) else {
                bail!("group {key:?} has normal equations but no trials");
            };
            (w.total, w.sy) = gram_of(&cols, r);
            w.t_ns = (t0.value(r) as i64, t1.value(r) as i64);
        }
    }

    let mut pass = 0;
    loop {
        // The normal equations of every trial rejected so far and not yet removed, one scan.
        let pending: Vec<TrialId> = groups.values().flat_map(Work::pending).collect();
        if !pending.is_empty() {
            progress(&format!(
                "scanning: normal equations of {} rejected trials",
                pending.len()
            ));
            for b in run(
                &format!("rejected_{pass}"),
                sql::normal_equations(by, true, Pick::Only(&pending), &opts.target, filter),
            )? {
                let cols = NormalColumns::of(&b)?;
                for r in 0..b.num_rows() {
                    let Some(w) = groups.get_mut(&key_of(&b, by, r)?) else {
                        continue;
                    };
                    let id = trial_of(&b, r)?;
                    if w.pending().contains(&id) {
                        let (g, sy) = gram_of(&cols, r);
                        w.removed.push((id, g, sy));
                    }
                }
            }
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
            let theta = match w.fit().and_then(|f| f.theta49()) {
                Ok(t) => t,
                Err(e) => {
                    w.error = Some(format!("{e:#}"));
                    w.done = true;
                    continue;
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
    }

    progress("final fits");
    let groups = groups
        .into_iter()
        .map(|(key, w)| {
            let (g, sy) = w.kept();
            let mut out = GroupFit {
                key,
                rows: w.total.n,
                rows_used: g.n,
                trials: w.trials.len(),
                rejections: w.rejections.clone(),
                sessions: w.sessions.clone(),
                t_ns: w.t_ns,
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
                        out.std_err = fit.std_err;
                    }
                    Err(e) => out.error = Some(format!("{e:#}")),
                }
            }
            out
        })
        .collect();
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
