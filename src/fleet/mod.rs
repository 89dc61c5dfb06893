//! `g1viz fleet`: per-robot, per-period power models of many sessions' row tables (Parquet, as
//! `g1viz export rows` writes them), and their drift.
//!
//! The heavy part — sums over millions of rows — is SQL ([`sql`]) run by an embedded engine made
//! for Arrow and Parquet (Apache DataFusion, [`Engine`]) over the files: per group of `--by` keys
//! the trials' first moments (Σy, Σφ, σ_ω), then the group's normal equations ΦᵀΦ, Φᵀy, yᵀy, n.
//! `--save-sql` writes each query with the engine's result; `examples/fleet_sql_crosscheck.py`
//! runs them unchanged on DuckDB and Spark. Each group is then solved here, with identification's
//! own filters ([`crate::trial::Cascade`]): the IMU filter over the group's trials, then the 3σ
//! residual passes, the groups in step so that each pass costs one scan (the normal equations of
//! the trials a pass rejects, subtracted from the group's). Memory holds per-trial moments and
//! per-group normal equations, never rows. [`drift`] then follows each robot's parameters over
//! the periods.

pub mod drift;
pub mod report;
pub mod sql;
pub mod synth;
#[cfg(feature = "viz")]
pub mod viz;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use datafusion::arrow::array::{Array, Float64Array, Int64Array, StringArray};
use datafusion::arrow::compute::cast;
use datafusion::arrow::datatypes::DataType;
use datafusion::arrow::record_batch::RecordBatch;
use datafusion::common::tree_node::{Transformed, TreeNode};
use datafusion::datasource::listing::PartitionedFile;
use datafusion::datasource::physical_plan::{FileGroup, FileScanConfig, FileSource, ParquetSource};
use datafusion::datasource::source::DataSourceExec;
use datafusion::object_store;
use datafusion::physical_plan::ExecutionPlan;
use datafusion::physical_plan::execution_plan::reset_plan_states;
use datafusion::prelude::{ParquetReadOptions, SessionConfig, SessionContext};

use crate::N_PARAMS;
use crate::lsq::Gram;
use crate::trial::{Cascade, RejectReason, Rejection, TrialStat};
pub use sql::{Key, Pick, TrialId};

