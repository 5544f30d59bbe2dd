//! Scenario files (in progress).

/// Errors in a scenario file.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// Placeholder.
    #[error("{0}")]
    Invalid(String),
}
