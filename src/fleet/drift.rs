//! Drift: each robot's parameters over the periods of a fleet fit, and the robots that differ
//! from the fleet.
//!
//! Per robot and parameter, a weighted straight line θ(t) = level + slope·(t − t₀) through the
//! periods where the parameter is free (weights 1/s.e.², t in weeks from the fleet's first
//! reading). The slope's nominal standard error is calibrated on the fleet's own empirical null,
//! since the periods' errors are neither exact nor independent (bounded parameters, shared
//! conditions): multiplied by the largest of the fleet's spread of the nominal z over every
//! parameter, the other robots' spread of it for the same parameter (1.4826 × median |z|; 1 with
//! fewer than three others) and the robot's own scatter about its line, √(χ²/(k − 2)).
//! A calibrated |z| beyond `z` is a drift.
//! A robot's level at t₀ against the median of the other robots' levels, in combined standard
//! errors, is calibrated by the same rule: the larger of the other robots' spread of that
//! distance for the parameter (at least 1) and the robot's own scatter. Beyond `z`, the robot
//! differs from the fleet — on parameters that more than half of the fleet's robots follow
//! (elsewhere there is no fleet level). A trend heading down to its bound, on the bound in some of
//! the robot's periods and within one standard error of it in a free one, is censored: its
//! missing periods are the low ones, so neither its slope nor its level is tested (it stays in
//! the null). Each followed (robot,
//! parameter) is thus tested up to twice, against a null drawn from the same fleet.

use crate::N_PARAMS;

use super::{FleetFit, Key};

/// One period of one robot's parameter.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Point {
    /// Mid time of the period [weeks since the fleet's first reading].
    pub t_weeks: f64,
    /// θ.
    pub value: f64,
    /// Its standard error.
    pub std_err: f64,
}

/// A robot's parameter over the periods, with its straight-line fit.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Trend {
    /// Robot.
    pub robot: String,
    /// Parameter index (model order).
    pub param: usize,
    /// The periods where the parameter was free.
    pub points: Vec<Point>,
    /// Level at the fleet's first reading.
    pub level: f64,
    /// Its standard error (nominal).
    pub level_se: f64,
    /// Slope [per week].
    pub slope: f64,
    /// Its standard error (calibrated: the nominal one × `null_scale`).
    pub slope_se: f64,
    /// The scale of the nominal slope error (the empirical null, or the robot's own scatter).
    pub null_scale: f64,
    /// slope / slope_se.
    pub z: f64,
    /// Whether |z| exceeds the threshold (and the trend is not censored).
    pub drifting: bool,
    /// Heading down to the bound, on it in some periods and near it in a free one: not tested
    /// (docs/fleet.md, Drift).
    pub censored: bool,
}

/// A robot's level that differs from the other robots'.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Outlier {
    /// Robot.
    pub robot: String,
    /// Parameter index.
    pub param: usize,
    /// The robot's level at the fleet's first reading.
    pub level: f64,
    /// The other robots' median level.
    pub fleet_level: f64,
    /// The larger of the other robots' spread of their own distance from the fleet (the
    /// empirical null) and the robot's own scatter.
    pub null_scale: f64,
    /// (level − fleet_level) / (combined standard error · null_scale).
    pub z: f64,
}

/// Drift analysis of a fleet fit.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Drift {
    /// Threshold in standard errors.
    pub z: f64,
    /// The fleet's first reading [ns since the epoch] (t = 0 of the trends).
    pub t0_ns: i64,
    /// Every (robot, parameter) free in at least `min_periods` (and 4) periods and half the robot's.
    pub trends: Vec<Trend>,
    /// Robots differing from the fleet.
    pub outliers: Vec<Outlier>,
}