/// An embedded SQL engine (DataFusion) with the row tables registered as the table `rows`.
pub struct Engine {
    ctx: SessionContext,
    runtime: tokio::runtime::Runtime,
    /// The Parquet files, located for the engine.
    paths: Vec<PartitionedFile>,
    /// The Parquet files under the given paths.
    pub files: usize,
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

/// Bytes of Parquet data the plan's scans read (the engine's `bytes_scanned` metric).
fn bytes_scanned(plan: &dyn ExecutionPlan) -> usize {
    let own = plan
        .metrics()
        .and_then(|m| m.sum_by_name("bytes_scanned"))
        .map_or(0, |v| v.as_usize());
    own + plan
        .children()
        .iter()
        .map(|c| bytes_scanned(c.as_ref()))
        .sum::<usize>()
}

/// The columns the queries read, and whether each holds text (else numbers).
fn read_columns() -> impl Iterator<Item = (String, bool)> {
    let text = ["robot", "session", "target"].map(|c| (c.to_string(), true));
    let numbers = ["trial", "t_ns", "y_w", "sigma_omega"].map(|c| (c.to_string(), false));
    (text.into_iter().chain(numbers))
        .chain((0..N_PARAMS).map(|p| (crate::rows::phi_column(p), false)))
}

/// Check from its footer that `path` is a row table with every column the queries read, of a
/// usable type; its joint names.
fn check_table(path: &Path) -> Result<Option<Vec<String>>> {
    let table = crate::rows::open_table(path)?;
    let schema = table.schema();
    for (name, text) in read_columns() {
        let Ok(field) = schema.field_with_name(&name) else {
            bail!(
                "{}: no column `{name}` (not a table of `g1viz export rows`)",
                path.display()
            );
        };
        let t = field.data_type();
        let usable = match text {
            true => matches!(t, DataType::Utf8 | DataType::LargeUtf8 | DataType::Utf8View),
            false => t.is_numeric(),
        };
        if !usable {
            let want = if text { "text" } else { "numbers" };
            bail!(
                "{}: column `{name}` has type {t}, expected {want}",
                path.display()
            );
        }
    }
    crate::rows::joint_names_of(&table, path)
}

impl Engine {
    /// Register `paths` (Parquet files, or folders searched recursively for `*.parquet`, e.g. a
    /// dataset partitioned as ROBOT/DAY.parquet) as one listing table `rows`. Every path must
    /// exist and hold at least one file; each file's footer must hold every column the queries
    /// read, and all name the same joints.
    pub fn open(paths: &[PathBuf]) -> Result<Engine> {
        let mut files = Vec::new();
        for p in paths {
            let before = files.len();
            if p.is_dir() {
                parquet_files(p, &mut files)?;
                if files.len() == before {
                    bail!(
                        "{}: no .parquet files in the folder or below it",
                        p.display()
                    );
                }
            } else if p.exists() {
                files.push(p.clone());
            } else {
                bail!("{}: no such file or folder", p.display());
            }
        }
        files.sort();
        files.dedup();
        if files.is_empty() {
            bail!("no row tables given");
        }
        let mut joint_names = None;
        for (k, f) in files.iter().enumerate() {
            let names = check_table(f)?;
            if k == 0 {
                joint_names = names;
            } else if names != joint_names {
                bail!(
                    "{}: joint names {names:?} differ from {}'s {joint_names:?}",
                    f.display(),
                    files[0].display()
                );
            }
        }
        let urls = (files.iter()).map(|f| Ok(std::path::absolute(f)?.display().to_string()));
        let urls: Vec<String> = urls.collect::<Result<_>>()?;
        let locate = |(f, url): (&PathBuf, &String)| {
            let mut file = PartitionedFile::new(String::new(), std::fs::metadata(f)?.len());
            file.object_meta.location = object_store::path::Path::from_absolute_path(url)?;
            Ok(file)
        };
        let located = files.iter().zip(&urls).map(locate);
        let located: Vec<PartitionedFile> = located.collect::<Result<_>>()?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .build()
            .context("starting the query engine's runtime")?;
        // Batches of 2,048 rows, not 8,192: the block join makes five of each, and the IMU
        // filter's join holds them; peak RSS at 20 × 30 281 → 217 MB, CPU the same. No cache of
        // the files' footers (50 MB by default, filled with every file) and no file statistics
        // (20 KB a file, even unknown ones): a footer is read again per query, with a 64 KiB
        // first read (default 512 KiB, for footers of ≈ 20 KiB; docs/fleet.md, Memory). No
        // dynamic filters from joins: their state would outlive the plan's chunks.
        let config = (SessionConfig::new().with_batch_size(2048))
            .set_bool("datafusion.execution.parquet.pushdown_filters", true)
            .set_bool("datafusion.execution.collect_statistics", false)
            .set_bool(
                "datafusion.optimizer.enable_join_dynamic_filter_pushdown",
                false,
            )
            .set_usize("datafusion.execution.parquet.metadata_size_hint", 64 << 10);
        let cache = datafusion::execution::runtime_env::RuntimeEnvBuilder::new()
            .with_metadata_cache_limit(0);
        // The sums' ~1,300 aggregate expressions have no common subexpression worth sharing
        // (each product appears once), and the rule that looks for them hashes every expression
        // of every pass: most of a query's time before the first row is read.
        let rules = datafusion::optimizer::Optimizer::new().rules;
        let rules = rules
            .into_iter()
            .filter(|r| r.name() != "common_sub_expression_eliminate");
        let state = datafusion::execution::SessionStateBuilder::new()
            .with_config(config)
            .with_runtime_env(cache.build_arc()?)
            .with_default_features()
            .with_optimizer_rules(rules.collect())
            .build();
        let ctx = SessionContext::new_with_state(state);
        // The files are listed here, so none is skipped for its name. The table is one file per
        // partition: each query is planned on it, then run on the files CHUNK at a time.
        let options = ParquetReadOptions {
            file_extension: "",
            ..Default::default()
        };
        let parts = ctx.copied_config().target_partitions();
        runtime
            .block_on(async {
                let df = ctx
                    .read_parquet(urls[..parts.min(urls.len())].to_vec(), options)
                    .await?;
                ctx.register_table("rows", df.into_view())?;
                anyhow::Ok(())
            })
            .with_context(|| format!("reading the row tables under {}", paths[0].display()))?;
        Ok(Engine {
            ctx,
            runtime,
            paths: located,
            files: files.len(),
            joint_names,
        })
    }

