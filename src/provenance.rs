//! Provenance: hashes of what a result was computed against (the network file, the filter, the
//! region `C`, the norm), so that a stored result (an error map, a verify checkpoint, a shard) is
//! refused when any of them changed, naming what changed; and [`uncovered`], the parts of a box
//! that a set of cells leaves out (a map must cover `C`). Imports boxes, expressions and the
//! scenario only.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::boxes::IntervalBox;
use crate::error_map::{error_map_path, CellBound, ErrorMap, ErrorMapError};
use crate::expressions::{Expr, Node};
use crate::intervals::Interval;
use crate::scenario::{Norm, Scenario};

/// FNV-1a 64, fed piecewise (bytes, numbers by their bits, tagged nodes).
#[derive(Clone, Copy, Debug)]
pub struct Fnv(u64);

impl Default for Fnv {
    fn default() -> Fnv {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    /// Feeds bytes.
    pub fn bytes(&mut self, bytes: &[u8]) -> &mut Fnv {
        for &b in bytes {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }

    /// Feeds a number by its bits (so 0.3 and 0.30000000000000004 differ).
    pub fn f64(&mut self, x: f64) -> &mut Fnv {
        self.bytes(&x.to_bits().to_le_bytes())
    }

    /// Feeds a count.
    pub fn usize(&mut self, k: usize) -> &mut Fnv {
        self.bytes(&(k as u64).to_le_bytes())
    }

    /// Feeds a text, length first (so that `["ab", "c"]` and `["a", "bc"]` differ).
    pub fn str(&mut self, s: &str) -> &mut Fnv {
        self.usize(s.len()).bytes(s.as_bytes())
    }

    /// Feeds a box.
    pub fn interval_box(&mut self, b: &IntervalBox) -> &mut Fnv {
        self.usize(b.dim());
        for (&l, &u) in b.lower.iter().zip(&b.upper) {
            self.f64(l).f64(u);
        }
        self
    }

    /// Feeds an expression by its tree (not its printed form, so that printing changes do not
    /// invalidate stored results).
    pub fn expr(&mut self, e: &Expr) -> &mut Fnv {
        self.node(e.node())
    }

    fn node(&mut self, n: &Node) -> &mut Fnv {
        match n {
            Node::Const(c) => self.bytes(b"c").f64(*c),
            Node::Var(i) => self.bytes(b"v").usize(*i),
            Node::Neg(a) => self.bytes(b"-").node(a),
            Node::Add(a, b) => self.bytes(b"+").node(a).node(b),
            Node::Sub(a, b) => self.bytes(b"s").node(a).node(b),
            Node::Mul(a, b) => self.bytes(b"*").node(a).node(b),
            Node::Div(a, b) => self.bytes(b"/").node(a).node(b),
            Node::Pow(a, k) => self.bytes(b"^").bytes(&k.to_le_bytes()).node(a),
            Node::Call(f, args) => {
                self.bytes(b"f").str(f.name());
                for a in args {
                    self.node(a);
                }
                self
            }
        }
    }

    /// The hash as 16 hex digits.
    pub fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

/// FNV-1a 64 of a byte string, as 16 hex digits.
pub fn fnv1a_hex(bytes: &[u8]) -> String {
    Fnv::default().bytes(bytes).hex()
}

/// The hash of a network file's bytes.
pub fn network_hash(path: &Path) -> std::io::Result<String> {
    Ok(fnv1a_hex(&std::fs::read(path)?))
}

/// The hash of the filter `v`: the system (`f`, `g`, `κ`, with the parameters substituted), the
/// CBFs (`h`, `α`), the input bounds and the further constraints. Names and comments do not
/// count; anything that changes `v` does.
pub fn filter_hash(s: &Scenario) -> String {
    let mut h = Fnv::default();
    h.bytes(b"filter-1").usize(s.n()).usize(s.m());
    for e in &s.f {
        h.expr(e);
    }
    for row in &s.g {
        for e in row {
            h.expr(e);
        }
    }
    for e in &s.kappa {
        h.expr(e);
    }
    h.usize(s.cbfs.len());
    for c in &s.cbfs {
        h.expr(&c.h);
        // A gain hashes as it did before functions were allowed (the shipped maps' hashes).
        match c.alpha.gain {
            Some(a) => h.f64(a),
            None => h.bytes(b"alpha").expr(&c.alpha.expr),
        };
    }
    match &s.input_bounds {
        Some(b) => h.bytes(b"u").interval_box(b),
        None => h.bytes(b"-"),
    };
    h.usize(s.constraints.len());
    for c in &s.constraints {
        for a in &c.a {
            h.expr(a);
        }
        h.expr(&c.b);
    }
    h.hex()
}

/// The hash of a region.
pub fn region_hash(region: &IntervalBox) -> String {
    Fnv::default().bytes(b"region-1").interval_box(region).hex()
}

fn norm_name(n: Norm) -> &'static str {
    match n {
        Norm::Inf => "inf",
        Norm::One => "1",
        Norm::Two => "2",
    }
}

/// What a stored result was computed against.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Provenance {
    /// [`network_hash`] of the network file.
    pub network: String,
    /// [`filter_hash`] of the scenario.
    pub filter: String,
    /// [`region_hash`] of `C`.
    pub region: String,
    /// The norm of the bounds and of the scenario's closeness radius (`inf/inf`).
    pub norm: String,
}

impl Provenance {
    /// The provenance of a result for scenario `s` with the network file `network` and bounds
    /// in the norm `norm` (`"inf"` for the error map).
    pub fn of(s: &Scenario, network: &Path, norm: &str) -> std::io::Result<Provenance> {
        Ok(Provenance {
            network: network_hash(network)?,
            filter: filter_hash(s),
            region: region_hash(&s.reach.region),
            norm: format!("{norm}/{}", norm_name(s.reach.norm)),
        })
    }

