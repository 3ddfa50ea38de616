//! Gaussian-process maths for specgp (work in progress).
