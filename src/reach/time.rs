//! The time model a reach run's sets bound (issue 36): the continuous-time filtered system (the
//! default), a sampled-data controller held over each control period, or the paper's Euler map.
//! Plain data; imports nothing from the engines.

use serde::Serialize;

/// Which system the sets bound.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case", tag = "model")]
pub enum TimeModel {
    /// `ẋ = f̃(x) + g(x)v(x)` with the filter acting continuously: every step is validated (an
    /// a-priori enclosure of the step, the comparison principle on slabs,
    /// [`super::validated`]), and the sets hold at every time, the flowpipe between grid times.
    /// The default.
    #[default]
    Continuous,
    /// A digital controller: `u_k = κ(x_k) + v(x_k)` computed at `t_k = k·T_s` and held while
    /// the plant `ẋ = f(x) + g(x)u_k` evolves (zero-order hold), sets at every `dt`. Nothing
    /// keeps the state in `S` between samples: sets that may leave it are a finding
    /// ([`super::UnsafeBetweenSamples`]).
    Sampled {
        /// `T_s = K·dt`, `K` a whole number ≥ 1.
        control_period: f64,
    },
    /// The discrete map `x ← x + dt·F(x)` of the paper's experiments (`paper` runs it), kept
    /// to reproduce them: its sets do not bound the ODE.
    Euler,
}

impl TimeModel {
    /// The setting's value as written in a scenario (`time = "…"`).
    pub fn name(self) -> &'static str {
        match self {
            TimeModel::Continuous => "continuous",
            TimeModel::Sampled { .. } => "sampled",
            TimeModel::Euler => "euler",
        }
    }

    /// Whether `substeps` validated steps per `dt` fit this model: they cut continuous steps
    /// only. The message names the conflict; the caller names the setting.
    pub fn check_substeps(self, substeps: usize) -> Result<(), String> {
        match substeps > 1 && self != TimeModel::Continuous {
            true => Err(format!(
                "{substeps} substeps cut validated steps: they need time = \"continuous\" (found \"{}\")",
                self.name()
            )),
            false => Ok(()),
        }
    }

    /// Reads `time = name` with `control_period` (`sampled` only; `K·dt` with `K` a whole
    /// number ≥ 1, `dt` when absent).
    pub fn parse(name: &str, control_period: Option<f64>, dt: f64) -> Result<TimeModel, TimeError> {
        match name {
            "continuous" => Ok(TimeModel::Continuous),
            "euler" => Ok(TimeModel::Euler),
            "sampled" => {
                let ts = control_period.unwrap_or(dt);
                periods(ts, dt).ok_or(TimeError::Period { ts, dt })?;
                Ok(TimeModel::Sampled { control_period: ts })
            }
            other => Err(TimeError::Name(other.to_string())),
        }
    }

    /// The model a report's label names ([`std::fmt::Display`]'s text; empty in reports from
    /// before the setting existed, whose sets bound the Euler map); `None` for any other text.
    pub fn from_label(label: &str) -> Option<TimeModel> {
        match label {
            "" | "euler" => Some(TimeModel::Euler),
            "continuous" => Some(TimeModel::Continuous),
            other => {
                let ts = other.strip_prefix("sampled (T_s = ")?.strip_suffix(')')?;
                let control_period = ts.parse().ok()?;
                Some(TimeModel::Sampled { control_period })
            }
        }
    }

    /// A clause for summaries: what the sets bound.
    pub fn clause(self) -> String {
        match self {
            TimeModel::Continuous => {
                "continuous time (validated steps; sets hold at every time)".into()
            }
            TimeModel::Sampled { control_period } => {
                format!("sampled-data (control held over T_s = {control_period})")
            }
            TimeModel::Euler => "the Euler map x ← x + dt·F(x) (not the ODE)".into(),
        }
    }
}

/// `K` with `ts = K·dt`, `K` a whole number ≥ 1 (to a relative 1e-9), else `None`.
fn periods(ts: f64, dt: f64) -> Option<usize> {
    let k = (ts / dt).round();
    // A hold of more steps than a run may take is no period (1e300 once hung the engine).
    let held = (1.0..=crate::scenario::limits::MAX_STEPS).contains(&k);
    (ts.is_finite() && ts > 0.0 && held && (ts - k * dt).abs() <= 1e-9 * ts).then_some(k as usize)
}

/// A time model that cannot be read; [`TimeError::field`] names the setting at fault.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TimeError {
    /// An unknown `time`.
    #[error("time = \"{0}\": expected \"continuous\", \"sampled\" or \"euler\"")]
    Name(String),
    /// `control_period` is not `K·dt` with `K` a whole number ≥ 1.
    #[error(
        "control_period = {}: expected K·dt with K a whole number from 1 to 1e7 (dt = {dt}): \
         the input is held over K integration steps",
        crate::scenario::limits::shown(*ts)
    )]
    Period {
        /// The period asked for.
        ts: f64,
        /// The integration step.
        dt: f64,
    },
}

