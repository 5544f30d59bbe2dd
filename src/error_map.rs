//! The error map: certified per-cell bounds of `‖N − v‖∞` for one network, stored beside it
//! (`<network stem>.errormap.json`, [`error_map_path`]), so that reachability can use a local
//! bound over the cells that a box meets ([`ErrorMap::local_bound`]) instead of the global
//! `M_C`; [`resolve_margin`] turns a scenario's `m_c = "certified"` / `"measured"` into a number.
//! It may import boxes and the scenario; not the error analysis that writes the maps
//! (`surrogate_error`), so that the engines read them without it.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::boxes::IntervalBox;
use crate::provenance::{Fnv, Provenance};
use crate::scenario::{Margin, Scenario};

/// Why an error map could not be read, written or used.
#[derive(Debug, thiserror::Error)]
pub enum ErrorMapError {
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// An error map file is not valid.
    #[error("{path}: not a valid error map: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The error map was computed for another network (its file changed since).
    #[error("{path} was computed for another version of {network} (run `cbfreach error` again)")]
    StaleMap {
        /// The error map.
        path: PathBuf,
        /// The network file.
        network: PathBuf,
    },
    /// The map records no provenance (it predates it): what it certifies against is unknown.
    #[error("{path} records no provenance (the network, filter, region and norm it was certified for); run `cbfreach error` again (or `cbfreach error --restamp` for a map known to be made for this scenario)")]
    Unstamped {
        /// The error map.
        path: PathBuf,
    },
    /// The map was certified against something else: what changed since.
    #[error("{path} was certified for another version of {what} (run `cbfreach error` again)")]
    Changed {
        /// The error map.
        path: PathBuf,
        /// What changed, in words.
        what: String,
    },
    /// The map's cells are not the ones it was written with (edited or cut short).
    #[error("{path}: its cells are not the ones it was written with ({count} now); run `cbfreach error` again")]
    CellsChanged {
        /// The error map.
        path: PathBuf,
        /// Cells found.
        count: usize,
    },
    /// The map's cells leave part of the region out (where nothing is certified).
    #[error("{path}: its cells do not cover the region: {count} piece(s) uncovered, e.g. {lower:?}..{upper:?}")]
    Uncovered {
        /// The error map.
        path: PathBuf,
        /// Uncovered pieces found (up to a limit).
        count: usize,
        /// The first piece's lower corner.
        lower: Vec<f64>,
        /// Its upper corner.
        upper: Vec<f64>,
    },
    /// The map has no certified bound (the filter is a general QP).
    #[error("{path} holds no certified bound (the scenario's filter has too many active sets to certify); use a number or \"measured\"")]
    NotCertified {
        /// The error map.
        path: PathBuf,
    },
    /// A box that the map does not cover.
    #[error("box {lower:?}..{upper:?} is not inside the mapped region {region_lower:?}..{region_upper:?}")]
    OutsideMap {
        /// The box's lower corner.
        lower: Vec<f64>,
        /// The box's upper corner.
        upper: Vec<f64>,
        /// The region's lower corner.
        region_lower: Vec<f64>,
        /// The region's upper corner.
        region_upper: Vec<f64>,
    },
}

/// One cell of an error map and its certified bound.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CellBound {
    /// Lower corner.
    pub lower: Vec<f64>,
    /// Upper corner.
    pub upper: Vec<f64>,
    /// `sup ‖N(x) − v(x)‖∞` over `cell ∩ S` is at most this (+∞, written `"inf"`, when
    /// nothing could be certified on the cell).
    #[serde(with = "inf_as_string")]
    pub bound: f64,
}

impl CellBound {
    /// The cell as a box.
    pub fn cell(&self) -> IntervalBox {
        IntervalBox {
            lower: self.lower.clone(),
            upper: self.upper.clone(),
        }
    }

    /// Whether the (closed) cell meets the (closed) box.
    pub fn meets(&self, b: &IntervalBox) -> bool {
        (0..self.lower.len()).all(|i| self.lower[i] <= b.upper[i] && b.lower[i] <= self.upper[i])
    }
}

