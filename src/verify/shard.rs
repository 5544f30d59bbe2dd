//! Shards: the K-th of N contiguous slices of a grid's cells, and [`merge`], which joins the
//! reports of shards into one. May import `verify`'s report types.

use std::ops::Range;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use super::{VerifyError, VerifyReport, VerifyTiming, FORMAT};

/// The K-th (1-based) of N contiguous slices of a grid's cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    /// K, in `1..=count`.
    pub index: usize,
    /// N ≥ 1.
    pub count: usize,
}

impl Shard {
    /// The cell indices of this shard among `total` cells: `[⌊(K−1)·total/N⌋, ⌊K·total/N⌋)`.
    pub fn range(&self, total: usize) -> Range<usize> {
        let at = |k: usize| (k as u128 * total as u128 / self.count as u128) as usize;
        at(self.index - 1)..at(self.index)
    }
}

impl FromStr for Shard {
    type Err = VerifyError;

    /// Parses `K/N` with `1 ≤ K ≤ N`.
    fn from_str(s: &str) -> Result<Shard, VerifyError> {
        let bad = |why: &str| VerifyError::Settings {
            field: "shard",
            message: format!(
                "{s}: {why} (expected K/N with 1 ≤ K ≤ N, e.g. 2/8 for the second of 8 slices)"
            ),
        };
        let (k, n) = s.split_once('/').ok_or_else(|| bad("no `/`"))?;
        let k: usize = k
            .trim()
            .parse()
            .map_err(|_| bad("K is not a whole number"))?;
        let n: usize = n
            .trim()
            .parse()
            .map_err(|_| bad("N is not a whole number"))?;
        if n == 0 {
            return Err(bad("N must be at least 1"));
        }
        if k == 0 || k > n {
            return Err(bad("K is out of range (shards are numbered from 1)"));
        }
        Ok(Shard { index: k, count: n })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// Joins shard reports (`(file name, report)`, any order) into one report over the whole grid.
/// They must come from the same run (scenario, region, grid, settings), have the same shard
/// count, and tile the grid's cells without gap or overlap.
pub fn merge(parts: Vec<(String, VerifyReport)>) -> Result<VerifyReport, VerifyError> {
    let Some((first_name, first)) = parts.first().cloned() else {
        return Err(VerifyError::Merge("no files given".into()));
    };
    let total: usize = first.run.grid.iter().product();
    for (name, r) in &parts[1..] {
        if r.run != first.run {
            let (a, b) = (
                serde_json::to_value(&first.run).unwrap_or_default(),
                serde_json::to_value(&r.run).unwrap_or_default(),
            );
            let differs: Vec<String> = match (a, b) {
                (serde_json::Value::Object(a), serde_json::Value::Object(b)) => a
                    .iter()
                    .filter(|(k, v)| b.get(*k) != Some(v))
                    .map(|(k, v)| {
                        format!(
                            "{k}: {v} in {first_name} but {} in {name}",
                            b.get(k).cloned().unwrap_or_default()
                        )
                    })
                    .collect(),
                _ => vec![],
            };
            return Err(VerifyError::Merge(format!(
                "{first_name} and {name} come from different runs ({})",
                differs.join("; ")
            )));
        }
        let count = |r: &VerifyReport| r.shard.map(|s| s.count);
        if count(r) != count(&first) {
            return Err(VerifyError::Merge(format!(
                "{first_name} is shard {} but {name} is shard {} (different shard counts)",
                first.shard.map_or("none".into(), |s| s.to_string()),
                r.shard.map_or("none".into(), |s| s.to_string())
            )));
        }
    }
    let mut parts = parts;
    parts.sort_by_key(|(_, r)| (r.cells[0], r.cells[1]));
    let mut at = 0;
    for (name, r) in &parts {
        if r.cells[1] > total || r.cells[0] > r.cells[1] {
            return Err(VerifyError::Merge(format!(
                "{name}: cells {}..{} do not fit the {total} cells of the grid",
                r.cells[0], r.cells[1]
            )));
        }
        if r.cells[0] < at {
            return Err(VerifyError::Merge(format!(
                "{name} overlaps another file: its cells {}..{} start before {at} (the same shard twice?)",
                r.cells[0], r.cells[1]
            )));
        }
        if r.cells[0] > at {
            return Err(VerifyError::Merge(format!(
                "cells {at}..{} are missing (a shard file not given?)",
                r.cells[0]
            )));
        }
        at = r.cells[1];
    }
    if at != total {
        return Err(VerifyError::Merge(format!(
            "cells {at}..{total} are missing (a shard file not given?)"
        )));
    }
    let mut merged = VerifyReport {
        format: FORMAT.into(),
        run: first.run.clone(),
        shard: None,
        cells: [0, total],
        traps: first.traps.clone(),
        before: Vec::new(),
        after: Vec::new(),
        timing: VerifyTiming::default(),
        what_stops: None,
    };
    for (_, r) in parts {
        merged.before.extend(r.before);
        merged.after.extend(r.after);
        merged.timing.reach_s += r.timing.reach_s;
        merged.timing.total_s += r.timing.total_s;
        merged.timing.equilibria_s += r.timing.equilibria_s;
        merged.timing.boxes_run += r.timing.boxes_run;
        merged.timing.box_steps += r.timing.box_steps;
        merged.timing.integration_steps += r.timing.integration_steps;
    }
    Ok(merged)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_tile_the_cells() {
        for total in [1usize, 7, 100, 4096] {
            for n in 1..=total.min(9) {
                let mut at = 0;
                for k in 1..=n {
                    let r = Shard { index: k, count: n }.range(total);
                    assert_eq!(r.start, at);
                    at = r.end;
                }
                assert_eq!(at, total);
            }
        }
    }

    #[test]
    fn shard_parsing_explains_errors() {
        assert_eq!(
            "2/8".parse::<Shard>().unwrap(),
            Shard { index: 2, count: 8 }
        );
        for bad in ["0/4", "5/4", "1/0", "a/2", "3", "1/-2"] {
            let e = bad.parse::<Shard>().unwrap_err().to_string();
            assert!(e.starts_with("shard: "), "{e}");
        }
    }
}
