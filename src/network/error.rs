//! [`NetworkError`]: everything that can go wrong reading, writing or training a network.

use std::path::PathBuf;

/// Errors in loading, saving, validating or training a network. Each names the file (or the
/// name given for an in-memory buffer) and what was expected, so the user can fix the export.
#[derive(Debug, thiserror::Error)]
pub enum NetworkError {
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// The bytes are not a safetensors file, or its header or metadata are malformed.
    #[error("{}: not a valid safetensors network file: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A tensor the layer structure needs is absent (e.g. `2.bias` beside `2.weight`).
    #[error(
        "{}: tensor `{name}` is missing (every Linear layer needs `<k>.weight` and `<k>.bias`; \
         export with bias=True)",
        path.display()
    )]
    MissingTensor {
        /// The file.
        path: PathBuf,
        /// The tensor name that was expected.
        name: String,
    },
    /// A tensor has the wrong shape: weights are `[out, in]`, biases `[out]`, and each layer's
    /// `in` must equal the previous layer's `out`.
    #[error(
        "{}: tensor `{name}` has shape {found:?}, expected {expected:?} (weights are [out, in] \
         as in torch.nn.Linear; consecutive layers must chain)",
        path.display()
    )]
    Shape {
        /// The file.
        path: PathBuf,
        /// The tensor.
        name: String,
        /// The shape the layer structure requires.
        expected: Vec<usize>,
        /// The shape in the file.
        found: Vec<usize>,
    },
    /// A weight or bias is NaN or infinite.
    #[error("{}: tensor `{name}` has a non-finite value (NaN or ±∞) at flat index {index}", path.display())]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// The tensor.
        name: String,
        /// Row-major flat index of the first bad entry.
        index: usize,
    },
    /// A tensor is stored in a dtype other than F32 or F64.
    #[error(
        "{}: tensor `{name}` has dtype {dtype}; only F32 and F64 are supported \
         (convert with `model.float()` or `model.double()` before saving)",
        path.display()
    )]
    UnsupportedDtype {
        /// The file.
        path: PathBuf,
        /// The tensor.
        name: String,
        /// The dtype found, as safetensors names it (e.g. `F16`).
        dtype: String,
    },
    /// The file describes something other than an `nn.Sequential` of `Linear` layers with ReLU
    /// between them.
    #[error(
        "{}: unsupported network: {message} (expected the state_dict of an nn.Sequential of \
         Linear layers with ReLU between them)",
        path.display()
    )]
    UnsupportedLayer {
        /// The file.
        path: PathBuf,
        /// What was found.
        message: String,
    },
    /// The network has no layers (or the file no tensors).
    #[error("the network has no layers")]
    Empty,
    /// The training data are inconsistent (lengths, dimensions, non-finite values).
    #[error("training data: {message}")]
    Dataset {
        /// What is wrong.
        message: String,
    },
    /// A training setting is out of range.
    #[error("training settings: {message}")]
    Settings {
        /// What is wrong.
        message: String,
    },
    /// Training produced a non-finite loss or non-finite weights.
    #[error(
        "training diverged at epoch {epoch} (loss {loss}); lower learning_rate or \
         jacobian_weight, or rescale the data"
    )]
    Diverged {
        /// Epoch (1-based) where it was noticed.
        epoch: usize,
        /// The epoch's mean loss.
        loss: f64,
    },
    /// A checkpoint does not fit the run it should resume (other data, network or settings).
    #[error("{}: cannot resume from this checkpoint: {message}", path.display())]
    Checkpoint {
        /// The checkpoint file.
        path: PathBuf,
        /// What does not match.
        message: String,
    },
}
