//! `[training] target` (issue 38): parsed into the scenario, and every bad value refused with
//! an error naming the file and the field.

mod common;

use common::{from_text, SMALL};

fn with_training(section: &str) -> String {
    format!("{SMALL}\n[training]\ngrid = [5, 5]\n{section}\n")
}

fn error_for(section: &str) -> String {
    match from_text(&with_training(section)) {
        Ok(_) => panic!("`{section}` was accepted"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_target_is_parsed() {
    let s = from_text(&with_training("target = { linf = 0.1, slope_p95 = 0.2 }")).expect("valid");
    let t = s.training.target.expect("a target");
    assert_eq!((t.linf, t.slope_p95), (Some(0.1), Some(0.2)));
    let s = from_text(&with_training("target = { linf = 0.5 }")).expect("valid");
    assert_eq!(s.training.target.and_then(|t| t.slope_p95), None);
    let s = from_text(&with_training("")).expect("valid");
    assert!(s.training.target.is_none());
}

#[test]
fn bad_targets_name_the_field() {
    for (section, parts) in [
        (
            "target = { linf = -0.1 }",
            &["test.toml", "training.target.linf", "-0.1"][..],
        ),
        (
            "target = { linf = 0.1, slope_p95 = 0 }",
            &["training.target.slope_p95", "> 0"],
        ),
        ("target = { linf = nan }", &["training.target.linf", "NaN"]),
        ("target = {}", &["training.target", "linf, slope_p95"]),
        ("target = { lnf = 0.1 }", &["lnf", "linf"]),
        ("target = { linf = \"small\" }", &["linf"]),
    ] {
        let message = error_for(section);
        for p in parts {
            assert!(
                message.contains(p),
                "`{section}`: `{message}` does not mention `{p}`"
            );
        }
    }
}