/// The certified per-cell error bounds of one network, stored beside it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorMap {
    /// Format tag, `cbfreach-errormap-1`.
    pub format: String,
    /// The network file's name (informational).
    pub network: String,
    /// FNV-1a 64 of the network file's bytes, hex: a map for another file is refused.
    pub network_hash: String,
    /// The mapped region `C`.
    pub region: IntervalBox,
    /// The norm of the bounds (`inf`).
    pub norm: String,
    /// Measured `max ‖N − v‖∞` over a grid of `C ∩ S`.
    pub measured_linf: f64,
    /// Measured `max ‖N − v‖₂`.
    pub measured_l2: f64,
    /// The certified global bound (max over the cells; `"inf"` when some cell could not be
    /// certified), `None` for a QP filter.
    #[serde(with = "opt_inf_as_string")]
    pub certified_linf: Option<f64>,
    /// Cells with their bounds; they tile `region` ([`ErrorMap::load_certified`] checks it).
    /// Cells proven to miss `S` (where the filtered system never goes) have bound 0.
    pub cells: Vec<CellBound>,
    /// What the map certifies against ([`ErrorMap::stamp`]); `None` in maps that predate it,
    /// which [`ErrorMap::load_certified`] refuses.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub provenance: Option<Provenance>,
    /// [`ErrorMap::cells_digest`] when stamped: a map whose cells were edited is refused.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cells_hash: Option<String>,
    /// A tree over the cells for [`ErrorMap::local_bound`], built on first use (not serialised; a
    /// map whose `cells` are changed afterwards must be rebuilt with [`ErrorMap::reindexed`]).
    #[serde(skip)]
    index: LazyIndex,
}

/// The lazily built [`CellIndex`]; a cache, so it takes no part in equality.
#[derive(Clone, Debug, Default)]
struct LazyIndex(std::sync::OnceLock<CellIndex>);

impl PartialEq for LazyIndex {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// A bounding-volume tree over the cells for [`ErrorMap::local_bound`]: each node holds the
/// hull of its cells and their largest bound, so that a query descends only into nodes that
/// meet the box and could raise the maximum found so far. It takes `O(K)` memory in any
/// dimension (a uniform bucket grid over a tree of cells of many sizes does not: a large cell
/// lands in many buckets, a small one on a bucket corner in up to `2ⁿ`), and a query visits
/// `O(log K)` nodes plus those along the box's boundary.
#[derive(Clone, Debug, Default)]
struct CellIndex {
    n: usize,
    /// Per node: its hull, `lower` then `upper` (`2n` numbers).
    hull: Vec<f64>,
    /// Per node: the largest bound of its cells.
    max: Vec<f64>,
    /// Per node: `[first, end)` in `order` for a leaf (`kids == 0`), else its children's
    /// indices.
    span: Vec<[u32; 2]>,
    kids: Vec<bool>,
    /// Cells, permuted so that every node's cells are one run.
    order: Vec<u32>,
}

/// Cells per leaf of [`CellIndex`].
const LEAF_CELLS: usize = 8;

impl CellIndex {
    fn build(n: usize, cells: &[CellBound]) -> CellIndex {
        let mut idx = CellIndex {
            n,
            order: (0..cells.len() as u32).collect(),
            ..CellIndex::default()
        };
        if !cells.is_empty() {
            idx.node(cells, 0, cells.len());
        }
        idx
    }

    /// Builds the node over `order[first..end]` and returns its index.
    fn node(&mut self, cells: &[CellBound], first: usize, end: usize) -> u32 {
        let n = self.n;
        let mut lo = vec![f64::INFINITY; n];
        let mut hi = vec![f64::NEG_INFINITY; n];
        let mut max = f64::NEG_INFINITY;
        for &k in &self.order[first..end] {
            let c = &cells[k as usize];
            for i in 0..n {
                lo[i] = lo[i].min(c.lower[i]);
                hi[i] = hi[i].max(c.upper[i]);
            }
            max = max.max(c.bound);
        }
        let id = self.max.len();
        self.hull.extend(lo.iter().chain(&hi));
        self.max.push(max);
        self.span.push([first as u32, end as u32]);
        self.kids.push(false);
        if end - first > LEAF_CELLS {
            // Split at the median centre along the hull's widest axis.
            let axis = (0..n)
                .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
                .unwrap_or(0);
            let mid = first + (end - first) / 2;
            let centre = |k: &u32| cells[*k as usize].lower[axis] + cells[*k as usize].upper[axis];
            self.order[first..end]
                .select_nth_unstable_by(mid - first, |a, b| centre(a).total_cmp(&centre(b)));
            let left = self.node(cells, first, mid);
            let right = self.node(cells, mid, end);
            self.span[id] = [left, right];
            self.kids[id] = true;
        }
        id as u32
    }