    /// Run one query: planned once, run on the files `chunk` at a time, each chunk's result
    /// handed to `each` batch by batch and dropped (a group in two chunks has a result row in
    /// each), so memory holds one chunk's result however many files there are; the bytes of
    /// Parquet data it read.
    pub fn query(
        &self,
        sql: &str,
        chunk: usize,
        mut each: impl FnMut(&RecordBatch) -> Result<()>,
    ) -> Result<usize> {
        self.runtime.block_on(async {
            let plan = self.ctx.sql(sql).await?.create_physical_plan().await?;
            let mut bytes = 0;
            for files in self.paths.chunks(chunk.max(1)) {
                let plan = Arc::clone(&plan).transform_up(|p| reading(p, files))?;
                // Else every chunk would read the files the query was planned on.
                anyhow::ensure!(plan.transformed, "the query plan has no Parquet scan");
                // Every operator fresh, not only those above the scan: a repartition beside it
                // (a partitioned join's build side) hands out each partition's stream once.
                let plan = reset_plan_states(plan.data)?;
                let task = self.ctx.task_ctx();
                for b in datafusion::physical_plan::collect(Arc::clone(&plan), task).await? {
                    each(&b)?;
                }
                bytes += bytes_scanned(plan.as_ref());
            }
            Ok(bytes)
        })
    }
}

/// A plan's Parquet scan made to read `files` (dealt to its partitions in turn), with fresh
/// metrics (the engine keeps a few per file read): the chunk's files are its only per-file state.
fn reading(
    plan: Arc<dyn ExecutionPlan>,
    files: &[PartitionedFile],
) -> datafusion::error::Result<Transformed<Arc<dyn ExecutionPlan>>> {
    let scan = plan.downcast_ref::<DataSourceExec>();
    let Some(config) = scan.and_then(|s| s.data_source().downcast_ref::<FileScanConfig>()) else {
        return Ok(Transformed::no(plan));
    };
    let Some(old) = config.file_source.downcast_ref::<ParquetSource>() else {
        return Ok(Transformed::no(plan));
    };
    let mut source = ParquetSource::new(old.table_schema().clone())
        .with_table_parquet_options(old.table_parquet_options().clone());
    if let Some(p) = old.filter() {
        source = source.with_predicate(p);
    }
    let mut config = config.clone();
    config.file_source = match old.projection() {
        Some(p) => source
            .try_pushdown_projection(p)?
            .unwrap_or(Arc::new(source)),
        None => Arc::new(source),
    };
    let mut groups = vec![Vec::new(); config.file_groups.len().max(1)];
    let n = groups.len();
    (files.iter().enumerate()).for_each(|(k, f)| groups[k % n].push(f.clone()));
    config.file_groups = groups.into_iter().map(FileGroup::new).collect();
    Ok(Transformed::yes(DataSourceExec::from_data_source(config)))
}

/// One result column cast to `to` (the engine may return any numeric type; keys as text).
fn column_as<A: Array + Clone + 'static>(b: &RecordBatch, name: &str, to: DataType) -> Result<A> {
    let c =
        (b.column_by_name(name)).with_context(|| format!("query result has no column {name}"))?;
    let c = cast(c, &to).with_context(|| format!("query result column {name} as {to}"))?;
    (c.as_any().downcast_ref::<A>().cloned()).with_context(|| format!("column {name} as {to}"))
}

fn numbers(b: &RecordBatch, name: &str) -> Result<Float64Array> {
    column_as(b, name, DataType::Float64)
}

