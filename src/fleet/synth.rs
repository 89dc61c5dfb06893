//! A synthetic fleet from the simulator, for the fleet test and benchmark: `robots` robots, one
//! session every `every_days` days for `days` days, wear (a true parameter growing linearly)
//! (or a constant offset) on chosen parameters of chosen robots, one robot carrying a payload. Each session is
//! simulated, identified and exported as `export rows` does, into a partitioned dataset
//! `DIR/<robot>/day<NNN>.parquet`; the session file is deleted once its rows are written.

use std::path::Path;

use anyhow::{Context, Result};

use crate::sim::{Preset, SimConfig};

/// A true parameter of one robot off its nominal value θ₀ from the start and growing:
/// θ = θ₀ · (1 + `offset` + `per_week` · weeks since day 0).
#[derive(Debug, Clone, Copy)]
pub struct Wear {
    /// Robot index.
    pub robot: usize,
    /// Parameter index (model order).
    pub param: usize,
    /// Relative offset from day 0 (0.4: a robot 40 % off the fleet from the start).
    pub offset: f64,
    /// Relative growth per week (0.2: +20 % of the nominal value a week).
    pub per_week: f64,
}

/// What to simulate.
#[derive(Debug, Clone)]
pub struct FleetSpec {
    /// Number of robots.
    pub robots: usize,
    /// Days covered.
    pub days: usize,
    /// One session every this many days (1: daily).
    pub every_days: usize,
    /// Trial set of each session.
    pub preset: Preset,
    /// Wear.
    pub wear: Vec<Wear>,
    /// The robot with a payload in its hand (the simulator's `payload` effect, 0.5 kg).
    pub payload_robot: Option<usize>,
    /// Base seed (each session gets its own).
    pub seed: u64,
}

/// Robot `r`'s name in the rows (`g1_00`, `g1_01`, …).
pub fn robot_name(r: usize) -> String {
    format!("g1_{r:02}")
}

/// Write the fleet's rows under `dir`; `progress(done, total)` after each session. Returns the
/// number of rows written.
pub fn write_fleet(
    dir: &Path,
    spec: &FleetSpec,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<usize> {
    let map = crate::signals::SignalMap::g1_left_arm();
    let scratch = tempfile::tempdir().context("creating a scratch folder")?;
    let days: Vec<usize> = (0..spec.days).step_by(spec.every_days.max(1)).collect();
    let total = spec.robots * days.len();
    let mut rows = 0;
    for r in 0..spec.robots {
        let folder = dir.join(robot_name(r));
        std::fs::create_dir_all(&folder)
            .with_context(|| format!("creating {}", folder.display()))?;
        for (k, &day) in days.iter().enumerate() {
            let mut theta = crate::power::PowerModel::PAPER.to_vector();
            for w in spec.wear.iter().filter(|w| w.robot == r) {
                theta[w.param] *= 1.0 + w.offset + w.per_week * day as f64 / 7.0;
            }
            let mut cfg = SimConfig {
                preset: spec.preset,
                seed: spec.seed.wrapping_mul(1_000_003) + (r * 10_000 + day) as u64,
                truth: crate::power::PowerModel::from_vector(&theta),
                start_day: day as u64,
                progress: false,
                ..SimConfig::default()
            };
            if spec.payload_robot == Some(r) {
                cfg.effects.enable("payload=0.5")?;
            }
            let session = scratch
                .path()
                .join(format!("{}_day{day:03}.mcap", robot_name(r)));
            crate::sim::simulate(&cfg, &session)?;
            let file = crate::session::SessionFile {
                path: session.clone(),
                map: map.clone(),
                read: Default::default(),
                spill: Default::default(),
            };
            let files = [file];
            let id = crate::identify::identify_files(
                &files,
                &crate::identify::IdentifyOptions::default(),
                &crate::session::StreamOptions::default(),
            )
            .with_context(|| format!("identifying {}", session.display()))?;
            let table = crate::rows::table_rows_files(&files, &id, &robot_name(r))?;
            rows += table.len();
            crate::rows::write_parquet(
                &folder.join(format!("day{day:03}.parquet")),
                &table,
                &map.joint_names,
            )?;
            std::fs::remove_file(&session).ok();
            std::fs::remove_file(crate::sim::truth_path(&session)).ok();
            progress(r * days.len() + k + 1, total);
        }
    }
    Ok(rows)
}
