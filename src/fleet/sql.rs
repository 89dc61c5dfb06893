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
    /// UTC day of the reading (days since 1970-01-01).
    Day,
    /// Week of the reading, Monday to Sunday (weeks since Monday 1969-12-29).
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
    /// Every row.
    All,
    /// Only the rows of these trials.
    Only(&'a [TrialId]),
}

fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "''"))
}

/// `FROM rows …` with the pick's join and the `WHERE` clause (`target`, the user's filter).
fn from_where(pick: Pick, target: &str, filter: Option<&str>) -> String {
    let mut conditions = vec![format!("target = {}", quote(target))];
    if let Some(f) = filter {
        conditions.push(format!("({f})"));
    }
    let from = match pick {
        Pick::All => "rows".to_string(),
        Pick::Only(list) => {
            let values: Vec<String> = list
                .iter()
                .map(|(r, s, t)| format!("({}, {}, {t})", quote(r), quote(s)))
                .collect();
            format!(
                "rows JOIN (VALUES {}) AS x(x_robot, x_session, x_trial) ON rows.robot = x.x_robot \
                 AND rows.session = x.x_session AND CAST(rows.trial AS BIGINT) = x.x_trial",
                if values.is_empty() {
                    "('', '', -1)".to_string()
                } else {
                    values.join(", ")
                }
            )
        }
    };
    format!("FROM {from}\nWHERE {}", conditions.join(" AND "))
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

/// Per trial of each group: rows `n`, Σy `sy`, Σφ_p `s_p` and σ_ω (the trial's IMU statistic,
/// the same on each of its rows). Everything the IMU filter and the residual passes need.
pub fn moments(keys: &[Key], target: &str, filter: Option<&str>) -> String {
    let (mut select, group) = grouping(keys, true);
    select.push("COUNT(*) AS n".into());
    select.push("MAX(rows.sigma_omega) AS sigma_omega".into());
    select.push("SUM(rows.y_w) AS sy".into());
    for p in 0..N_PARAMS {
        select.push(format!("SUM(rows.{}) AS s_{p}", phi_column(p)));
    }
    format!(
        "SELECT {}\n{}\nGROUP BY {}",
        select.join(", "),
        from_where(Pick::All, target, filter),
        group.join(", ")
    )
}

/// The normal equations of each group's picked rows (per trial too when `per_trial`): `n`,
/// Σy `sy`, yᵀy `yy`, Φᵀy `h_p`, the upper triangle of ΦᵀΦ `g_i_j` (i ≤ j), and the first and
/// last reading time `t_min`/`t_max` [ns].
pub fn normal_equations(
    keys: &[Key],
    per_trial: bool,
    pick: Pick,
    target: &str,
    filter: Option<&str>,
) -> String {
    let (mut select, group) = grouping(keys, per_trial);
    select.push("COUNT(*) AS n".into());
    select.push("MIN(rows.t_ns) AS t_min".into());
    select.push("MAX(rows.t_ns) AS t_max".into());
    select.push("SUM(rows.y_w) AS sy".into());
    select.push("SUM(rows.y_w * rows.y_w) AS yy".into());
    for i in 0..N_PARAMS {
        select.push(format!("SUM(rows.{} * rows.y_w) AS h_{i}", phi_column(i)));
    }
    for i in 0..N_PARAMS {
        for j in i..N_PARAMS {
            select.push(format!(
                "SUM(rows.{} * rows.{}) AS g_{i}_{j}",
                phi_column(i),
                phi_column(j)
            ));
        }
    }
    format!(
        "SELECT {}\n{}\nGROUP BY {}",
        select.join(", "),
        from_where(pick, target, filter),
        group.join(", ")
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
        let picked = [("r'1".to_string(), "a.mcap".to_string(), 3)];
        let q = normal_equations(&[Key::Robot], true, Pick::Only(&picked), "mbs", None);
        assert!(q.contains("('r''1', 'a.mcap', 3)"), "{q}");
        assert!(q.contains("g_48_48") && !q.contains("g_1_0"));
        assert!(q.contains("GROUP BY rows.robot, rows.session, rows.trial"));
    }
}
