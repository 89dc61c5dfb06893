//! Series colours and styles: one distinct colour per joint (its command lighter and thinner),
//! distinct colours for measured, predicted and error series, a warning colour for rejected
//! trials. Every series gets its name and colour set explicitly (static `SeriesLines` /
//! `SeriesPoints`), so the viewer never assigns two series the same colour by chance.

use anyhow::Result;
use rerun::components::{AggregationPolicy, MarkerShape};
use rerun::{Color, SeriesLines, SeriesPoints};

use super::ChunkWriter;

/// Seven distinguishable joint colours (Tableau 10), shoulder pitch → wrist yaw.
const JOINTS: [[u8; 3]; 7] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
];

/// The colours of [`JOINTS`] and [`TERMS`] in words.
const JOINT_HUES: [&str; 7] = ["blue", "orange", "green", "red", "purple", "brown", "pink"];
const TERM_HUES: [&str; 5] = ["black", "olive", "cyan", "grey", "teal"];

/// The joints' and the terms' colours in words (`joints` in arm order), for plots whose legend
/// would cover the data.
pub(super) fn colour_key(joints: &[String]) -> String {
    let joints = joints.iter().enumerate();
    let joints: Vec<String> = joints
        .map(|(j, n)| format!("{n} {}", JOINT_HUES[j % JOINT_HUES.len()]))
        .collect();
    let terms = crate::power::TERM_NAMES.iter().zip(TERM_HUES);
    let terms: Vec<String> = terms.map(|(n, h)| format!("{n} {h}")).collect();
    format!("joints {}; terms {}", joints.join(", "), terms.join(", "))
}

/// Colour of arm joint `j`.
pub(super) fn joint(j: usize) -> [u8; 3] {
    JOINTS[j % JOINTS.len()]
}

/// The joint's colour blended halfway to white: its command.
pub(super) fn joint_command(j: usize) -> [u8; 3] {
    JOINTS[j % JOINTS.len()].map(|c| c + (255 - c) / 2)
}

/// Measured power readings: a dark, saturated blue that stands out on the viewer's dark and
/// light themes alike (and from the orange prediction).
pub(super) const MEASURED: [u8; 3] = [40, 70, 200];
/// Like-for-like prediction at the readings.
pub(super) const PREDICTED: [u8; 3] = [255, 160, 40];
/// Instantaneous prediction (context line).
pub(super) const PREDICTED_CONTEXT: [u8; 3] = [150, 95, 30];
/// MBS net power.
pub(super) const MBS: [u8; 3] = [23, 190, 207];
/// BMS net power.
pub(super) const BMS: [u8; 3] = [188, 189, 34];
/// Error per reading.
pub(super) const ERROR: [u8; 3] = [0, 140, 160];
/// Error per trajectory.
pub(super) const ERROR_TRAJECTORY: [u8; 3] = [255, 221, 87];
/// Rejected trials (filters) and located trials (diagnosis).
pub(super) const WARNING: [u8; 3] = [230, 50, 50];
/// Kept trials, IMU |ω| and other context.
pub(super) const NEUTRAL: [u8; 3] = [150, 150, 150];
/// The IMU statistic per trial.
pub(super) const IMU_SIGMA: [u8; 3] = [120, 200, 255];

/// Colours of the loss terms: mechanical, copper, Coulomb, viscous, interaction — a scheme of
/// their own (near-black, olive, cyan, grey, dark teal), none of them a joint's hue, since the
/// per-term and per-joint plots sit side by side; no two alike in both hue and lightness (the
/// earlier gold interaction beside the olive copper read as one colour).
pub(super) const TERMS: [[u8; 3]; 5] = [
    [40, 40, 40],
    [188, 189, 34],
    [23, 190, 207],
    [150, 150, 150],
    [0, 110, 110],
];
/// The IMU filter's threshold: a dark line above the noise band, not the rejected trials' red.
pub(super) const THRESHOLD: [u8; 3] = [20, 20, 20];

/// An RGB triple as a Rerun colour.
pub(super) fn rgb([r, g, b]: [u8; 3]) -> Color {
    Color::from_rgb(r, g, b)
}

/// A named line of colour `c` and width `width` [ui points]; min-max decimation keeps spikes
/// visible when zoomed out.
pub(super) fn line(
    w: &mut ChunkWriter<'_>,
    path: &str,
    name: &str,
    c: [u8; 3],
    width: f32,
) -> Result<()> {
    line_with(w, path, (name, c, width), AggregationPolicy::MinMax)
}

/// A line's name, colour and width sent with the aggregation `policy` (`Off`: drawn point by
/// point at any zoom, e.g. narrow bar outlines that min-max decimation turns into zigzags).
pub(super) fn line_with(
    w: &mut ChunkWriter<'_>,
    path: &str,
    (name, c, width): (&str, [u8; 3], f32),
    policy: AggregationPolicy,
) -> Result<()> {
    w.send_static(
        path,
        &SeriesLines::new()
            .with_names([name])
            .with_colors([rgb(c)])
            .with_widths([width])
            .with_aggregation_policy(policy),
    )
}

/// Named points of colour `c`, marker `shape` and size `size`.
pub(super) fn points(
    w: &mut ChunkWriter<'_>,
    path: &str,
    name: &str,
    c: [u8; 3],
    shape: MarkerShape,
    size: f32,
) -> Result<()> {
    w.send_static(
        path,
        &SeriesPoints::new()
            .with_names([name])
            .with_colors([rgb(c)])
            .with_markers([shape])
            .with_marker_sizes([size]),
    )
}