    /// What differs from `now`, in words (empty when nothing does).
    pub fn changes(&self, now: &Provenance) -> Vec<&'static str> {
        let mut out = Vec::new();
        if self.network != now.network {
            out.push("the network file");
        }
        if self.filter != now.filter {
            out.push("the filter (system, CBFs, constraints or parameters)");
        }
        if self.region != now.region {
            out.push("the region C");
        }
        if self.norm != now.norm {
            out.push("the norm");
        }
        out
    }
}

/// The parts of `region` that no cell covers (closed cells; empty when they cover it), at
/// most `limit` of them. Cells that tile `region` by grid cuts and bisections share their cut
/// coordinates exactly, so this is exact for them; a gap of any width is found.
pub fn uncovered(region: &IntervalBox, cells: &[IntervalBox], limit: usize) -> Vec<IntervalBox> {
    let idx: Vec<usize> = (0..cells.len()).collect();
    let mut out = Vec::new();
    // An explicit stack: a deep recursion on a hostile file must not overflow.
    let mut stack = vec![(region.clone(), idx)];
    while let Some((piece, meeting)) = stack.pop() {
        if out.len() >= limit {
            break;
        }
        let meeting: Vec<usize> = meeting
            .into_iter()
            .filter(|&k| overlaps_open(&cells[k], &piece))
            .collect();
        if meeting.is_empty() {
            out.push(piece);
            continue;
        }
        if meeting.iter().any(|&k| piece.is_subset_of(&cells[k])) {
            continue;
        }
        // Cut at a face of a meeting cell strictly inside the piece: the widest such cut.
        let mut cut: Option<(usize, f64, f64)> = None;
        for &k in &meeting {
            let c = &cells[k];
            for i in 0..piece.dim() {
                for x in [c.lower[i], c.upper[i]] {
                    if piece.lower[i] < x && x < piece.upper[i] {
                        let balance = (x - piece.lower[i]).min(piece.upper[i] - x);
                        if cut.is_none_or(|(_, _, b)| balance > b) {
                            cut = Some((i, x, balance));
                        }
                    }
                }
            }
        }
        // A cell meets the piece's interior and does not contain it, so one of its faces cuts
        // the piece; NaN corners (refused when loading) would end here.
        let Some((i, x, _)) = cut else {
            out.push(piece);
            continue;
        };
        let mut lo = piece.clone();
        let mut hi = piece;
        lo.upper[i] = x;
        hi.lower[i] = x;
        stack.push((lo, meeting.clone()));
        stack.push((hi, meeting));
    }
    out
}

