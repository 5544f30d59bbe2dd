//! The crate's error type: one enum per concern, gathered here with `#[from]`.

/// Every error cbfreach's library can return.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scenario file could not be read or is invalid.
    #[error(transparent)]
    Scenario(#[from] crate::scenario::ScenarioError),
    /// An expression could not be parsed or differentiated.
    #[error(transparent)]
    Expr(#[from] crate::expressions::ExprError),
    /// A network file could not be read or is invalid.
    #[error(transparent)]
    Network(#[from] crate::network::NetworkError),
    /// The safety filter could not be evaluated.
    #[error(transparent)]
    Filter(#[from] crate::filter::FilterError),
    /// Bounding a network over a box failed (bad box or network).
    #[error(transparent)]
    Bounds(#[from] crate::bounds::BoundsError),
    /// A reach run could not start.
    #[error(transparent)]
    Reach(#[from] crate::reach::ReachError),
    /// A change of coordinates for the embedding could not be built.
    #[error(transparent)]
    Transform(#[from] crate::reach::transform::TransformError),
    /// The GPU engine could not start or run.
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
    /// A verification run or a merge failed.
    #[error(transparent)]
    Verify(#[from] crate::verify::VerifyError),
    /// Measuring or certifying a network's error failed.
    #[error(transparent)]
    Analysis(#[from] crate::surrogate_error::AnalysisError),
    /// A box was malformed (dimensions, order, NaN).
    #[error(transparent)]
    Box(#[from] crate::boxes::BoxError),
    /// Settings were invalid (the field is named).
    #[error(transparent)]
    Settings(#[from] crate::reach::settings::SettingsError),
    /// A scenario could not be compiled into a reach problem.
    #[error(transparent)]
    Problem(#[from] crate::problem::ProblemError),
    /// An engine could not be chosen or does not support the settings.
    #[error(transparent)]
    Engine(#[from] crate::reach::engine::EngineError),
    /// An error map could not be read, written or used.
    #[error(transparent)]
    ErrorMap(#[from] crate::error_map::ErrorMapError),
    /// A training job could not run.
    #[error(transparent)]
    Training(#[from] crate::training::TrainingError),
    /// A picture could not be drawn.
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// What went wrong.
        source: std::io::Error,
    },
}
