//! stride-mapping: elevation maps (paper 000), 2-D range-sensor maps (paper 003), the
//! Fankhauser baseline and map metrics.
//!
//! Empty for now: the mapper is built in its own issue.
