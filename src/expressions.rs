//! expressions (in progress)
