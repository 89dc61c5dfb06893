//! The fleet's SQL: the text every engine runs (DataFusion here; DuckDB or Spark SQL unchanged,
//! see `examples/fleet_sql_crosscheck.py`). Only portable SQL: `COUNT`/`SUM`/`MIN`/`MAX`, `CAST`,
//! `FLOOR`, an inline `VALUES` table joined; the row table is called `rows`.

use crate::N_PARAMS;
use crate::rows::phi_column;

/// A grouping key of `--by`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Key {
    /// The robot name column.
    Robot,
    /// The session file.
    Session,
    /// UTC day of the reading (days since 1970-01-01 in SQL, shown as its ISO date).
    Day,
    /// Week of the reading, Monday to Sunday (weeks since Monday 1969-12-29 in SQL, shown as
    /// its Monday's ISO date).
    Week,
}

impl Key {
    /// The key's column name in results (`robot`, `session`, `day`, `week`).
    pub fn name(self) -> &'static str {
        match self {
            Key::Robot => "robot",
            Key::Session => "session",
            Key::Day => "day",
            Key::Week => "week",
        }
    }

    /// The SQL expression of the key over the row table.
    pub fn expr(self) -> &'static str {
        match self {
            Key::Robot => "robot",
            Key::Session => "session",
            // 8.64e13 ns a day; 1970-01-01 was a Thursday, so +3 days starts weeks on Mondays.
            Key::Day => "CAST(FLOOR(t_ns / 8.64e13) AS BIGINT)",
            Key::Week => "CAST(FLOOR((t_ns / 8.64e13 + 3) / 7) AS BIGINT)",
        }
    }

    /// A result's key value as shown: a day or week as the ISO date it starts on (`2026-11-23`),
    /// the others as they are. The SQL keeps the integer (portable across engines).
    pub fn show(self, v: &str) -> String {
        let per = match self {
            Key::Day => 1,
            Key::Week => 7,
            _ => return v.to_string(),
        };
        // Weeks count from Monday 1969-12-29, three days before the epoch.
        let day = |n: i64| i32::try_from(n * per - if per == 7 { 3 } else { 0 }).ok();
        let date = v.parse().ok().and_then(day);
        let date = date.and_then(arrow_array::temporal_conversions::date32_to_datetime);
        date.map_or(v.to_string(), |d| d.date().to_string())
    }

    /// Whether the key is a time period (day, week).
    pub fn is_period(self) -> bool {
        matches!(self, Key::Day | Key::Week)
    }

    /// Parse `robot,week`-style lists (no duplicates, at least one key).
    pub fn parse_list(s: &str) -> anyhow::Result<Vec<Key>> {
        let mut out = Vec::new();
        for part in s.split(',').map(str::trim) {
            let k = match part {
                "robot" => Key::Robot,
                "session" => Key::Session,
                "day" => Key::Day,
                "week" => Key::Week,
                _ => anyhow::bail!(
                    "--by: unknown key {part:?} (expected robot, session, day or week, comma-separated)"
                ),
            };
            if out.contains(&k) {
                anyhow::bail!("--by: {part} given twice");
            }
            out.push(k);
        }
        Ok(out)
    }
}

/// The columns a trial is identified by (robot, session file, trial index in that session).
pub const TRIAL_COLUMNS: [&str; 3] = ["robot", "session", "trial"];

/// A trial: robot, session file, trial index in that session.
pub type TrialId = (String, String, u32);

/// Which rows a query reads.
#[derive(Debug, Clone, Copy)]
pub enum Pick<'a> {
    /// Only the rows of these trials (not none) in these groups (the `--by` keys' SQL values, as the
    /// queries return them): a trial that spans two groups (a session across midnight by day) is
    /// picked in the group that rejected it alone.
    Only(&'a [(Vec<String>, TrialId)]),
    /// Every row but those whose σ_ω exceeds its group's IMU threshold (group key, threshold): a
    /// trial's σ_ω is the same on each of its rows, so these are the IMU filter's rejected trials,
    /// named in one inline row per group however many trials it rejects. A group not listed keeps
    /// every row, and so does a row whose σ_ω is NaN (to the filter NaN exceeds nothing).
    ImuBelow(&'a [(Vec<String>, f64)]),
}

fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "''"))
}