    /// The largest bound of the cells that meet `[lower, upper]` (−∞ when none does).
    fn max_meeting(&self, cells: &[CellBound], lower: &[f64], upper: &[f64]) -> f64 {
        let n = self.n;
        let mut worst = f64::NEG_INFINITY;
        if self.max.is_empty() {
            return worst;
        }
        let mut stack = vec![0u32];
        while let Some(id) = stack.pop() {
            let id = id as usize;
            let hull = &self.hull[2 * n * id..2 * n * (id + 1)];
            if self.max[id] <= worst || (0..n).any(|i| hull[i] > upper[i] || lower[i] > hull[n + i])
            {
                continue;
            }
            let [a, b] = self.span[id];
            if self.kids[id] {
                stack.push(a);
                stack.push(b);
            } else {
                for &k in &self.order[a as usize..b as usize] {
                    let c = &cells[k as usize];
                    if (0..n).all(|i| c.lower[i] <= upper[i] && lower[i] <= c.upper[i]) {
                        worst = worst.max(c.bound);
                    }
                }
            }
        }
        worst
    }
}

/// JSON has no ∞: a non-finite bound is written as the string `"inf"`.
mod inf_as_string {
    use serde::{Deserialize, Deserializer, Serializer};

    #[derive(Deserialize)]
    #[serde(untagged)]
    pub(super) enum NumOrText {
        Num(f64),
        Text(String),
    }

    /// A text other than `"inf"` where a bound belongs.
    #[derive(Debug, thiserror::Error)]
    #[error("`{0}` is not a bound (a number or \"inf\")")]
    pub(super) struct NotABound(String);

    pub(super) fn to_f64(v: NumOrText) -> Result<f64, NotABound> {
        match v {
            NumOrText::Num(x) => Ok(x),
            NumOrText::Text(s) if s == "inf" => Ok(f64::INFINITY),
            NumOrText::Text(s) => Err(NotABound(s)),
        }
    }

    pub fn serialize<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
        if x.is_finite() {
            s.serialize_f64(*x)
        } else {
            s.serialize_str("inf")
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        to_f64(NumOrText::deserialize(d)?).map_err(serde::de::Error::custom)
    }
}

/// [`inf_as_string`] for an optional bound (`null` for `None`).
mod opt_inf_as_string {
    use serde::{Deserialize, Deserializer, Serializer};

    use super::inf_as_string::{to_f64, NumOrText};

