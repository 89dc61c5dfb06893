//! Writes the `.rrd` files the screenshots in `docs/` are taken from: the shipped example session
//! replayed as `g1viz replay examples/g1_example.mcap --model paper --max-rate 25 --pose-rate 25`
//! does, once per tab of the
//! layout, each opening on its tab (`docs/screenshots.sh` serves and photographs them). The first
//! tab is what the layout opens on, so it is not written twice.
//!
//! Run from the repository root: `cargo run --example docs_views -- OUT_DIR` writes `OUT_DIR/<n>-<tab>.rrd` (n = 0 is the
//! layout as it opens) and prints one line per file: `<file>\t<tab name>`.

use std::path::PathBuf;

use anyhow::{Context, Result};

use g1viz::identify::IdentifyOptions;
use g1viz::power::PowerModel;
use g1viz::robot::RobotModel;
use g1viz::signals::{SignalMap, load_recording};
use g1viz::viz::{OutputKind, Sink, model_extras, open_stream, recording_id_for, short_joint_name};
use g1viz::viz::{ReplayOptions, log_replay};

fn main() -> Result<()> {
    let out = PathBuf::from(
        std::env::args()
            .nth(1)
            .context("usage: docs_views OUT_DIR")?,
    );
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    // Relative, as a user types it: the recording's `input` property shows this path, not the
    // directory of the machine that made the screenshots.
    let session = PathBuf::from("examples/g1_example.mcap");
    anyhow::ensure!(
        session.is_file(),
        "{} not found: run from the repository root (docs/screenshots.sh does)",
        session.display()
    );
    let rec = load_recording(&session, &SignalMap::g1_left_arm(), &Default::default())?;
    let robot = RobotModel::builtin();
    let arm = robot.arm(&rec.joint_names)?;
    let (extras, _) = model_extras(&rec, &PowerModel::PAPER, &IdentifyOptions::default())?;
    let kind = OutputKind::ModelReplay;
    let mut tabs: Vec<Option<String>> = vec![None];
    let joints: Vec<String> = rec
        .joint_names
        .iter()
        .map(|n| short_joint_name(n))
        .collect();
    let layout = g1viz::viz::layout(&robot, &arm, &joints, &extras);
    tabs.extend(layout.tab_names().into_iter().map(Some));
    for (n, tab) in tabs.iter().enumerate() {
        // The layout opens on its first tab: that view is the default one, already taken.
        if n == 1 {
            continue;
        }
        let slug = slug(tab.as_deref().unwrap_or("default"));
        let file = out.join(format!("{n}-{slug}.rrd"));
        let viz = open_stream(
            &kind.app_id(),
            &kind.recording_id(&recording_id_for(&rec)),
            &Sink::Save(file.clone()),
            &[&session],
        )?;
        let opts = ReplayOptions {
            // `replay --max-rate 25 --pose-rate 25`: the same views for an 82 s session, a
            // quarter of the data for the web viewer to ingest before the screenshot.
            pose_rate_hz: Some(25.0),
            slice: g1viz::viz::Slice {
                max_rate_hz: Some(25.0),
                ..Default::default()
            },
            open_tab: tab.clone(),
            properties: vec![
                (
                    "command".into(),
                    "g1viz replay examples/g1_example.mcap --model paper --max-rate 25 --pose-rate 25"
                        .into(),
                ),
                ("model".into(), "paper".into()),
            ],
            ..Default::default()
        };
        log_replay(&rec, &robot, &arm, &extras, &opts, viz.stream())?;
        viz.finish()?;
        println!(
            "{}\t{}",
            file.display(),
            tab.as_deref().unwrap_or("(as it opens)")
        );
    }
    Ok(())
}

/// `Raw power MBS/BMS [W]` → `raw-power-mbs-bms-w`.
fn slug(name: &str) -> String {
    let words: Vec<String> = name
        .split(|c: char| !c.is_ascii_alphanumeric())
        .filter(|w| !w.is_empty())
        .map(str::to_ascii_lowercase)
        .collect();
    words.join("-")
}