impl TimeError {
    /// The field at fault, as in a scenario's `[reach]` table.
    pub fn field(&self) -> &'static str {
        match self {
            TimeError::Name(_) => "reach.time",
            TimeError::Period { .. } => "reach.control_period",
        }
    }
}

impl super::ReachProblem {
    /// Integration steps per control period: `T_s / dt` for `sampled`, 1 otherwise.
    pub fn period_steps(&self) -> Result<usize, super::ReachError> {
        match self.time {
            TimeModel::Sampled { control_period } => {
                periods(control_period, self.dt).ok_or_else(|| {
                    super::ReachError::Settings(
                        TimeError::Period {
                            ts: control_period,
                            dt: self.dt,
                        }
                        .to_string(),
                    )
                })
            }
            _ => Ok(1),
        }
    }

    /// The problem with another time model and validated steps per `dt`, in every frame.
    pub fn with_time(mut self, time: TimeModel, substeps: usize) -> super::ReachProblem {
        self.time = time;
        self.substeps = substeps.max(1);
        self.in_x = self.in_x.map(|x| Box::new(x.with_time(time, substeps)));
        // Turned frames tighten continuous time alone (`with_turned_frames`).
        self.turned = match time {
            TimeModel::Continuous => std::mem::take(&mut self.turned)
                .into_iter()
                .map(|p| p.with_time(time, substeps))
                .collect(),
            _ => Vec::new(),
        };
        self
    }

    /// Steps of the engine per `dt`: the substeps in continuous time, 1 otherwise.
    pub fn steps_per_dt(&self) -> usize {
        match self.time {
            TimeModel::Continuous => self.substeps.max(1),
            _ => 1,
        }
    }

    /// Checks the time model against the problem and the settings: substeps cut, and
    /// [`taylor3`](super::ReachSettings::taylor3) sharpens, continuous-time steps only (asked
    /// of another model they would change nothing, silently).
    pub fn check_time(&self, settings: &super::ReachSettings) -> Result<(), super::ReachError> {
        self.time.check_substeps(self.substeps).map_err(|e| {
            super::ReachError::Settings(format!("{e}: --substeps 1, or leave it out"))
        })?;
        if settings.taylor3 && self.time != TimeModel::Continuous {
            return Err(super::ReachError::Settings(format!(
                "taylor3 (--taylor3) sharpens the validated steps of time = \"continuous\"; \
                 time = \"{}\" takes none: leave it out, or --time continuous",
                self.time.name()
            )));
        }
        Ok(())
    }
}

impl std::fmt::Display for TimeModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TimeModel::Sampled { control_period } => write!(f, "sampled (T_s = {control_period})"),
            other => f.write_str(other.name()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every model's label reads back as the model (a report's checks simulate what it names).
    #[test]
    fn labels_read_back_as_their_models() {
        for time in [
            TimeModel::Continuous,
            TimeModel::Euler,
            TimeModel::Sampled {
                control_period: 0.08,
            },
            TimeModel::Sampled {
                control_period: 0.1 + 0.2,
            },
        ] {
            assert_eq!(TimeModel::from_label(&time.to_string()), Some(time));
        }
        assert_eq!(TimeModel::from_label(""), Some(TimeModel::Euler));
        assert_eq!(TimeModel::from_label("sampled"), None);
        assert_eq!(TimeModel::from_label("sampled (T_s = x)"), None);
    }

    #[test]
    fn names_parse_and_periods_are_multiples_of_dt() {
        assert_eq!(
            TimeModel::parse("continuous", None, 0.1),
            Ok(TimeModel::Continuous)
        );
        assert_eq!(TimeModel::parse("euler", None, 0.1), Ok(TimeModel::Euler));
        assert_eq!(
            TimeModel::parse("sampled", None, 0.05),
            Ok(TimeModel::Sampled {
                control_period: 0.05
            })
        );
        assert_eq!(
            TimeModel::parse("sampled", Some(0.15), 0.05),
            Ok(TimeModel::Sampled {
                control_period: 0.15
            })
        );
        let e = TimeModel::parse("sampled", Some(0.12), 0.05).unwrap_err();
        assert_eq!(e.field(), "reach.control_period");
        assert!(e.to_string().contains("control_period = 0.12"), "{e}");
        // 1e300 and 1e6 (2·10⁷ steps a hold) were accepted, and the first hung the engine.
        for bad in [0.0, -0.1, 0.025, f64::NAN, f64::INFINITY, 1e300, 1e6] {
            assert!(
                TimeModel::parse("sampled", Some(bad), 0.05).is_err(),
                "{bad}"
            );
        }
        let e = TimeModel::parse("rk4", None, 0.05).unwrap_err();
        assert!(e.to_string().contains("rk4") && e.field() == "reach.time");
    }
}