/// `FROM` the row table and the `WHERE` clause (`target`, the user's filter); with `x` =
/// (join, rows of group key values and the rest as SQL, the rest's column names), the inline
/// table `x` joined first on the group keys (and the trial when it names `x_trial`). The inline
/// table comes first in the text: without file statistics the engine builds its joins' hash
/// tables (and buffers a cross join) from the left side, so the row table must be the right one.
fn from_where(keys: &[Key], x: Option<Inline>, target: &str, filter: Option<&str>) -> String {
    let mut conditions = vec![format!("target = {}", quote(target))];
    if let Some(f) = filter {
        conditions.push(format!("({f})"));
    }
    let Some((join, list, names)) = x.filter(|x| !x.1.is_empty()) else {
        return format!("FROM rows\nWHERE {}", conditions.join(" AND "));
    };
    let values: Vec<String> = (list.iter())
        .map(|(key, rest)| {
            let key = keys.iter().zip(*key).map(|(k, v)| match k.is_period() {
                true => v.parse::<i64>().map_or("NULL".into(), |n| n.to_string()),
                false => quote(v),
            });
            format!("({}{rest})", key.map(|v| v + ", ").collect::<String>())
        })
        .collect();
    let cols: String = (0..keys.len()).map(|i| format!("x_k{i}, ")).collect();
    let mut on: Vec<String> = (keys.iter().enumerate())
        .map(|(i, k)| format!("{} = x.x_k{i}", qualify(k.expr())))
        .collect();
    if names.contains("x_trial") {
        on.push("rows.robot = x.x_robot AND rows.session = x.x_session".into());
        on.push("CAST(rows.trial AS BIGINT) = x.x_trial".into());
    }
    if join == "RIGHT JOIN" {
        // Only the IMU thresholds are right-joined: the rows of groups not listed are kept.
        let keep = "(x.x_imu IS NULL OR rows.sigma_omega <= x.x_imu OR isnan(rows.sigma_omega))";
        conditions.push(keep.into());
    }
    format!(
        "FROM (VALUES {}) AS x({cols}{names}) {join} rows ON {}\nWHERE {}",
        values.join(", "),
        on.join(" AND "),
        conditions.join(" AND ")
    )
}

