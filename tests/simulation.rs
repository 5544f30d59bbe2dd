//! Simulation of the filtered system: where trajectories end, and forward invariance of S.

mod common;

use cbfreach::filter::SafetyFilter;
use cbfreach::simulate::{simulate_filtered, Integrator};
use common::{double_integrator, integrator};

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).powi(2))
        .sum::<f64>()
        .sqrt()
}

#[test]
fn scenario_1_endpoints() {
    let s = integrator();
    let f = SafetyFilter::new(&s);
    let steps = s.reach.steps();
    for integrator in [Integrator::Euler, Integrator::Rk4] {
        let behind = simulate_filtered(&f, &[6.0, 0.3], s.reach.dt, steps, integrator);
        assert!(behind.stopped.is_none());
        assert!(
            dist(behind.last(), &[3.0, 0.0]) < 1e-2,
            "{:?}",
            behind.last()
        );
        let front = simulate_filtered(&f, &[-2.0, 2.0], s.reach.dt, steps, integrator);
        assert!(dist(front.last(), &[0.0, 0.0]) < 1e-3, "{:?}", front.last());
    }
}

/// Forward invariance of S: along Euler trajectories from many random safe starts, h stays
/// non-negative up to the step's local error O(dt²); with dt ten times smaller the violation
/// must shrink accordingly, which separates discretisation error from a wrong filter.
/// Trajectories that reach a state where the QP is infeasible stop there and say so (scenario
/// 2's two CBFs conflict near (4.9, −2)); at most `max_stopped` of them may.
fn check_invariance(s: &cbfreach::scenario::Scenario, starts: usize, max_stopped: usize) {
    let f = SafetyFilter::new(s);
    let points = cbfreach::simulate::sample_box(&s.reach.region, 4 * starts, 11);
    let safe: Vec<_> = points
        .into_iter()
        .filter(|x| s.is_safe(x))
        .take(starts)
        .collect();
    assert_eq!(safe.len(), starts);
    let worst = |dt: f64| {
        let steps = (4.0 / dt) as usize;
        let mut worst = 0.0_f64;
        let mut stopped = 0;
        for x0 in &safe {
            let t = simulate_filtered(&f, x0, dt, steps, Integrator::Euler);
            if let Some(why) = &t.stopped {
                assert!(why.cause.is_infeasible(), "{why}");
                stopped += 1;
            }
            for x in &t.x {
                worst = worst.min(s.min_h(x));
            }
        }
        assert!(
            stopped <= max_stopped,
            "{stopped} trajectories hit an infeasible QP"
        );
        worst
    };
    let coarse = worst(s.reach.dt);
    let fine = worst(s.reach.dt / 10.0);
    assert!(coarse > -0.05, "h fell to {coarse} with the scenario's dt");
    assert!(
        fine > -0.05 / 50.0,
        "h fell to {fine} with dt/10 (coarse: {coarse})"
    );
}

#[test]
fn scenario_1_forward_invariance_over_1000_starts() {
    check_invariance(&integrator(), 1000, 0);
}

#[test]
fn scenario_2_forward_invariance() {
    // About a tenth of the safe starts of C run into the conflict of the two CBFs.
    check_invariance(&double_integrator(), 300, 60);
}

/// `simulate` says which starts lie outside `S`, where the filter promises nothing (scenario
/// 1's obstacle is the disc of radius 1 about (2, 0)).
#[test]
fn simulate_names_starts_outside_s() {
    let path = common::scenario_path("integrator.toml");
    let path = path.to_str().unwrap();
    let args = ["simulate", path, "--from", "6,0.3", "--horizon", "0.2"];
    let (code, _, stderr) = common::cbfreach(&[&args[..], &["--from", "2,0.5"]].concat());
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stderr.contains("note: 1 of 2 starts lie outside S (the first, (2.0000, 0.5000)"),
        "{stderr}"
    );
    let (code, _, stderr) = common::cbfreach(&args);
    assert_eq!(code, 0, "{stderr}");
    assert!(!stderr.contains("outside S"), "{stderr}");
}
