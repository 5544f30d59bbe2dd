//! Bounds on a ReLU network over a box (in progress).
