//! The safety filter (in progress).

/// Errors in evaluating the filter.
#[derive(Debug, thiserror::Error)]
pub enum FilterError {
    /// Placeholder.
    #[error("{0}")]
    Invalid(String),
}