/// A query's result as CSV (arrow's writer: a header, then one line per row).
pub fn to_csv(batches: &[RecordBatch]) -> Result<String> {
    let mut buf = Vec::new();
    {
        let mut w = datafusion::arrow::csv::WriterBuilder::new()
            .with_header(true)
            .build(&mut buf);
        for b in batches {
            w.write(b)?;
        }
    }
    Ok(String::from_utf8(buf)?)
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
    /// Keep each query's result as CSV in [`FleetFit::queries`] (for `--save-sql`; else empty).
    pub keep_results: bool,
}

/// The fitted model of one group.
#[derive(Debug, Clone, serde::Serialize)]
pub struct GroupFit {
    /// Values of the `--by` keys, in their order (a day or week as its ISO date).
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
    /// Each query run, with its name, text and result as CSV (empty unless
    /// [`FleetOptions::keep_results`]).
    pub queries: Vec<(String, String, String)>,
    /// Bytes of Parquet data the engine read over all queries.
    pub bytes_scanned: usize,
}

struct Work {
    /// The group's trials: index into `sessions`, trial index, σ_ω (sorted).
    trials: Vec<(usize, u32, f64)>,
    sessions: Vec<(String, String)>,
    /// Rows of the group.
    rows: usize,
    /// The normal equations and Σy of the group's rows less those of the trials in `removed`.
    kept: (Gram, f64),
    /// First and last reading time [ns].
    t_ns: (i64, i64),
    /// The first `removed` rejections' rows are taken out of `kept` (rejections only grow).
    removed: usize,
    rejections: Vec<Rejection>,
    error: Option<String>,
    done: bool,
}

impl Work {
    fn session_index(&self, robot: &str, session: &str) -> Option<usize> {
        (self.sessions.iter()).position(|(r, s)| r == robot && s == session)
    }

    fn fit(&self) -> Result<crate::lsq::Fit> {
        let g = &self.kept.0;
        if g.n < N_PARAMS {
            bail!(
                "{} rows left after filtering, fewer than the {N_PARAMS} parameters",
                g.n
            );
        }
        crate::identify::fit_normal(g).context("constrained least squares")
    }
}

/// Adds `sign` × the normal equations and Σy of each group of a [`sql::normal_equations`]
/// result (its blocks of matrix rows put together) to the group's kept sums: the only copy of a
/// group's normal equations held, whether its rows are added or its rejected trials' taken out.
fn add_normal_sums(
    run: &mut Runner,
    (name, q): (&str, String),
    by: &[Key],
    groups: &mut BTreeMap<Vec<String>, Work>,
    sign: f64,
) -> Result<()> {
    run.run(name, q, |b| {
        let block = column_as::<Int64Array>(b, "b", DataType::Int64)?;
        let (n, sy) = (numbers(b, "n")?, numbers(b, "sy")?);
        let mut g = Vec::new();
        for a in 0..sql::BLOCK {
            for j in 0..=N_PARAMS {
                g.push(numbers(b, &format!("g_{a}_{j}"))?);
            }
        }
        for (r, (key, _)) in result_rows(b, by)?.into_iter().enumerate() {
            let w = (groups.get_mut(&key)).context(format!("group {key:?} has no trials"))?;
            let s = &mut w.kept;
            // Summed: a group's rows may come in several chunks of files.
            if block.value(r) == 0 {
                s.0.n = (s.0.n as f64 + sign * n.value(r)) as usize;
                s.1 += sign * sy.value(r);
            }
            for a in 0..sql::BLOCK {
                let i = block.value(r) as usize * sql::BLOCK + a;
                for j in i..=N_PARAMS {
                    let v = sign * g[a * (N_PARAMS + 1) + j].value(r);
                    match (i, j) {
                        (N_PARAMS, _) => s.0.yy += v,
                        (_, N_PARAMS) => s.0.h[i] += v,
                        _ if i == j => s.0.g[(i, i)] += v,
                        _ => (s.0.g[(i, j)] += v, s.0.g[(j, i)] += v).1,
                    }
                }
            }
        }
        Ok(())
    })
}

