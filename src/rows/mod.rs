//! Per-reading rows as a table, for engines made for many sessions and robots (DataFusion,
//! DuckDB, Polars): `g1viz export rows` writes them as Parquet, `g1viz identify --rows` fits
//! from such a file.
//!
//! One row per power reading inside a trial: robot, session, trial, reading time, the sensor
//! timing used, the net power, the 49 regressors φ averaged over the reading's own window, the
//! joints' mean winding temperatures over that window, the trial's IMU statistic, and whether
//! (and by which filter) the identification rejected the trial.

use std::fs::File;
use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use arrow_array::{
    Array, ArrayRef, BooleanArray, Float64Array, Int64Array, RecordBatch, StringArray, UInt32Array,
};
use arrow_schema::{DataType, Field, Schema};
use parquet::arrow::ArrowWriter;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;

use crate::identify::Row;
use crate::power::PowerModel;
use crate::signals::Recording;
use crate::{N_JOINTS, N_PARAMS};

/// One exported row: a regression row plus who and what it belongs to.
#[derive(Debug, Clone, PartialEq)]
pub struct TableRow {
    /// Robot name (`--robot`, default: the session's folder name).
    pub robot: String,
    /// Session file.
    pub session: String,
    /// The regression row (trial, reading time, window, φ, net power, σ_ω).
    pub row: Row,
    /// Absolute reading time [ns since the Unix epoch].
    pub t_ns: i64,
    /// Power target (`mbs` / `bms`).
    pub target: String,
    /// Sensor window and lag used [s].
    pub window_s: f64,
    /// Sensor lag [s].
    pub lag_s: f64,
    /// Mean winding temperature per joint over the reading's window [°C].
    pub temp_c: [f64; N_JOINTS],
    /// The filter that rejected the row's trial (`imu_sigma`, `residual_3sigma`, …), if any.
    pub rejected_by: Option<String>,
}

/// Parquet key-value metadata key holding the arm's URDF joint names (a JSON array, model
/// order), which `phi_*` and `temp_c_*` columns refer to.
pub const JOINT_NAMES_KEY: &str = "g1viz:joint_names";

/// A row table with the joint names its regressors refer to.
#[derive(Debug, Clone, PartialEq)]
pub struct RowTable {
    /// URDF joint names in model order (None: a table without the [`JOINT_NAMES_KEY`] metadata).
    pub joint_names: Option<Vec<String>>,
    /// The rows.
    pub rows: Vec<TableRow>,
}

/// Name of the column holding regressor `p` (`phi_a0` … `phi_e56`).
pub fn phi_column(p: usize) -> String {
    format!("phi_{}", PowerModel::param_name(p))
}

/// Mean winding temperature per joint over [t0, t1) of `rec` (NaN where no sample falls inside).
pub fn mean_temperatures(rec: &Recording, t0: f64, t1: f64) -> [f64; N_JOINTS] {
    let t = &rec.state.t;
    let (i0, i1) = (
        t.partition_point(|&x| x < t0),
        t.partition_point(|&x| x < t1),
    );
    let samples = rec.state.temp.get(i0..i1.max(i0)).unwrap_or(&[]);
    std::array::from_fn(|j| samples.iter().map(|s| s[j]).sum::<f64>() / samples.len() as f64)
}

fn schema() -> Schema {
    let mut fields = vec![
        Field::new("robot", DataType::Utf8, false),
        Field::new("session", DataType::Utf8, false),
        Field::new("trial", DataType::UInt32, false),
        Field::new("t_s", DataType::Float64, false),
        Field::new("t_ns", DataType::Int64, false),
        Field::new("target", DataType::Utf8, false),
        Field::new("window_s", DataType::Float64, false),
        Field::new("lag_s", DataType::Float64, false),
        Field::new("y_w", DataType::Float64, false),
    ];
    fields.extend((0..N_PARAMS).map(|p| Field::new(phi_column(p), DataType::Float64, false)));
    fields
        .extend((0..N_JOINTS).map(|j| Field::new(format!("temp_c_{j}"), DataType::Float64, true)));
    fields.push(Field::new("sigma_omega", DataType::Float64, false));
    fields.push(Field::new("rejected", DataType::Boolean, false));
    fields.push(Field::new("rejected_by", DataType::Utf8, true));
    Schema::new(fields)
}

