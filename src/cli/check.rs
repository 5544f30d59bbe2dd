//! `cbfreach check <scenario>`: validate and summarise.

use std::path::Path;

use cbfreach::expressions::Expr;
use cbfreach::filter::{
    findings, FilterFindings, FilterMethod, Inert, QpForms, SafetyFilter, Vanishing, MAX_ACTIVE,
    MAX_SETS,
};
use cbfreach::scenario::{Margin, Scenario, MAX_ORDER};

use super::{fmt_point, load_scenario, CliResult};

/// Runs the command.
pub fn run(path: &Path) -> CliResult {
    let s = load_scenario(path)?;
    // A network file that is there must be the one the scenario describes.
    if s.network.as_ref().is_some_and(|n| n.file.exists()) {
        cbfreach::problem::load_network(&s, None)?;
    }
    let show = |e: &Expr| e.display(&s.states).to_string();
    println!("{}: scenario `{}` is valid", s.file, s.name);
    if !s.description.is_empty() {
        println!("  {}", s.description.replace('\n', "\n  "));
    }
    let labels = |names: &[String]| -> Vec<String> { names.iter().map(|x| s.label(x)).collect() };
    println!(
        "  states  {} (n = {}), inputs {} (m = {})",
        labels(&s.states).join(", "),
        s.n(),
        labels(&s.inputs).join(", "),
        s.m()
    );
    for p in &s.periodic {
        println!(
            "  {} is periodic, modulo [{:.4}, {:.4}]: sets are not wrapped, one that reaches the \
             period's end leaves C",
            s.states[p.state], p.lower, p.upper
        );
    }
    for (i, e) in s.f_tilde.iter().enumerate() {
        println!("  f̃[{}] = {}", s.states[i], show(e));
    }
    for c in &s.cbfs {
        let written = match c.level {
            0 => String::new(),
            k => format!(
                "   (ψ{k} = L_f̃ψ{} + α(ψ{}), written by cbf[{}].order)",
                k - 1,
                k - 1,
                c.section
            ),
        };
        println!(
            "  CBF {}: h = {}   α(h) = {}{written}",
            c.name,
            show(&c.h),
            c.alpha
        );
    }
    if let Some(b) = &s.input_bounds {
        println!(
            "  input bounds {} … {}",
            fmt_point(&b.lower),
            fmt_point(&b.upper)
        );
    }
    let filter = SafetyFilter::new(&s);
    let rows = filter.rows();
    println!(
        "  filter: {rows} constraint row{}, {}",
        if rows == 1 { "" } else { "s" },
        filter.method()
    );
    if filter.method() == FilterMethod::Qp {
        let qp = QpForms::new(&s);
        match qp.is_complete() {
            true => println!(
                "    its certified bounds enumerate {} active sets (design §2.1a)",
                qp.len()
            ),
            false => println!(
                "    its active sets are past those enumerated ({MAX_SETS} sets of at most \
                 {MAX_ACTIVE} rows): no certified error bound (`cbfreach error` finds none, and \
                 m_c = \"certified\" or \"local\" cannot run); fewer rows would give one"
            ),
        }
    }
    print_findings(&s, &findings(&s));
    let r = &s.reach;
    println!(
        "  reach: C = {} … {}, dt = {}, T = {} ({} steps), norm {:?}, {}",
        fmt_point(&r.region.lower),
        fmt_point(&r.region.upper),
        r.dt,
        r.horizon,
        r.steps(),
        r.norm,
        match r.m_c {
            Margin::Value(v) => format!("M_C = {v} (taken as given)"),
            Margin::Certified => "M_C = the error map's certified bound".to_string(),
            Margin::Measured => "M_C = the error map's measured error (not a bound)".to_string(),
            Margin::Local => "M = the error map's certified local bounds".to_string(),
        }
    );
    println!(
        "  goal {} … {}, {} initial boxes",
        fmt_point(&r.goal.lower),
        fmt_point(&r.goal.upper),
        r.initial.len()
    );
    for (k, b) in r.initial.iter().enumerate() {
        let start = cbfreach::verify::in_safe_set(&s, b);
        if start != cbfreach::verify::InSafeSet::Inside {
            println!(
                "  initial box {k} {} … {} lies {start}: reach bounds the trajectories that \
                 start in S",
                fmt_point(&b.lower),
                fmt_point(&b.upper)
            );
        }
    }
    print_survey(&s);
    if let Some(transient) = cbfreach::reach::Transient::at_goal(&s, &s.reach.transform) {
        println!("  {transient}");
    }
    if let Some(turning) = cbfreach::reach::Turning::at_goal(&s) {
        println!("  {turning}");
    }
    match &s.network {
        Some(net) => println!(
            "  network {} ({}{})",
            net.file.display(),
            net.architecture
                .iter()
                .map(|w| w.to_string())
                .collect::<Vec<_>>()
                .join("×"),
            if net.file.exists() {
                ""
            } else {
                ", file not present yet"
            }
        ),
        None => println!("  no network"),
    }
    println!(
        "  training grid {:?} over {} … {}",
        s.training.grid,
        fmt_point(&s.training.region.lower),
        fmt_point(&s.training.region.upper)
    );
    Ok(())
}