    pub fn serialize<S: Serializer>(x: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
        match x {
            None => s.serialize_none(),
            Some(v) => super::inf_as_string::serialize(v, s),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
        Option::<NumOrText>::deserialize(d)?
            .map(to_f64)
            .transpose()
            .map_err(serde::de::Error::custom)
    }
}

/// The format tag of [`ErrorMap`] files.
pub const ERROR_MAP_FORMAT: &str = "cbfreach-errormap-1";

/// Whether `[lo, hi]` is not an interval (inverted or NaN).
fn inverted(lo: f64, hi: f64) -> bool {
    lo.is_nan() || hi.is_nan() || lo > hi
}

/// `<network stem>.errormap.json` beside the network.
pub fn error_map_path(network: &Path) -> PathBuf {
    let stem = network
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "network".into());
    network.with_file_name(format!("{stem}.errormap.json"))
}

pub use crate::provenance::fnv1a_hex;

fn hash_file(path: &Path) -> Result<String, ErrorMapError> {
    let bytes = std::fs::read(path).map_err(|source| ErrorMapError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(fnv1a_hex(&bytes))
}

impl ErrorMap {
    /// A map for the network file `network` from its measured errors (`max ‖N − v‖∞` and
    /// `max ‖N − v‖₂` on a grid) and, when the filter has a closed form, the certified global
    /// bound with the cells that give it. The error analysis builds one from its results with
    /// `ErrorMap::new` (in `surrogate_error`).
    pub fn from_bounds(
        network: &Path,
        region: &IntervalBox,
        measured_linf: f64,
        measured_l2: f64,
        certified: Option<(f64, &[CellBound])>,
    ) -> Result<ErrorMap, ErrorMapError> {
        Ok(ErrorMap {
            format: ERROR_MAP_FORMAT.into(),
            network: network
                .file_name()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            network_hash: hash_file(network)?,
            region: region.clone(),
            norm: "inf".into(),
            measured_linf,
            measured_l2,
            certified_linf: certified.map(|c| c.0),
            cells: certified.map(|c| c.1.to_vec()).unwrap_or_default(),
            provenance: None,
            cells_hash: None,
            index: LazyIndex::default(),
        })
    }

    /// Reads and checks a map file.
    pub fn load(path: &Path) -> Result<ErrorMap, ErrorMapError> {
        let text = std::fs::read_to_string(path).map_err(|source| ErrorMapError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let bad = |message: String| ErrorMapError::Format {
            path: path.to_path_buf(),
            message,
        };
        let map: ErrorMap = serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?;
        if map.format != ERROR_MAP_FORMAT {
            return Err(bad(format!(
                "format `{}`, expected `{ERROR_MAP_FORMAT}`",
                map.format
            )));
        }
        let n = map.region.dim();
        if n == 0
            || map.region.upper.len() != n
            || (0..n).any(|i| inverted(map.region.lower[i], map.region.upper[i]))
        {
            return Err(bad("`region` is not a box".into()));
        }
        for (k, c) in map.cells.iter().enumerate() {
            if c.lower.len() != n
                || c.upper.len() != n
                || (0..n).any(|i| inverted(c.lower[i], c.upper[i]))
                || c.bound.is_nan()
                || c.bound < 0.0
            {
                return Err(bad(format!("cell {k} is malformed")));
            }
        }
        Ok(map)
    }

    /// Loads the map beside `network` and checks that it was made for that file.
    pub fn load_for(network: &Path) -> Result<ErrorMap, ErrorMapError> {
        let path = error_map_path(network);
        let map = ErrorMap::load(&path)?;
        if map.network_hash != hash_file(network)? {
            return Err(ErrorMapError::StaleMap {
                path,
                network: network.to_path_buf(),
            });
        }
        Ok(map)
    }

    /// Loads the map beside `network` for use with scenario `s`: refused unless it was
    /// certified for this network file, this filter, region and norm (naming what changed),
    /// its cells are the ones it was written with, and they cover the region.
    pub fn load_certified(network: &Path, s: &Scenario) -> Result<ErrorMap, ErrorMapError> {
        let path = error_map_path(network);
        let map = ErrorMap::load(&path)?;
        let io = |source| ErrorMapError::Io {
            path: network.to_path_buf(),
            source,
        };
        let Some(was) = &map.provenance else {
            return Err(ErrorMapError::Unstamped { path });
        };
        let changes = was.changes(&Provenance::of(s, network, &map.norm).map_err(io)?);
        if !changes.is_empty() {
            return Err(ErrorMapError::Changed {
                path,
                what: changes.join(" and "),
            });
        }
        if map.cells_hash.as_deref() != Some(map.cells_digest().as_str()) {
            return Err(ErrorMapError::CellsChanged {
                count: map.cells.len(),
                path,
            });
        }
        if map.certified_linf.is_some() {
            let boxes: Vec<IntervalBox> = map.cells.iter().map(CellBound::cell).collect();
            let gaps = crate::provenance::uncovered(&map.region, &boxes, 100);
            if let Some(g) = gaps.first() {
                return Err(ErrorMapError::Uncovered {
                    path,
                    count: gaps.len(),
                    lower: g.lower.clone(),
                    upper: g.upper.clone(),
                });
            }
        }
        Ok(map)
    }

    /// The hash of the cells and the global numbers, which [`ErrorMap::stamp`] records.
    pub fn cells_digest(&self) -> String {
        let mut h = Fnv::default();
        h.bytes(b"cells-1")
            .f64(self.measured_linf)
            .f64(self.measured_l2)
            .f64(self.certified_linf.unwrap_or(f64::NAN))
            .usize(self.cells.len());
        for c in &self.cells {
            for (&l, &u) in c.lower.iter().zip(&c.upper) {
                h.f64(l).f64(u);
            }
            h.f64(c.bound);
        }
        h.hex()
    }

    /// Records what the map certifies against: scenario `s`'s filter, region and norm, and the
    /// network file `network`; and the hash of its cells. Call it when the map is final.
    pub fn stamp(&mut self, s: &Scenario, network: &Path) -> Result<(), ErrorMapError> {
        let provenance =
            Provenance::of(s, network, &self.norm).map_err(|source| ErrorMapError::Io {
                path: network.to_path_buf(),
                source,
            })?;
        self.network_hash = provenance.network.clone();
        self.provenance = Some(provenance);
        self.cells_hash = Some(self.cells_digest());
        Ok(())
    }

    /// Writes the map as JSON, atomically (a failed write leaves the old file).
    pub fn save(&self, path: &Path) -> Result<(), ErrorMapError> {
        let text = serde_json::to_string(self).map_err(|e| ErrorMapError::Format {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        crate::output::write_atomic(path, text.as_bytes()).map_err(|source| ErrorMapError::Io {
            path: path.to_path_buf(),
            source,
        })
    }

    /// The largest finite cell bound: `M_C` over `C ∩ S` minus the cells with no bound.
    pub fn finite_max(&self) -> f64 {
        self.cells
            .iter()
            .map(|c| c.bound)
            .filter(|b| b.is_finite())
            .fold(0.0, f64::max)
    }

    /// Whether every cell has a finite certified bound (the cells cover the region). Read
    /// from the cell index's root, the largest bound (asked where every tube ends without a
    /// bound: not a scan of the cells each time).
    pub fn certified_everywhere(&self) -> bool {
        let index = self
            .index
            .0
            .get_or_init(|| CellIndex::build(self.region.dim(), &self.cells));
        self.certified_linf.is_some() && index.max.first().is_none_or(|m| m.is_finite())
    }

    /// The certified bound of `‖N − v‖∞` over `b ∩ S`: the max over the cells that meet `b` (0
    /// when `b` meets only cells proven unsafe, +∞ when it meets none). +∞ when `b` is not inside the mapped region (or
    /// the map holds no certified cells); see [`ErrorMap::try_local_bound`] for an error instead.
    pub fn local_bound(&self, b: &IntervalBox) -> f64 {
        self.try_local_bound(b).unwrap_or(f64::INFINITY)
    }

    /// As [`ErrorMap::local_bound`], with an error for a box outside the region.
    pub fn try_local_bound(&self, b: &IntervalBox) -> Result<f64, ErrorMapError> {
        if self.certified_linf.is_none() {
            return Ok(f64::INFINITY);
        }
        if b.dim() != self.region.dim() || !b.is_subset_of(&self.region) {
            return Err(ErrorMapError::OutsideMap {
                lower: b.lower.clone(),
                upper: b.upper.clone(),
                region_lower: self.region.lower.clone(),
                region_upper: self.region.upper.clone(),
            });
        }
        let index = self
            .index
            .0
            .get_or_init(|| CellIndex::build(self.region.dim(), &self.cells));
        // A box that meets no cell is where nothing was certified: +∞, never 0.
        let worst = index.max_meeting(&self.cells, &b.lower, &b.upper);
        Ok(if worst == f64::NEG_INFINITY {
            f64::INFINITY
        } else {
            worst
        })
    }

    /// The map with its cell index dropped (to be rebuilt on the next query), for a map
    /// whose `cells` were changed after a query.
    pub fn reindexed(mut self) -> ErrorMap {
        self.index = LazyIndex::default();
        self
    }
}

/// `M_C` for a scenario: its number, or `"certified"` / `"measured"` from the error map beside
/// `network` (written by `cbfreach error`).
pub fn resolve_margin(s: &Scenario, network: &Path) -> Result<f64, ErrorMapError> {
    margin_value(s.reach.m_c, s, network)
}

/// The global `M_C` that `margin` stands for with `network`: a fixed value, or the error
/// map's certified or measured maximum, or (for local bounds) the map's largest finite cell
/// bound. The map must have been certified for `s` ([`ErrorMap::load_certified`]).
pub fn margin_value(margin: Margin, s: &Scenario, network: &Path) -> Result<f64, ErrorMapError> {
    match margin {
        Margin::Value(v) => Ok(v),
        Margin::Measured => Ok(ErrorMap::load_certified(network, s)?.measured_linf),
        Margin::Certified => {
            let map = ErrorMap::load_certified(network, s)?;
            map.certified_linf.ok_or(ErrorMapError::NotCertified {
                path: error_map_path(network),
            })
        }
        // The global number beside local bounds: the largest finite cell bound, which bounds
        // every local M a set can get without being stopped (cells with +∞ stop it).
        Margin::Local => {
            let map = ErrorMap::load_certified(network, s)?;
            if map.certified_linf.is_none() {
                return Err(ErrorMapError::NotCertified {
                    path: error_map_path(network),
                });
            }
            Ok(map.finite_max())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn infinite_bounds_round_trip_through_json() {
        let c = CellBound {
            lower: vec![0.0],
            upper: vec![1.0],
            bound: f64::INFINITY,
        };
        let text = serde_json::to_string(&c).unwrap();
        assert!(text.contains("\"inf\""), "{text}");
        let back: CellBound = serde_json::from_str(&text).unwrap();
        assert_eq!(back.bound, f64::INFINITY);
        assert!(
            serde_json::from_str::<CellBound>(r#"{"lower":[0],"upper":[1],"bound":"x"}"#).is_err()
        );
    }

    #[test]
    fn map_path_sits_beside_the_network() {
        assert_eq!(
            error_map_path(Path::new("scenarios/integrator.safetensors")),
            PathBuf::from("scenarios/integrator.errormap.json")
        );
    }

    /// A bisection tree of cells in 4 states (cells of many sizes, corners shared), queried by
    /// boxes, points and boxes on cell faces: the indexed bound equals a scan of every cell.
    #[test]
    fn tree_index_equals_a_linear_scan_in_four_states() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut rnd = move || rng.random::<f64>();
        let region = IntervalBox::new(vec![0.0, -1.0, 0.0, 5.0], vec![4.0, 1.0, 0.5, 9.0]).unwrap();
        let mut cells = vec![region.clone()];
        while cells.len() < 3000 {
            let k = (rnd() * cells.len() as f64) as usize % cells.len();
            let (l, r) = cells.swap_remove(k).bisect();
            cells.push(l);
            cells.push(r);
        }
        let cells: Vec<CellBound> = cells
            .into_iter()
            .map(|c| CellBound {
                bound: if rnd() < 0.01 { f64::INFINITY } else { rnd() },
                lower: c.lower,
                upper: c.upper,
            })
            .collect();
        let mut map = ErrorMap {
            format: ERROR_MAP_FORMAT.into(),
            network: String::new(),
            network_hash: String::new(),
            region: region.clone(),
            norm: "inf".into(),
            measured_linf: 0.0,
            measured_l2: 0.0,
            certified_linf: Some(f64::INFINITY),
            cells,
            provenance: None,
            cells_hash: None,
            index: LazyIndex::default(),
        };
        let mut queries = 0;
        for k in 0..3000 {
            let b = if k % 4 == 0 {
                // A face or corner of a cell, as a point or a thin box.
                let c = &map.cells[k % map.cells.len()];
                let p: Vec<f64> = (0..4)
                    .map(|i| if rnd() < 0.5 { c.lower[i] } else { c.upper[i] })
                    .collect();
                IntervalBox::new(p.clone(), p).unwrap()
            } else {
                let w = 0.3 * rnd();
                let lo: Vec<f64> = (0..4)
                    .map(|i| region.lower[i] + (region.upper[i] - region.lower[i]) * rnd())
                    .collect();
                let hi = (0..4).map(|i| (lo[i] + w).min(region.upper[i])).collect();
                IntervalBox::new(lo, hi).unwrap()
            };
            let scan = map
                .cells
                .iter()
                .filter(|c| c.meets(&b))
                .map(|c| c.bound)
                .fold(f64::NEG_INFINITY, f64::max);
            assert_eq!(map.local_bound(&b), scan, "{b:?}");
            queries += 1;
        }
        assert!(queries > 2000);
        // A map whose cells leave a hole: a box inside the hole meets none, +∞.
        let hole = map.cells.swap_remove(0);
        map = map.reindexed();
        let inside = IntervalBox::new(hole.cell().center(), hole.cell().center()).unwrap();
        assert_eq!(map.local_bound(&inside), f64::INFINITY);
    }
}