/// An inline table for [`from_where`]: the join, its rows (group key, the rest as SQL) and the
/// rest's column names.
type Inline<'a> = (&'static str, Vec<(&'a [String], String)>, String);

/// The pick's inline table: trials joined to keep them, or groups' IMU thresholds right-joined.
fn picked(pick: Pick) -> Inline {
    match pick {
        Pick::Only(list) => {
            let rows = (list.iter())
                .map(|(key, (r, s, t))| (&key[..], format!("{}, {}, {t}", quote(r), quote(s))))
                .collect();
            ("JOIN", rows, "x_robot, x_session, x_trial".into())
        }
        Pick::ImuBelow(list) => {
            let rows = (list.iter())
                .map(|(key, t)| (&key[..], format!("{t:e}")))
                .collect();
            ("RIGHT JOIN", rows, "x_imu".into())
        }
    }
}

/// `SELECT` key expressions and the `GROUP BY` list, with the trial columns when `per_trial`.
fn grouping(keys: &[Key], per_trial: bool) -> (Vec<String>, Vec<String>) {
    let mut select: Vec<String> = keys
        .iter()
        .map(|k| format!("{} AS {}", qualify(k.expr()), k.name()))
        .collect();
    let mut group: Vec<String> = keys.iter().map(|k| qualify(k.expr())).collect();
    if per_trial {
        for c in TRIAL_COLUMNS {
            select.push(format!("rows.{c} AS trial_{c}"));
            if !group.contains(&format!("rows.{c}")) {
                group.push(format!("rows.{c}"));
            }
        }
    }
    (select, group)
}

/// Column references of the row table qualified with `rows.` (the pick's join has columns of its own).
fn qualify(expr: &str) -> String {
    match expr {
        "robot" | "session" => format!("rows.{expr}"),
        e => e.replace("t_ns", "rows.t_ns"),
    }
}

/// Per trial of each group: rows `n`, its first and last reading time `t_min`/`t_max` [ns] and
/// σ_ω (the trial's IMU statistic, the same on each of its rows): what the IMU filter needs.
pub fn moments(keys: &[Key], target: &str, filter: Option<&str>) -> String {
    let (mut select, group) = grouping(keys, true);
    select.push("COUNT(*) AS n, MIN(rows.t_ns) AS t_min, MAX(rows.t_ns) AS t_max".into());
    select.push("MAX(rows.sigma_omega) AS sigma_omega".into());
    format!(
        "SELECT {}\n{}\nGROUP BY {}",
        select.join(", "),
        from_where(keys, None, target, filter),
        group.join(", ")
    )
}

/// Per trial of the groups in `thetas` (group key, θ): rows `n` and the sum of its residuals
/// y − φ·θ under its group's θ, `s_resid` (what a residual pass needs). θ enters as double
/// literals (`1.25e-1`; a plain `0.125` is a decimal to some engines).
pub fn residuals(
    keys: &[Key],
    thetas: &[(Vec<String>, [f64; N_PARAMS])],
    target: &str,
    filter: Option<&str>,
) -> String {
    let (mut select, group) = grouping(keys, true);
    let fit: Vec<String> = (0..N_PARAMS)
        .map(|p| format!("x.t_{p} * rows.{}", phi_column(p)))
        .collect();
    select.push(format!(
        "COUNT(*) AS n, SUM(rows.y_w - ({})) AS s_resid",
        fit.join(" + ")
    ));
    let rows = (thetas.iter())
        .map(|(key, t)| {
            let t: Vec<String> = t.iter().map(|v| format!("{v:e}")).collect();
            (&key[..], t.join(", "))
        })
        .collect();
    let names: Vec<String> = (0..N_PARAMS).map(|p| format!("t_{p}")).collect();
    let x = ("JOIN", rows, names.join(", "));
    format!(
        "SELECT {}\n{}\nGROUP BY {}",
        select.join(", "),
        from_where(keys, Some(x), target, filter),
        group.join(", ")
    )
}

/// Entries of the row vector (φ_0 … φ_48, y) each row of a [`normal_equations`] result holds.
/// The engine's SQL planner costs about the square of a query's aggregate count (≈ 1 s for the
/// 1,275 sums of the triangle), so the rows are unnested into `BLOCKS` copies, copy `b` holding
/// `BLOCK` rows of the matrix: `BLOCK` × 50 sums (docs/fleet.md, How the fit runs).
pub const BLOCK: usize = 10;

/// The number of row blocks: 50 entries of (φ, y) in blocks of [`BLOCK`].
pub const BLOCKS: usize = (N_PARAMS + 1).div_ceil(BLOCK);

/// The normal equations of each group's picked rows, as one result row per group and block `b`:
/// `n`, Σy `sy` (the same in each block) and `g_a_j` = Σ x_i·x_j for i = b·BLOCK + a, j = 0…49,
/// over x = (φ_0 … φ_48, y): ΦᵀΦ, Φᵀy (j = 49) and yᵀy (i = j = 49).
pub fn normal_equations(keys: &[Key], pick: Pick, target: &str, filter: Option<&str>) -> String {
    let (mut inner, _) = grouping(keys, false);
    let x: Vec<String> = (0..N_PARAMS)
        .map(phi_column)
        .chain(["y_w".into()])
        .collect();
    inner.extend(x.iter().map(|c| format!("rows.{c} AS {c}")));
    let group: Vec<&str> = keys.iter().map(|k| k.name()).collect();
    let mut blocked: Vec<String> = group.iter().map(|k| format!("r.{k} AS {k}")).collect();
    blocked.push("b.b AS b".into());
    blocked.extend(x.iter().map(|c| format!("r.{c} AS {c}")));
    for a in 0..BLOCK {
        let whens: String = (0..BLOCKS)
            .filter_map(|b| {
                x.get(b * BLOCK + a)
                    .map(|c| format!(" WHEN {b} THEN r.{c}"))
            })
            .collect();
        blocked.push(format!("CASE b.b{whens} ELSE 0 END AS v_{a}"));
    }
    let group = group.join(", ");
    let mut select = vec![
        format!("{group}, b"),
        "COUNT(*) AS n, SUM(y_w) AS sy".into(),
    ];
    for a in 0..BLOCK {
        select
            .extend((x.iter().enumerate()).map(|(j, c)| format!("SUM(v_{a} * {c}) AS g_{a}_{j}")));
    }
    let blocks: Vec<String> = (0..BLOCKS).map(|b| format!("({b})")).collect();
    format!(
        "SELECT {}\nFROM (SELECT {}\nFROM (VALUES {}) AS b(b) CROSS JOIN (SELECT {}\n{}) AS r) AS e\nGROUP BY {group}, b",
        select.join(", "),
        blocked.join(", "),
        blocks.join(", "),
        inner.join(", "),
        from_where(keys, Some(picked(pick)), target, filter),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_parse_and_queries_name_their_columns() {
        assert_eq!(
            Key::parse_list("robot, week").unwrap(),
            vec![Key::Robot, Key::Week]
        );
        assert!(Key::parse_list("robot,robot").is_err());
        assert!(Key::parse_list("month").is_err());
        // Expected dates from Python's datetime.
        assert_eq!(Key::Week.show("2932"), "2026-03-09");
        assert_eq!(Key::Week.show("-1"), "1969-12-22");
        assert_eq!(Key::Day.show("20526"), "2026-03-14");
        assert_eq!(Key::Day.show("-1"), "1969-12-31");
        assert_eq!(Key::Robot.show("g1_00"), "g1_00");
        let picked = [(
            vec!["r'1".to_string(), "20526".to_string()],
            ("r'1".to_string(), "a.mcap".to_string(), 3),
        )];
        let q = normal_equations(&[Key::Robot, Key::Day], Pick::Only(&picked), "mbs", None);
        assert!(q.contains("('r''1', 20526, 'r''1', 'a.mcap', 3)"), "{q}");
        assert!(
            q.contains("CAST(FLOOR(rows.t_ns / 8.64e13) AS BIGINT) = x.x_k1"),
            "{q}"
        );
        assert!(q.contains("g_9_49") && !q.contains("g_10_0"));
        assert!(q.contains("GROUP BY robot, day, b"));
        let imu = [(vec!["r'1".to_string()], 0.125)];
        let q = normal_equations(&[Key::Robot], Pick::ImuBelow(&imu), "mbs", None);
        assert!(
            q.contains("FROM (VALUES ('r''1', 1.25e-1)) AS x(x_k0, x_imu) RIGHT JOIN rows"),
            "{q}"
        );
        assert!(q.contains("rows.sigma_omega <= x.x_imu"), "{q}");
        assert!(!normal_equations(&[Key::Robot], Pick::ImuBelow(&[]), "mbs", None).contains("x_"));
    }
}
