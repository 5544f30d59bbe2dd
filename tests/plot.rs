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
    let dir = std::env::temp_dir().join(format!("cbfreach-plot-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
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
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn unknown_extension_and_bad_size_are_errors() {
    let dir = std::env::temp_dir();
    let e = trajectories_figure(&dir.join("fig.jpg"), (640, 480)).unwrap_err();
    assert!(matches!(e, PlotError::Format(_)), "{e}");
    assert!(e.to_string().contains(".png or .svg"));
    let e = trajectories_figure(&dir.join("fig.png"), (10, 480)).unwrap_err();
    assert!(e.to_string().contains("pixels"), "{e}");
}
