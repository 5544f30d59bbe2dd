//! equilibria (in progress)
