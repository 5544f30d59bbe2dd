//! Plotting produces non-empty PNG and SVG files of the requested pixel size.

mod common;

use std::path::Path;

use cbfreach::equilibria::{find_equilibria, EquilibriumSearch};
use cbfreach::filter::SafetyFilter;
use cbfreach::plot::{save, Figure, PlotError};
use cbfreach::simulate::{simulate_filtered, Integrator};

/// Width and height from a PNG's IHDR chunk.
fn png_size(bytes: &[u8]) -> (u32, u32) {
    assert!(bytes.len() > 24, "PNG too short");
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "not a PNG signature");
    assert_eq!(&bytes[12..16], b"IHDR", "first chunk is not IHDR");
    let be = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
    (be(&bytes[16..20]), be(&bytes[20..24]))
}

fn trajectories_figure(out: &Path, size: (u32, u32)) -> Result<(), PlotError> {
    let s = common::integrator();
    let filter = SafetyFilter::new(&s);
    let found = find_equilibria(&filter, &s.reach.region, &EquilibriumSearch::default());
    let t: Vec<_> = s
        .reach
        .initial
        .iter()
        .map(|b| simulate_filtered(&filter, &b.center(), s.reach.dt, 100, Integrator::Euler))
        .collect();
    save(
        &Figure::Trajectories {
            scenario: &s,
            trajectories: &t,
            equilibria: &found,
        },
        out,
        size,
    )
}

#[test]
fn png_and_svg_have_the_requested_size() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let png = dir.join("fig1.png");
    trajectories_figure(&png, (640, 480)).unwrap();
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(png_size(&bytes), (640, 480));
    assert!(
        bytes.len() > 5_000,
        "suspiciously small PNG: {} bytes",
        bytes.len()
    );

    let svg = dir.join("fig1.svg");
    trajectories_figure(&svg, (800, 600)).unwrap();
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.contains("<svg"), "not an SVG");
    assert!(text.contains("width=\"800\"") && text.contains("height=\"600\""));
    // Axis names and the legend are drawn as text.
    assert!(
        text.contains("x1") && text.contains("saddle"),
        "labels missing"
    );
}

#[test]
fn unknown_extension_and_bad_size_are_errors() {
    // Nothing should be written, but if it were, it lands in a directory removed on drop.
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let e = trajectories_figure(&dir.join("fig.jpg"), (640, 480)).unwrap_err();
    assert!(matches!(e, PlotError::Format(_)), "{e}");
    assert!(e.to_string().contains(".png or .svg"));
    let e = trajectories_figure(&dir.join("fig.png"), (10, 480)).unwrap_err();
    assert!(e.to_string().contains("pixels"), "{e}");
}

#[test]
fn error_map_colours_each_cell_by_its_certified_bound() {
    use cbfreach::error_map::ErrorMap;
    use cbfreach::plot::{error_class, ERROR_CLASSES};
    // Class edges are inclusive above, and +∞ (not certified) has a class of its own.
    assert_eq!(ERROR_CLASSES, [0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5]);
    assert_eq!(error_class(0.0), 0);
    assert_eq!(error_class(0.005), 0);
    assert_eq!(error_class(0.0051), 1);
    assert_eq!(error_class(0.321), 6);
    assert_eq!(error_class(0.51), 7);
    assert_eq!(error_class(f64::INFINITY), 8);

    let s = common::integrator();
    let map = ErrorMap::load_for(&common::scenario_path("integrator.safetensors")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let svg = dir.join("map.svg");
    save(
        &Figure::ErrorMap {
            scenario: &s,
            map: &map,
        },
        &svg,
        (1000, 790),
    )
    .unwrap();
    let text = std::fs::read_to_string(&svg).unwrap();
    // Viridis, light to dark: every cell is one rectangle in its class's colour, plus one
    // legend swatch per class present (none of these colours is used for anything else).
    let colours = [
        "#FDE725", "#A0DA39", "#4AC16D", "#1FA187", "#277F8E", "#365C8D", "#46327E", "#440154",
    ];
    let mut drawn = 0;
    for (k, colour) in colours.iter().enumerate() {
        let cells = map
            .cells
            .iter()
            .filter(|c| {
                let lower = if k == 0 {
                    f64::NEG_INFINITY
                } else {
                    ERROR_CLASSES[k - 1]
                };
                let upper = ERROR_CLASSES.get(k).copied().unwrap_or(f64::INFINITY);
                c.bound.is_finite() && c.bound > lower && c.bound <= upper
            })
            .count();
        let fills = text.matches(&format!("fill=\"{colour}\"")).count();
        let expected = if cells == 0 { 0 } else { cells + 1 };
        assert_eq!(fills, expected, "class {k} ({colour}): {cells} cells");
        drawn += cells;
    }
    assert_eq!(
        drawn,
        map.cells.len(),
        "every cell of the shipped map is certified"
    );
    // The title gives the certified and measured maxima; the legend the classes.
    let title = format!(
        "max {:.3}; measured {:.3}",
        map.certified_linf.unwrap(),
        map.measured_linf
    );
    // The class of the largest bound is in the legend (between two thresholds: the map's
    // bounds lie above the first and below the last).
    let top = cbfreach::plot::error_class(map.certified_linf.unwrap());
    let class = format!("{} &lt; M ≤ {}", ERROR_CLASSES[top - 1], ERROR_CLASSES[top]);
    assert!(text.contains(&title), "title");
    assert!(text.contains(&class), "legend: {class}");
}