impl Drift {
    /// Each flag as a line of text (drifts, then robots differing from the fleet) with the time
    /// it refers to [weeks since the fleet's first reading]: a drift's last period, 0 for a level.
    pub fn flags(&self, joints: &[String]) -> Vec<(f64, String)> {
        let label = |p| super::report::param_label(p, joints);
        let drifts = self.drifting().map(|t| {
            let last = t.points.last().map_or(0.0, |p| p.t_weeks);
            let (slope, se, z, level) = (t.slope, t.slope_se, t.z, t.level);
            let (robot, param) = (&t.robot, label(t.param));
            let text = format!("{robot} {param}: drift {slope:+.4} ± {se:.4} per week (z {z:+.1}), level {level:.4}");
            (last, text)
        });
        let levels = self.outliers.iter().map(|o| {
            let (robot, param, level, fleet, z) =
                (&o.robot, label(o.param), o.level, o.fleet_level, o.z);
            (
                0.0,
                format!("{robot} {param}: level {level:.4}, other robots {fleet:.4} (z {z:+.1})"),
            )
        });
        drifts.chain(levels).collect()
    }

    /// Whether `robot`'s parameter `param` drifts or differs from the fleet.
    pub fn is_flagged(&self, param: usize, robot: &str) -> bool {
        let of = |p: usize, r: &str| p == param && r == robot;
        self.drifting().any(|t| of(t.param, &t.robot))
            || self.outliers.iter().any(|o| of(o.param, &o.robot))
    }

    /// The drifting trends.
    pub fn drifting(&self) -> impl Iterator<Item = &Trend> {
        self.trends.iter().filter(|t| t.drifting)
    }
}

const NS_PER_WEEK: f64 = 7.0 * 86_400e9;

/// The median of a non-empty list.
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let m = v.len();
    0.5 * (v[(m - 1) / 2] + v[m / 2])
}