/// Stamps a map that predates provenance with scenario `s` and its network file `network`,
/// for a map known to have been certified for them (the shipped maps): the map must have been
/// made for this network file; the parts of `C` its cells leave out (the cells the
/// certification dropped) get bound 0 where interval evaluation proves some `hᵢ < 0` on them
/// (as the certification proved), else +∞. Returns the number of cells added.
pub fn restamp(map: &mut ErrorMap, s: &Scenario, network: &Path) -> Result<usize, ErrorMapError> {
    let path = error_map_path(network);
    let io = |source| ErrorMapError::Io {
        path: network.to_path_buf(),
        source,
    };
    let now = Provenance::of(s, network, &map.norm).map_err(io)?;
    if map.network_hash != now.network {
        return Err(ErrorMapError::StaleMap {
            path,
            network: network.to_path_buf(),
        });
    }
    if let Some(was) = &map.provenance {
        let changes = was.changes(&now);
        if !changes.is_empty() {
            return Err(ErrorMapError::Changed {
                path,
                what: changes.join(" and "),
            });
        }
    }
    if map.region != s.reach.region {
        return Err(ErrorMapError::Changed {
            path,
            what: "the region C".into(),
        });
    }
    let boxes: Vec<IntervalBox> = map.cells.iter().map(|c| c.cell()).collect();
    let gaps = if map.certified_linf.is_some() {
        uncovered(&map.region, &boxes, usize::MAX)
    } else {
        Vec::new()
    };
    let before = map.cells.len();
    for gap in gaps {
        // A piece that is not proven unsafe whole may be in halves.
        let mut todo = vec![(gap, 0)];
        while let Some((b, depth)) = todo.pop() {
            let bound = if misses_safe_set(s, &b) {
                0.0
            } else if depth < 6 {
                let (l, r) = b.bisect();
                todo.push((l, depth + 1));
                todo.push((r, depth + 1));
                continue;
            } else {
                f64::INFINITY
            };
            map.cells.push(CellBound {
                lower: b.lower,
                upper: b.upper,
                bound,
            });
        }
    }
    if map.cells.iter().any(|c| c.bound.is_infinite()) && map.certified_linf.is_some() {
        map.certified_linf = map
            .certified_linf
            .map(|c| map.cells.iter().map(|c| c.bound).fold(c, f64::max));
    }
    let added = map.cells.len() - before;
    // The cells changed: the bucket index is rebuilt on the next query.
    *map = map.clone().reindexed();
    map.stamp(s, network)?;
    Ok(added)
}

/// Whether some `hᵢ < 0` on the whole box (interval evaluation; NaN proves nothing).
fn misses_safe_set(s: &Scenario, b: &IntervalBox) -> bool {
    let x: Vec<Interval> = (0..b.dim())
        .map(|i| Interval::new(b.lower[i], b.upper[i]))
        .collect();
    s.cbfs.iter().any(|c| {
        let h = c.h.eval_interval(&x);
        !h.is_nan() && h.upper < 0.0
    })
}

/// Whether the interiors of two boxes meet (for a degenerate `b`: whether `b` lies in `a`'s
/// closure along its flat axes and meets its interior along the others).
fn overlaps_open(a: &IntervalBox, b: &IntervalBox) -> bool {
    (0..a.dim()).all(|i| {
        if b.lower[i] == b.upper[i] {
            a.lower[i] <= b.lower[i] && b.lower[i] <= a.upper[i]
        } else {
            a.lower[i] < b.upper[i] && b.lower[i] < a.upper[i]
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bx(l: &[f64], u: &[f64]) -> IntervalBox {
        IntervalBox::new(l.to_vec(), u.to_vec()).unwrap()
    }

    #[test]
    fn a_tiling_covers_and_a_removed_cell_is_found() {
        let region = bx(&[-1.0, 0.0], &[2.0, 0.3]);
        let mut cells = region.partition(&[3, 7]);
        let (l, r) = cells[5].bisect();
        cells[5] = l;
        cells.push(r);
        assert!(uncovered(&region, &cells, 10).is_empty());
        let removed = cells.remove(9);
        let gaps = uncovered(&region, &cells, 10);
        assert_eq!(gaps.len(), 1);
        assert_eq!(gaps[0], removed);
    }

    #[test]
    fn a_sliver_gap_is_found() {
        let region = bx(&[0.0], &[1.0]);
        let cells = vec![bx(&[0.0], &[0.5]), bx(&[0.5 + 1e-15], &[1.0])];
        assert_eq!(uncovered(&region, &cells, 10).len(), 1);
    }

    #[test]
    fn hashes_see_every_part() {
        assert_ne!(
            region_hash(&bx(&[0.0], &[1.0])),
            region_hash(&bx(&[0.0], &[1.5]))
        );
        let mut a = Fnv::default();
        let mut b = Fnv::default();
        a.str("ab").str("c");
        b.str("a").str("bc");
        assert_ne!(a.hex(), b.hex());
        assert_eq!(fnv1a_hex(b""), "cbf29ce484222325");
    }
}