/// Where the true filtered system goes from a grid of starts over `C ∩ S` within the horizon
/// (`verify::survey`): what a run can at best prove, before any training.
fn print_survey(s: &Scenario) {
    let traps = cbfreach::verify::traps_for(s);
    let c = cbfreach::verify::survey(s, &traps);
    if c.starts == 0 {
        return;
    }
    let mut parts = vec![format!(
        "from {} it reaches the goal{} by T = {}",
        c.by_horizon,
        if traps.is_empty() { "" } else { " or a trap" },
        s.reach.horizon
    )];
    if c.later > 0 {
        parts.push(format!(
            "from {} it gets there after T, all by t = {:.1} (a longer reach.horizon lets \
             verify follow them)",
            c.later, c.latest
        ));
    }
    let within = format!(
        "ends elsewhere (no target within {} horizons)",
        1 + cbfreach::verify::LATER_HORIZONS
    );
    for (k, what) in [
        (c.leaves_c, "leaves C"),
        (c.infeasible, "meets an infeasible QP"),
        (c.leaves_s, "leaves S between samples"),
        (c.elsewhere, within.as_str()),
    ] {
        if k > 0 {
            parts.push(format!("from {k} it {what}"));
        }
    }
    println!(
        "  the true filtered system ({} time) from {} starts on a grid over C ∩ S: {}",
        s.reach.time,
        c.starts,
        parts.join("; ")
    );
}

/// The filter's findings on `C`, one line each (inert CBFs are also said by `train`).
fn print_findings(s: &Scenario, f: &FilterFindings) {
    for inert in &f.inert {
        println!("  {}", inert_note(s, inert));
    }
    for v in &f.vanishing {
        println!("  {}", vanishing_note(v));
    }
    match &f.example {
        None => println!(
            "  the QP is feasible at all {} points of C ∩ S sampled",
            f.sampled
        ),
        Some((x, why)) => println!(
            "  the QP is infeasible at {} of {} points of C ∩ S sampled ({:.1} %), first at {}: {why}",
            f.infeasible,
            f.sampled,
            100.0 * f.infeasible as f64 / f.sampled.max(1) as f64,
            fmt_point(x)
        ),
    }
    if let Some(l) = &f.leaves_c {
        let axis = l.side.0;
        println!(
            "  C is not invariant: the filtered flow leaves it at {} of {} points sampled on its sides \
             in S (first through {} = {}, at {}): boxes whose flow meets them end early; \
             verify a region inside C (verify --region) or widen C",
            l.leaving,
            l.sampled,
            s.states[axis],
            l.at[axis],
            fmt_point(&l.at)
        );
    }
}

/// What a CBF no input acts on means, and what to do: write out the high-order CBF its row
/// asks for (`ψ = L_f̃h + α(h)`, printed to paste), or nothing where another CBF is that.
pub(super) fn inert_note(s: &Scenario, inert: &Inert) -> String {
    let name = &inert.cbf;
    match &inert.kept_by {
        Some(next) => format!(
            "CBF {name}: no input acts on it (L_g h = 0 on all of C); its row asks \
             L_f̃ h + α(h) ≥ 0, which CBF {next} is (a high-order CBF): S requires both, and \
             where {next} holds so does {name}'s row"
        ),
        None => {
            // The next level: `order` one higher in the section it comes from.
            let cbf = &s.cbfs[inert.index];
            let order = cbf.level + 2;
            let raise = match order <= MAX_ORDER {
                true => format!("write order = {order} in cbf[{}], or ", cbf.section),
                false => String::new(),
            };
            format!(
                "CBF {name}: no input acts on it (L_g h = 0 on all of C): its relative degree \
                 is above one, so the filter cannot enforce it and the QP is infeasible wherever \
                 L_f̃ h + α(h) < 0; {raise}add that function as a CBF of its own and keep this \
                 one (a high-order CBF: S then requires both, and the input acts on the new \
                 row where h is a position bound): [[cbf]] h = \"{}\"",
                inert.next.display(&s.states)
            )
        }
    }
}

/// Where a CBF's `‖L_g h‖` vanishes while its row needs the input, and what it does to `v`.
fn vanishing_note(v: &Vanishing) -> String {
    format!(
        "CBF {}: where it needs the input (L_f̃ h + α(h) < 0), ‖L_g h‖ falls to {:.1e} of its \
         largest on C ∩ S, at {}: v divides by ‖L_g h‖², so it is steep or jumps there, which \
         networks fit poorly and certified error bounds see",
        v.cbf,
        v.ratio,
        fmt_point(&v.at)
    )
}