fn batch(rows: &[TableRow], schema: Arc<Schema>) -> Result<RecordBatch> {
    let f64s = |f: &dyn Fn(&TableRow) -> f64| -> ArrayRef {
        Arc::new(Float64Array::from(rows.iter().map(f).collect::<Vec<_>>()))
    };
    let strings = |f: &dyn Fn(&TableRow) -> Option<String>| -> ArrayRef {
        Arc::new(StringArray::from(rows.iter().map(f).collect::<Vec<_>>()))
    };
    let mut columns: Vec<ArrayRef> = vec![
        strings(&|r| Some(r.robot.clone())),
        strings(&|r| Some(r.session.clone())),
        Arc::new(UInt32Array::from(
            rows.iter().map(|r| r.row.trial as u32).collect::<Vec<_>>(),
        )),
        f64s(&|r| r.row.t),
        Arc::new(Int64Array::from(
            rows.iter().map(|r| r.t_ns).collect::<Vec<_>>(),
        )),
        strings(&|r| Some(r.target.clone())),
        f64s(&|r| r.window_s),
        f64s(&|r| r.lag_s),
        f64s(&|r| r.row.y),
    ];
    for p in 0..N_PARAMS {
        columns.push(f64s(&|r| r.row.phi[p]));
    }
    for j in 0..N_JOINTS {
        columns.push(Arc::new(Float64Array::from(
            rows.iter()
                .map(|r| r.temp_c[j].is_finite().then_some(r.temp_c[j]))
                .collect::<Vec<_>>(),
        )));
    }
    columns.push(f64s(&|r| r.row.sigma_omega));
    columns.push(Arc::new(BooleanArray::from(
        rows.iter()
            .map(|r| r.rejected_by.is_some())
            .collect::<Vec<_>>(),
    )));
    columns.push(strings(&|r| r.rejected_by.clone()));
    RecordBatch::try_new(schema, columns).context("building the row table")
}

/// Write the rows as one zstd-compressed Parquet file (atomically), with `joint_names` (the
/// arm's URDF joint names in model order) under [`JOINT_NAMES_KEY`] in the file's metadata.
pub fn write_parquet(path: &Path, rows: &[TableRow], joint_names: &[String]) -> Result<()> {
    if joint_names.len() != N_JOINTS {
        bail!(
            "{}: {} joint names given, the model has {N_JOINTS} joints",
            path.display(),
            joint_names.len()
        );
    }
    let names = serde_json::to_string(joint_names)?;
    let schema = Arc::new(
        schema().with_metadata(
            [(JOINT_NAMES_KEY.to_string(), names.clone())]
                .into_iter()
                .collect(),
        ),
    );
    let batch = batch(rows, schema.clone())?;
    // In the file's own key-value metadata too, for engines that do not decode the Arrow schema.
    let props = WriterProperties::builder()
        .set_compression(Compression::ZSTD(ZstdLevel::default()))
        .set_key_value_metadata(Some(vec![KeyValue::new(
            JOINT_NAMES_KEY.to_string(),
            names,
        )]))
        .build();
    crate::util::write_atomic_with(path, |w| {
        let mut writer = ArrowWriter::try_new(w, schema, Some(props))?;
        writer.write(&batch)?;
        writer.close()?;
        Ok(())
    })
    .with_context(|| format!("writing {}", path.display()))
}

pub(crate) fn open_table(path: &Path) -> Result<ParquetRecordBatchReaderBuilder<File>> {
    let file = File::open(path).with_context(|| format!("opening {}", path.display()))?;
    ParquetRecordBatchReaderBuilder::try_new(file)
        .with_context(|| format!("{}: not a Parquet file", path.display()))
}

/// The joint names of a row table's [`JOINT_NAMES_KEY`] metadata (None when absent; an error
/// when present but not a JSON array of 7 names).
pub(crate) fn joint_names_of(
    builder: &ParquetRecordBatchReaderBuilder<File>,
    path: &Path,
) -> Result<Option<Vec<String>>> {
    builder
        .metadata()
        .file_metadata()
        .key_value_metadata()
        .and_then(|kv| kv.iter().find(|e| e.key == JOINT_NAMES_KEY))
        .and_then(|e| e.value.clone())
        .or_else(|| builder.schema().metadata().get(JOINT_NAMES_KEY).cloned())
        .map(|v| {
            let names: Vec<String> = serde_json::from_str(&v).with_context(|| {
                format!(
                    "{}: metadata {JOINT_NAMES_KEY} is not a JSON list of names: {v}",
                    path.display()
                )
            })?;
            if names.len() != N_JOINTS {
                bail!(
                    "{}: metadata {JOINT_NAMES_KEY} names {} joints, the model has {N_JOINTS}",
                    path.display(),
                    names.len()
                );
            }
            Ok(names)
        })
        .transpose()
}

/// Read a row table written by [`write_parquet`] (or by any tool keeping its column names and
/// types), with the joint names of the file's [`JOINT_NAMES_KEY`] metadata. Errors name the
/// file and the missing or mistyped column, or metadata that is not a JSON array of 7 names.
pub fn read_table(path: &Path) -> Result<RowTable> {
    let builder = open_table(path)?;
    let joint_names = joint_names_of(&builder, path)?;
    let reader = builder
        .build()
        .with_context(|| format!("{}: not a Parquet file", path.display()))?;
    let mut rows = Vec::new();
    for batch in reader {
        let batch = batch.with_context(|| format!("reading {}", path.display()))?;
        read_batch(&batch, &mut rows).with_context(|| format!("in {}", path.display()))?;
    }
    Ok(RowTable { joint_names, rows })
}