/// Each row of a result with its group key (the `--by` columns' SQL values) and, when the
/// result is per trial, its trial (the `trial_*` columns).
fn result_rows(b: &RecordBatch, by: &[Key]) -> Result<Vec<(Vec<String>, Option<TrialId>)>> {
    let keys: Vec<StringArray> = by
        .iter()
        .map(|k| column_as(b, k.name(), DataType::Utf8))
        .collect::<Result<_>>()?;
    let trial: Option<Vec<StringArray>> = b
        .column_by_name("trial_trial")
        .map(|_| {
            sql::TRIAL_COLUMNS
                .iter()
                .map(|c| column_as(b, &format!("trial_{c}"), DataType::Utf8))
                .collect::<Result<_>>()
        })
        .transpose()?;
    (0..b.num_rows())
        .map(|r| {
            let id = match &trial {
                Some(t) => Some((
                    t[0].value(r).to_string(),
                    t[1].value(r).to_string(),
                    t[2].value(r)
                        .parse()
                        .context("trial index is not a number")?,
                )),
                None => None,
            };
            Ok((keys.iter().map(|c| c.value(r).to_string()).collect(), id))
        })
        .collect()
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

/// Every group's rejected trials whose rows are not yet out of its sums, with the group's key;
/// they are taken as out from here on.
fn pending(groups: &mut BTreeMap<Vec<String>, Work>) -> Vec<(Vec<String>, TrialId)> {
    let mut out = Vec::new();
    for (key, w) in groups.iter_mut() {
        for r in &w.rejections[w.removed..] {
            let (robot, session) = w.sessions[r.session].clone();
            out.push((key.clone(), (robot, session, r.trial as u32)));
        }
        w.removed = w.rejections.len();
    }
    out
}

/// Files a query reads at a time (all of them for `--save-sql`, whose results are whole).
const CHUNK: usize = 50;

/// Runs the queries, keeping each with its result (for `--save-sql`) and the bytes read.
struct Runner<'a> {
    engine: &'a Engine,
    queries: Vec<(String, String, String)>,
    bytes_scanned: usize,
    keep: bool,
}

impl Runner<'_> {
    /// Run query `q` (named `name` in errors and `--save-sql`), its result batch by batch to `each`.
    fn run(
        &mut self,
        name: &str,
        q: String,
        mut each: impl FnMut(&RecordBatch) -> Result<()>,
    ) -> Result<()> {
        let mut whole = Vec::new();
        let chunk = if self.keep { usize::MAX } else { CHUNK };
        let bytes = (self.engine.query(&q, chunk, |b| {
            if self.keep {
                whole.push(b.clone());
            }
            each(b)
        }))
        .with_context(|| format!("running the {name} query"))?;
        let csv = (self.keep.then(|| to_csv(&whole)).transpose()?).unwrap_or_default();
        self.queries.push((name.to_string(), q, csv));
        self.bytes_scanned += bytes;
        Ok(())
    }
}

