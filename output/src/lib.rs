//! # stride-output
//!
//! How stride writes what it produces, apart from the types and models of stride-core:
//!
//! * [`fs`]: files replaced atomically (temporary file, then rename) and output folders
//!   staged beside their destination and swapped in whole, so that a killed run leaves the
//!   previous output or the complete new one, never half of one.
//! * [`colormap`]: the viridis colour map that map previews and report plots share.

pub mod colormap;
pub mod fs;
