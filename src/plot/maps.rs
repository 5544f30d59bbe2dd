//! Verdict maps and error maps: boxes of a partition coloured by their verdict, cells of an
//! error map by their certified bound. Imports the plot module's chart helpers only.

use super::*;

/// A verdict map's title: the share verified with the QP proven feasible on every set first,
/// the share that also counts boxes covering only the trajectories that exist beside it.
pub fn verdicts_title(report: &VerifyReport) -> String {
    let h = report.headline();
    let refined = report.after.len() != report.before.len();
    let grid: Vec<String> = report.run.grid.iter().map(usize::to_string).collect();
    let mut title = format!(
        "`{}` {}: verified {:.1}% of the safe area, QP proven feasible",
        report.run.scenario,
        grid.join("×"),
        100.0 * h.verified
    );
    if h.verified_existing_trajectories > h.verified {
        title += &format!(
            " ({:.1}% for existing trajectories only)",
            100.0 * h.verified_existing_trajectories
        );
    }
    if refined {
        title += &format!(
            "; {:.1}% before refinement",
            100.0 * h.verified_before_refinement
        );
    }
    title
}

pub(super) fn draw_verdicts<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    scenario: &Scenario,
    report: &VerifyReport,
) -> Result<(), DrawError> {
    let region = &report.run.region;
    let after = report.shares_after();
    let title = verdicts_title(report);
    let mut chart = chart(root, scenario, region, &title)?;
    for v in Verdict::ALL {
        // Verified boxes whose QP was not proven feasible on every set are drawn pale: their
        // verdict speaks only of the trajectories that do not meet an infeasible QP.
        let split = report
            .after
            .iter()
            .any(|b| b.verdict == v && b.feasible == Some(false));
        for pale in [false, true] {
            let boxes: Vec<IntervalBox> = report
                .after
                .iter()
                .filter(|b| b.verdict == v && (b.feasible == Some(false)) == pale)
                .map(|b| b.initial.clone())
                .collect();
            if boxes.is_empty() {
                continue;
            }
            let share = |bs: &[IntervalBox]| {
                let area: f64 = bs.iter().map(IntervalBox::volume).sum();
                100.0 * area / after.safe_area.max(f64::MIN_POSITIVE)
            };
            let (colour, label) = if pale {
                (
                    verdict_colour(v).mix(0.4),
                    format!(
                        "{}, QP feasibility not proven ({:.1}%)",
                        v.name(),
                        share(&boxes)
                    ),
                )
            } else if split {
                (
                    verdict_colour(v).mix(1.0),
                    format!("{}, QP proven feasible ({:.1}%)", v.name(), share(&boxes)),
                )
            } else {
                (
                    verdict_colour(v).mix(1.0),
                    format!("{} ({:.1}%)", v.name(), 100.0 * after.share(v)),
                )
            };
            box_series(&mut chart, &boxes, region, colour.filled(), Some(&label))?;
        }
    }
    // Thin cell borders so the refinement is visible (left out when cells are tiny).
    if report.after.len() <= 3000 {
        let all: Vec<IntervalBox> = report.after.iter().map(|b| b.initial.clone()).collect();
        box_series(
            &mut chart,
            &all,
            region,
            WHITE.mix(0.6).stroke_width(1),
            None,
        )?;
    }
    let traps: Vec<IntervalBox> = report.traps.iter().map(|t| t.region.clone()).collect();
    box_series(
        &mut chart,
        &traps,
        region,
        VERMILION.stroke_width(2),
        Some("trap boxes"),
    )?;
    box_series(
        &mut chart,
        std::slice::from_ref(&report.run.goal),
        region,
        BLUE.stroke_width(2),
        Some("goal set"),
    )?;
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.9))
        .border_style(DARK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(DrawError::from)
}

/// Upper ends of the error map's colour classes (the last class is everything finite above).
pub const ERROR_CLASSES: [f64; 7] = [0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5];

/// The class of a cell bound: `i` for `bound ≤ ERROR_CLASSES[i]` (the first such `i`),
/// `ERROR_CLASSES.len()` for larger finite bounds, one more for +∞ (not certified).
pub fn error_class(bound: f64) -> usize {
    if !bound.is_finite() {
        return ERROR_CLASSES.len() + 1;
    }
    ERROR_CLASSES
        .iter()
        .position(|&t| bound <= t)
        .unwrap_or(ERROR_CLASSES.len())
}

/// Viridis, light (small error) to dark (large), one colour per finite class.
const ERROR_COLOURS: [RGBColor; 8] = [
    RGBColor(253, 231, 37),
    RGBColor(160, 218, 57),
    RGBColor(74, 193, 109),
    RGBColor(31, 161, 135),
    RGBColor(39, 127, 142),
    RGBColor(54, 92, 141),
    RGBColor(70, 50, 126),
    RGBColor(68, 1, 84),
];

fn error_class_label(class: usize) -> String {
    match class {
        0 => format!("M ≤ {}", ERROR_CLASSES[0]),
        c if c < ERROR_CLASSES.len() => {
            format!("{} < M ≤ {}", ERROR_CLASSES[c - 1], ERROR_CLASSES[c])
        }
        c if c == ERROR_CLASSES.len() => format!("M > {}", ERROR_CLASSES[c - 1]),
        _ => "not certified (M = ∞)".to_string(),
    }
}

pub(super) fn draw_error_map<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    scenario: &Scenario,
    map: &ErrorMap,
) -> Result<(), DrawError> {
    let region = &map.region;
    let certified = match map.certified_linf {
        Some(m) if m.is_finite() => format!("{m:.3}"),
        Some(_) => "∞".to_string(),
        None => "none".to_string(),
    };
    let title = format!(
        "{}: certified local bound M on ‖N − v‖∞ (max {certified}; measured {:.3})",
        map.network, map.measured_linf
    );
    let mut chart = chart(root, scenario, region, &title)?;
    // The cells as boxes, sorted into their classes in one pass.
    let uncertified_class = ERROR_CLASSES.len() + 1;
    let mut classes: Vec<Vec<IntervalBox>> = vec![Vec::new(); uncertified_class + 1];
    for c in &map.cells {
        classes[error_class(c.bound)].push(IntervalBox {
            lower: c.lower.clone(),
            upper: c.upper.clone(),
        });
    }
    let total: f64 = classes.iter().flatten().map(IntervalBox::volume).sum();
    for (class, boxes) in classes.iter().enumerate().filter(|(_, b)| !b.is_empty()) {
        let colour = ERROR_COLOURS.get(class).copied().unwrap_or(VERMILION);
        let area: f64 = boxes.iter().map(IntervalBox::volume).sum();
        let share = 100.0 * area / total.max(f64::MIN_POSITIVE);
        let share = if share < 0.05 {
            "< 0.1%".to_string()
        } else {
            format!("{share:.1}%")
        };
        let label = format!("{} ({share} of the mapped area)", error_class_label(class));
        box_series(&mut chart, boxes, region, colour.filled(), Some(&label))?;
    }
    shade_unsafe(&mut chart, scenario, region)?;
    // Uncertified cells are few and tiny (where `L_g h = 0` on S's boundary): ring them, over
    // the shading of the unsafe set they straddle.
    box_series(
        &mut chart,
        &classes[uncertified_class],
        region,
        VERMILION.stroke_width(3),
        None,
    )?;
    box_series(
        &mut chart,
        std::slice::from_ref(&scenario.reach.goal),
        region,
        BLUE.stroke_width(2),
        Some("goal set"),
    )?;
    legend(&mut chart)
}