pub(crate) fn column<'a, T: 'static>(b: &'a RecordBatch, name: &str) -> Result<&'a T> {
    let Some(c) = b.column_by_name(name) else {
        bail!("column `{name}` is missing");
    };
    match c.as_any().downcast_ref::<T>() {
        Some(a) => Ok(a),
        None => bail!("column `{name}` has type {}", c.data_type()),
    }
}

fn read_batch(b: &RecordBatch, out: &mut Vec<TableRow>) -> Result<()> {
    let text = |name: &str| column::<StringArray>(b, name);
    let num = |name: &str| column::<Float64Array>(b, name);
    let (robot, session, target, rejected_by) = (
        text("robot")?,
        text("session")?,
        text("target")?,
        text("rejected_by")?,
    );
    let trial = column::<UInt32Array>(b, "trial")?;
    let t_ns = column::<Int64Array>(b, "t_ns")?;
    let (t, window, lag, y, sigma) = (
        num("t_s")?,
        num("window_s")?,
        num("lag_s")?,
        num("y_w")?,
        num("sigma_omega")?,
    );
    let phi: Vec<&Float64Array> = (0..N_PARAMS)
        .map(|p| num(&phi_column(p)))
        .collect::<Result<_>>()?;
    let temps: Vec<&Float64Array> = (0..N_JOINTS)
        .map(|j| num(&format!("temp_c_{j}")))
        .collect::<Result<_>>()?;
    for k in 0..b.num_rows() {
        let value = |a: &Float64Array| if a.is_null(k) { f64::NAN } else { a.value(k) };
        let row = Row {
            trial: trial.value(k) as usize,
            t: t.value(k),
            t0: t.value(k) - lag.value(k) - window.value(k),
            t1: t.value(k) - lag.value(k),
            phi: std::array::from_fn(|p| phi[p].value(k)),
            y: y.value(k),
            sigma_omega: sigma.value(k),
            tau0_sq: [f64::NAN; N_JOINTS],
        };
        if !(row.y.is_finite() && row.phi.iter().all(|v| v.is_finite())) {
            bail!("row {k}: net power or a regressor is not a finite number");
        }
        out.push(TableRow {
            robot: robot.value(k).to_string(),
            session: session.value(k).to_string(),
            row,
            t_ns: t_ns.value(k),
            target: target.value(k).to_string(),
            window_s: window.value(k),
            lag_s: lag.value(k),
            temp_c: std::array::from_fn(|j| value(temps[j])),
            rejected_by: (!rejected_by.is_null(k)).then(|| rejected_by.value(k).to_string()),
        });
    }
    Ok(())
}

/// The rows of one trial of session `s` built on `rec` (which holds at least the trial's window).
fn trial_table_rows(
    rec: &Recording,
    trial: &crate::trial::TrialWindow,
    s: usize,
    id: &crate::identify::Identification,
    robot: &str,
    out: &mut Vec<TableRow>,
) {
    use crate::identify::{DatasetOptions, Mode, build_dataset};
    let opts = DatasetOptions {
        mode: Mode::Reading,
        target: id.options.target,
        alignment: id.alignment,
    };
    let set = build_dataset(rec, std::slice::from_ref(trial), &opts);
    for row in set.rows {
        let rejected_by = id
            .rejections
            .iter()
            .find(|r| r.session == s && r.trial == row.trial)
            .map(|r| r.reason.name().to_string());
        out.push(TableRow {
            robot: robot.to_string(),
            session: rec.source.display().to_string(),
            t_ns: rec.start_ns as i64 + (row.t * 1e9).round() as i64,
            target: id.options.target.name().to_string(),
            window_s: id.alignment.window_s,
            lag_s: id.alignment.lag_s,
            temp_c: mean_temperatures(rec, row.t0, row.t1),
            rejected_by,
            row,
        });
    }
}

/// The rows of an identification's sessions, all trials with readings (the rejected ones
/// flagged with their filter), at the sensor timing the identification used.
pub fn table_rows(
    recs: &[Recording],
    id: &crate::identify::Identification,
    robot: &str,
) -> Vec<TableRow> {
    let mut out = Vec::new();
    for (s, (rec, summary)) in recs.iter().zip(&id.sessions).enumerate() {
        for trial in &summary.segmentation.trials {
            trial_table_rows(rec, trial, s, id, robot, &mut out);
        }
    }
    out
}

/// [`table_rows`] of session files, each streamed once more holding one trial at a time (from
/// the joint states the identification spilled, when it did; the
/// identification must come from [`crate::identify::identify_files`] on the same files, so the
/// trials share its clock).
pub fn table_rows_files(
    files: &[crate::session::SessionFile],
    id: &crate::identify::Identification,
    robot: &str,
) -> Result<Vec<TableRow>> {
    let mut out = Vec::new();
    for (s, (file, summary)) in files.iter().zip(&id.sessions).enumerate() {
        // Joint states and power only: the identification's spill when it left one.
        crate::session::for_each_trial_with_batches(
            file,
            &summary.segmentation.trials,
            4096,
            &mut |_| {},
            &mut |rec, trial| {
                trial_table_rows(rec, trial, s, id, robot, &mut out);
                Ok(())
            },
        )
        .with_context(|| format!("reading {} (rows)", file.path.display()))?;
    }
    Ok(out)
}