/// Step 1, two scans: the groups with their trials, sessions and the IMU filter's rejections;
/// then the normal equations of the trials the IMU filter kept.
fn scan_groups(run: &mut Runner, opts: &FleetOptions) -> Result<BTreeMap<Vec<String>, Work>> {
    let (by, target, filter) = (&opts.by, opts.target.as_str(), opts.filter.as_deref());
    let mut groups: BTreeMap<Vec<String>, Work> = BTreeMap::new();
    run.run("moments", sql::moments(by, target, filter), |b| {
        let (n, sigma) = (numbers(b, "n")?, numbers(b, "sigma_omega")?);
        // Reading times stay integer nanoseconds (an f64 rounds them by up to 256 ns).
        let int = |name| column_as::<Int64Array>(b, name, DataType::Int64);
        let (t0, t1) = (int("t_min")?, int("t_max")?);
        for (r, (key, id)) in result_rows(b, by)?.into_iter().enumerate() {
            let (robot, session, trial) = id.context("moments without trial columns")?;
            let w = groups.entry(key).or_insert_with(|| Work {
                trials: Vec::new(),
                sessions: Vec::new(),
                rows: 0,
                kept: (Gram::zeros(N_PARAMS), 0.0),
                t_ns: (i64::MAX, i64::MIN),
                removed: 0,
                rejections: Vec::new(),
                error: None,
                done: false,
            });
            let s = w.session_index(&robot, &session).unwrap_or_else(|| {
                w.sessions.push((robot, session));
                w.sessions.len() - 1
            });
            w.rows += n.value(r) as usize;
            w.t_ns = (w.t_ns.0.min(t0.value(r)), w.t_ns.1.max(t1.value(r)));
            w.trials.push((s, trial, sigma.value(r)));
        }
        Ok(())
    })?;
    if groups.is_empty() {
        let picked = filter.map(|f| format!(" where {f}")).unwrap_or_default();
        bail!("no rows of target {target} in the tables{picked}");
    }
    let mut imu = Vec::new();
    for (key, w) in groups.iter_mut() {
        // The engine returns rows in no fixed order: sessions by name and trials by session
        // and index, so the filters see the same sequence (and list their rejections in the
        // same order) on every run.
        let mut order: Vec<usize> = (0..w.sessions.len()).collect();
        order.sort_by(|&a, &b| w.sessions[a].cmp(&w.sessions[b]));
        let mut rank = vec![0; order.len()];
        order.iter().enumerate().for_each(|(r, &s)| rank[s] = r);
        w.sessions = order.iter().map(|&s| w.sessions[s].clone()).collect();
        w.trials.iter_mut().for_each(|t| t.0 = rank[t.0]);
        w.trials.sort_by_key(|t| (t.0, t.1));
        // A session in two files is a trial in two chunks (its σ_ω is the same on every row).
        w.trials.dedup_by_key(|t| (t.0, t.1));
        let stat = |&(s, t, sigma): &(usize, u32, f64)| TrialStat::new(s, t as usize, sigma);
        let sigmas: Vec<TrialStat> = w.trials.iter().map(stat).collect();
        w.rejections = opts.cascade.imu(&sigmas);
        w.removed = w.rejections.len();
        // Every IMU rejection names the group's threshold; a group without one keeps every row.
        if let Some(r) = w.rejections.first() {
            imu.push((key.clone(), r.threshold));
        }
    }
    // The IMU filter's rejections are left out in the scan (by their group's threshold, one
    // inline row a group), not subtracted after another.
    let q = sql::normal_equations(by, Pick::ImuBelow(&imu), target, filter);
    add_normal_sums(run, ("normal_equations", q), by, &mut groups, 1.0)?;
    Ok(groups)
}

/// Step 2, residual pass `pass` of the groups not done: fit each on its kept trials, one scan
/// for every trial's mean residual under its group's θ, reject by it; a group is done when
/// nothing more is rejected (or its fit fails).
fn residual_pass(
    run: &mut Runner,
    groups: &mut BTreeMap<Vec<String>, Work>,
    pass: usize,
    opts: &FleetOptions,
) -> Result<()> {
    let mut thetas = Vec::new();
    for (key, w) in groups.iter_mut().filter(|(_, w)| !w.done) {
        match w.fit().and_then(|f| f.theta49()) {
            Ok(t) => thetas.push((key.clone(), t)),
            Err(e) => (w.error, w.done) = (Some(format!("{e:#}")), true),
        }
    }
    if thetas.is_empty() {
        return Ok(());
    }
    let (by, target, filter) = (&opts.by, opts.target.as_str(), opts.filter.as_deref());
    let q = sql::residuals(by, &thetas, target, filter);
    // Each fitted group's trials' residual sums and rows, in the order of its trials.
    let mut sums: BTreeMap<Vec<String>, Vec<(f64, f64)>> = BTreeMap::new();
    run.run(&format!("residuals_{pass}"), q, |b| {
        let (n, sum) = (numbers(b, "n")?, numbers(b, "s_resid")?);
        for (r, (key, id)) in result_rows(b, by)?.into_iter().enumerate() {
            let (robot, session, trial) = id.context("residuals without trial columns")?;
            let w = groups
                .get(&key)
                .context(format!("group {key:?} has no trials"))?;
            let s = w
                .session_index(&robot, &session)
                .context("a trial of no session")?;
            let k = (w
                .trials
                .binary_search_by_key(&(s, trial), |t| (t.0, t.1))
                .ok())
            .context("a trial of no group")?;
            let len = w.trials.len();
            let t = &mut sums.entry(key).or_insert_with(|| vec![(0.0, 0.0); len])[k];
            (t.0, t.1) = (t.0 + sum.value(r), t.1 + n.value(r));
        }
        Ok(())
    })?;
    for (key, _) in thetas {
        let w = groups.get_mut(&key).context("a fitted group")?;
        let m = sums.remove(&key).unwrap_or_default();
        let residuals: Vec<TrialStat> = (w.trials.iter().enumerate())
            .filter(|(_, (s, t, _))| !crate::trial::is_rejected(&w.rejections, *s, *t as usize))
            .map(|(k, &(s, t, _))| {
                let (sum, n) = m.get(k).copied().unwrap_or((f64::NAN, 0.0));
                TrialStat::new(s, t as usize, sum / n)
            })
            .collect();
        w.done = !opts
            .cascade
            .residual_pass(pass, &mut w.rejections, residuals);
    }
    Ok(())
}