/// Weighted straight line through the points: level, its s.e., slope, its s.e. (nominal, from
/// the points' errors) and the points' scatter about it in their own errors, √(χ²/(k − 2)).
fn line(points: &[Point]) -> Option<[f64; 5]> {
    let (mut s, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for p in points {
        let w = 1.0 / (p.std_err * p.std_err);
        s += w;
        sx += w * p.t_weeks;
        sy += w * p.value;
        sxx += w * p.t_weeks * p.t_weeks;
        sxy += w * p.t_weeks * p.value;
    }
    let det = s * sxx - sx * sx;
    if det.is_nan() || det <= 0.0 || points.len() < 4 {
        return None;
    }
    let slope = (s * sxy - sx * sy) / det;
    let level = (sxx * sy - sx * sxy) / det;
    let chi2: f64 = points
        .iter()
        .map(|p| ((p.value - level - slope * p.t_weeks) / p.std_err).powi(2))
        .sum();
    let scatter = (chi2 / (points.len() - 2) as f64).sqrt();
    Some([level, (sxx / det).sqrt(), slope, (s / det).sqrt(), scatter])
}

impl Trend {
    /// The line through `points`; `null_scale` is their scatter about it until [`calibrate`].
    /// `censored` when it heads down, the parameter is not free in some of the robot's `periods`
    /// and a free one lies within one standard error of the bound.
    fn new(robot: &str, param: usize, points: Vec<Point>, periods: usize) -> Option<Trend> {
        let [level, level_se, slope, slope_se, null_scale] = line(&points)?;
        let bound = crate::lsq::paper_lower_bounds()[param];
        let near = points.iter().any(|p| p.value - bound < p.std_err);
        Some(Trend {
            robot: robot.to_string(),
            param,
            censored: slope < 0.0 && points.len() < periods && near,
            points,
            level,
            level_se,
            slope,
            slope_se,
            null_scale,
            ..Default::default()
        })
    }
}

/// Trends and outliers of a fit grouped by robot and a period (day, week or session); `None`
/// when `--by` has no robot key or no period key.
pub fn analyse(fit: &FleetFit, z: f64, min_periods: usize) -> Option<Drift> {
    let robot_at = fit.by.iter().position(|k| *k == Key::Robot)?;
    let periods = fit.by.iter().any(|k| k.is_period() || *k == Key::Session);
    periods.then_some(())?;
    let ok: Vec<_> = fit.groups.iter().filter(|g| g.error.is_none()).collect();
    let t0_ns = ok.iter().map(|g| g.t_ns.0).min()?;
    let robots: std::collections::BTreeSet<&str> =
        ok.iter().map(|g| g.key[robot_at].as_str()).collect();
    let mut trends = Vec::new();
    for robot in &robots {
        for param in 0..N_PARAMS {
            let points: Vec<Point> = ok
                .iter()
                .filter(|g| g.key[robot_at] == *robot)
                .filter_map(|g| {
                    let se = g.std_err[param].filter(|s| s.is_finite() && *s > 0.0)?;
                    let mid = 0.5 * (g.t_ns.0 + g.t_ns.1) as f64;
                    Some(Point {
                        t_weeks: (mid - t0_ns as f64) / NS_PER_WEEK,
                        value: g.theta[param],
                        std_err: se,
                    })
                })
                .collect();
            // Free in four periods at least (a line through three has one degree of freedom to
            // check its scatter with) and in half the robot's: else the periods where it left
            // its bound, a biased subset, make the trend (docs/fleet.md, Drift).
            let all = ok.iter().filter(|g| g.key[robot_at] == *robot).count();
            if points.len() < min_periods.max(4) || 2 * points.len() < all {
                continue;
            }
            trends.extend(Trend::new(robot, param, points, all));
        }
    }
    // Levels first: each trend's `null_scale` is still its own scatter.
    let outliers = outliers(&trends, z);
    calibrate(&mut trends, z);
    Some(Drift {
        z,
        t0_ns,
        trends,
        outliers,
    })
}

/// The spread of a null's |z| (σ for a normal: 1.4826 × the median), at least `floor` so that a
/// few quiet robots do not shrink the others' errors more than 1/`floor`; 1 with fewer than `min`.
fn spread(abs_z: Vec<f64>, min: usize, floor: f64) -> f64 {
    match abs_z.len() >= min {
        false => 1.0,
        true => (1.4826 * median(abs_z)).max(floor),
    }
}

/// The slopes' z on the fleet's own empirical null: each nominal s.e. times the largest of the
/// fleet's spread of the nominal z (every parameter), the other robots' spread of it for the same
/// parameter (1 with fewer than three) and the trend's own scatter (`null_scale` on entry).
fn calibrate(trends: &mut [Trend], z: f64) {
    let raw: Vec<(usize, f64)> = (trends.iter())
        .map(|t| (t.param, t.slope / t.slope_se))
        .collect();
    let fleet = spread(raw.iter().map(|q| q.1.abs()).collect(), 3, 0.0);
    for (k, t) in trends.iter_mut().enumerate() {
        let others = (raw.iter().enumerate()).filter(|&(i, q)| i != k && q.0 == t.param);
        let param = spread(others.map(|(_, q)| q.1.abs()).collect(), 3, fleet);
        t.null_scale = t.null_scale.max(param).max(fleet);
        t.slope_se *= t.null_scale;
        t.z = t.slope / t.slope_se;
        t.drifting = t.z.abs() > z && !t.censored;
    }
}

/// `t`'s level against the median of `others`' levels (at least two): that median, and the
/// distance in combined standard errors (the median's taken as the weighted mean's × √(π/2)).
fn distance(t: &Trend, others: &[&Trend]) -> Option<(f64, f64)> {
    (others.len() >= 2).then_some(())?;
    let fleet_level = median(others.iter().map(|o| o.level).collect());
    let sw: f64 = others.iter().map(|o| o.level_se.powi(-2)).sum();
    let se = (t.level_se.powi(2) + std::f64::consts::FRAC_PI_2 / sw).sqrt();
    Some((fleet_level, (t.level - fleet_level) / se))
}

/// The robots whose level differs from the other robots': its [`distance`] from them, calibrated
/// like the drift z by the larger of the robot's own scatter (`null_scale` on entry) and the
/// [`spread`] of the other robots' distances from the rest of them for that parameter (the robot
/// itself left out, so that it does not widen its own yardstick; 1 with fewer than five). Only
/// parameters that more than half of the fleet's robots follow are tested, censored trends not.
fn outliers(trends: &[Trend], z: f64) -> Vec<Outlier> {
    fn others<'a>(t: &Trend, of: &[&'a Trend]) -> Vec<&'a Trend> {
        let of = of
            .iter()
            .filter(|o| o.param == t.param && o.robot != t.robot);
        of.copied().collect()
    }
    let mut out = Vec::new();
    let all: Vec<&Trend> = trends.iter().collect();
    let mut robots: Vec<&str> = trends.iter().map(|t| t.robot.as_str()).collect();
    robots.sort_unstable();
    robots.dedup();
    for t in trends {
        let rest = others(t, &all);
        // A parameter most robots' fits leave at its bound has no fleet level: the few where it
        // is free are a selection, not the fleet (a 20-robot fleet flagged two of the three
        // robots following θ28, each against the mean of the other two).
        if 2 * (rest.len() + 1) <= robots.len() || t.censored {
            continue;
        }
        let Some((fleet_level, zd)) = distance(t, &rest) else {
            continue;
        };
        let null = rest.iter().filter_map(|o| distance(o, &others(o, &rest)));
        // Five at least: each of these distances is from a median of the few left. The null only
        // widens the yardstick (floor 1): the levels' tails are heavier than their median says,
        // and a floor of 0.7 gave 5 false flags in four runs on two 20 × 30 fleets.
        let null_scale = spread(null.map(|(_, d)| d.abs()).collect(), 5, 1.0).max(t.null_scale);
        if (zd / null_scale).abs() > z {
            let (robot, param, level) = (t.robot.clone(), t.param, t.level);
            let z = zd / null_scale;
            out.push(Outlier {
                robot,
                param,
                level,
                fleet_level,
                null_scale,
                z,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_recovers_a_slope_and_widens_for_scatter() {
        let exact: Vec<Point> = (0..5)
            .map(|k| Point {
                t_weeks: k as f64,
                value: 2.0 + 0.5 * k as f64,
                std_err: 0.1,
            })
            .collect();
        let [level, _, slope, se, _] = line(&exact).unwrap();
        assert!((level - 2.0).abs() < 1e-12 && (slope - 0.5).abs() < 1e-12);
        // Unweighted: se(slope) = σ/√Σ(t − t̄)² = 0.1/√10.
        assert!((se - 0.1 / 10f64.sqrt()).abs() < 1e-12);
        let mut noisy = exact.clone();
        noisy[2].value += 1.0;
        let [.., scatter] = line(&noisy).unwrap();
        assert!(scatter > 3.0, "{scatter}");
    }

    /// A robot's exact line (no scatter) through five weekly points of s.e. 0.1 whose slope is
    /// `z` nominal standard errors, the parameter free in all of the robot's five periods.
    fn sloped(robot: usize, param: usize, z: f64) -> Trend {
        sloped_of(robot, param, z, 5, 1.0)
    }

    /// The same, free in five of the robot's `periods`, starting from `start`.
    fn sloped_of(robot: usize, param: usize, z: f64, periods: usize, start: f64) -> Trend {
        let slope = z * 0.1 / 10f64.sqrt();
        let at = |k: usize| Point {
            t_weeks: k as f64,
            value: start + slope * k as f64,
            std_err: 0.1,
        };
        let points: Vec<Point> = (0..5).map(at).collect();
        Trend::new(&format!("r{robot:02}"), param, points, periods).unwrap()
    }

    /// Twenty robots whose slopes scatter as their errors say on eight parameters, and 0.55 of
    /// that on a ninth (its nominal errors too wide for most robots). A robot 3.3 nominal errors
    /// off on the ninth is not a drift: a parameter's yardstick is never narrower than the
    /// fleet's (the false drifts of three 20 × 30 fleets by week had their parameter's scale at
    /// the old fixed floor, 0.7). One 6 errors off on the first parameter (a0, bound 1) is. One 6
    /// errors down on it, not free in a sixth period, ending 0.4 errors above the bound is
    /// censored, not a drift (the fleet by week of seed 977743138, docs/fleet.md); the same
    /// ending far above the bound, or heading up, is a drift.
    #[test]
    fn a_drift_is_judged_on_no_narrower_a_null_than_the_fleets() {
        let z = |r: usize| 1.35 * (r as f64 - 9.5) / 9.5;
        let mut trends: Vec<Trend> = (0..9)
            .flat_map(|p| (0..19).map(move |r| (p, r)))
            .map(|(p, r)| sloped(r, p, z(r) * if p == 8 { 0.55 } else { 1.0 }))
            .collect();
        trends.extend((0..8).map(|p| sloped(19, p, z(19))));
        trends.push(sloped(19, 8, 3.3));
        trends[2] = sloped(2, 0, 6.0);
        trends[3] = sloped_of(3, 0, -6.0, 6, 1.8);
        trends[4] = sloped_of(4, 0, 6.0, 6, 1.0);
        trends[5] = sloped_of(5, 0, -6.0, 6, 3.0);
        calibrate(&mut trends, 4.0);
        let flagged: Vec<(&str, usize)> = (trends.iter().filter(|t| t.drifting))
            .map(|t| (t.robot.as_str(), t.param))
            .collect();
        assert_eq!(flagged, [("r02", 0), ("r04", 0), ("r05", 0)]);
        assert!(trends[3].censored && trends[3].z < -4.0);
    }

    /// A robot at `level` ± `se` on parameter `param` (its periods are not looked at).
    fn level(robot: usize, param: usize, level: f64, level_se: f64) -> Trend {
        let robot = format!("r{robot:02}");
        Trend {
            robot,
            param,
            level,
            level_se,
            ..Default::default()
        }
    }

    /// Eleven robots whose levels scatter three times their own standard errors (robots differ,
    /// or the errors are too small: the fleet's spread is the yardstick), at the normal quantiles
    /// (Blom) of that spread. A twelfth robot 5 own s.e. off (1.7 spreads) is not flagged; one
    /// 10 spreads off is, as is one 6 s.e. off where the fleet scatters as its errors say.
    /// Where the fleet scatters 1.5 s.e. (null spread 1.74), a robot 8.4 combined s.e. off whose
    /// own periods scatter 1.8 times their errors is flagged (8.4 / 1.8: the larger factor, as
    /// for slopes; their product, 3.1, missed g1_02's b2 by day on seed 615493558), one whose
    /// periods scatter 3 times is not.
    #[test]
    fn a_level_differs_only_beyond_the_fleets_own_spread() {
        let q = [
            -1.59, -1.06, -0.73, -0.46, -0.22, 0.0, 0.22, 0.46, 0.73, 1.06, 1.59,
        ];
        let (se, wide) = (0.01, 0.03);
        let mut trends = Vec::new();
        let odd = [
            (0, wide, 0.05, 0.0),
            (1, wide, 0.3, 0.0),
            (2, se, 0.06, 0.0),
        ];
        let birge = [(3, 0.015, 0.09, 1.8), (4, 0.015, 0.09, 3.0)];
        for (param, spread, odd, scatter) in odd.into_iter().chain(birge) {
            trends
                .extend((q.iter().enumerate()).map(|(r, x)| level(r, param, 1.0 + spread * x, se)));
            trends.push(Trend {
                null_scale: scatter,
                ..level(11, param, 1.0 + odd, se)
            });
        }
        let flagged: Vec<(String, usize)> = (outliers(&trends, 4.0).into_iter())
            .map(|o| (o.robot, o.param))
            .collect();
        let r11 = |p| ("r11".to_string(), p);
        assert_eq!(flagged, [r11(1), r11(2), r11(3)]);
    }

    /// Twenty robots follow parameter 0 at one level; only three follow parameter 1 (the rest of
    /// the fleet's fits leave it at its bound), one of them 10 s.e. from the mean of the other
    /// two. Parameter 1 has no fleet level to differ from: nothing is flagged on it, while a robot
    /// 10 s.e. off on parameter 0 is.
    #[test]
    fn a_level_is_tested_only_where_most_of_the_fleet_follows_it() {
        let mut trends: Vec<Trend> = (0..19)
            .map(|r| level(r, 0, 1.0 + 0.01 * (r as f64 - 9.0) / 9.0, 0.01))
            .collect();
        trends.push(level(19, 0, 1.1, 0.01));
        trends.extend([
            level(0, 1, 0.5, 0.01),
            level(1, 1, 0.52, 0.01),
            level(2, 1, 0.7, 0.01),
        ]);
        let flagged: Vec<(String, usize)> = (outliers(&trends, 4.0).into_iter())
            .map(|o| (o.robot, o.param))
            .collect();
        assert_eq!(flagged, [("r19".to_string(), 0)]);
    }
}