/// Step 3: a group's final fit on its kept trials.
fn final_fit(key: Vec<String>, w: Work) -> GroupFit {
    let (g, sy) = w.kept.clone();
    let mut out = GroupFit {
        key,
        rows: w.rows,
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
                out.std_err = widened_se(&g, &fit.std_err);
            }
            Err(e) => out.error = Some(format!("{e:#}")),
        }
    }
    out
}

/// Fit every group of the engine's rows: moments, IMU filter, normal equations, then per
/// residual pass the normal equations of the trials it rejected (one scan each), final fit.
/// `progress` hears each stage.
pub fn fit_fleet(
    engine: &Engine,
    opts: &FleetOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<FleetFit> {
    let (by, target, filter) = (&opts.by, opts.target.as_str(), opts.filter.as_deref());
    let mut run = Runner {
        engine,
        queries: Vec::new(),
        bytes_scanned: 0,
        keep: opts.keep_results,
    };
    let files = engine.files;
    progress(&format!(
        "scanning {files} files: moments and normal equations"
    ));
    let mut groups = scan_groups(&mut run, opts)?;
    let mut pass = 0;
    loop {
        // The normal equations of every trial rejected so far and not yet removed, one scan.
        let pending = pending(&mut groups);
        if !pending.is_empty() {
            progress(&format!(
                "scanning: normal equations of {} rejected trials",
                pending.len()
            ));
            // Summed by group, not by trial: memory stays per group however many are rejected.
            // Each group's own rejected trials only: a trial in two groups (a session across
            // midnight by day) may be rejected in one and kept in the other.
            let q = sql::normal_equations(by, Pick::Only(&pending), target, filter);
            let name = format!("rejected_{pass}");
            add_normal_sums(&mut run, (&name, q), by, &mut groups, -1.0)?;
        }
        pass += 1;
        if pass > opts.cascade.passes || groups.values().all(|w| w.done) {
            break;
        }
        let n = groups.values().filter(|w| !w.done).count();
        progress(&format!(
            "residual pass {pass}: fitting {n} groups, scanning their residuals"
        ));
        residual_pass(&mut run, &mut groups, pass, opts)?;
    }
    progress("final fits");
    let mut groups: Vec<GroupFit> = (groups.into_iter())
        .map(|(k, w)| final_fit(by.iter().zip(&k).map(|(k, v)| k.show(v)).collect(), w))
        .collect();
    groups.sort_by(|a, b| a.key.cmp(&b.key));
    Ok(FleetFit {
        by: by.clone(),
        groups,
        queries: run.queries,
        bytes_scanned: run.bytes_scanned,
    })
}

impl GroupFit {
    /// The group's key as `robot=r1 week=2026-11-23`.
    pub fn label(&self, by: &[Key]) -> String {
        let keys = (by.iter().zip(&self.key)).map(|(k, v)| format!("{}={v}", k.name()));
        keys.collect::<Vec<_>>().join(" ")
    }

    /// Rejected trials: (by the IMU filter, by the residual passes or unusable).
    pub fn rejected_by(&self) -> (usize, usize) {
        let imu = (self.rejections.iter()).filter(|x| x.reason == RejectReason::ImuSway);
        let imu = imu.count();
        (imu, self.rejections.len() - imu)
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
