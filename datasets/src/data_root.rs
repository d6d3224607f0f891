//! Locating the shared real data (`../shared/data` beside the repository, or `STRIDE_DATA`).

use std::path::PathBuf;

/// Environment variable that overrides where the shared data lives.
pub const DATA_ENV: &str = "STRIDE_DATA";

/// The shared data folder: `$STRIDE_DATA` when set (returned even if it does not exist, so
/// that callers can report the wrong setting), otherwise the first existing of
/// `./../shared/data` (relative to the working directory) and `<repository>/../shared/data`.
pub fn shared_data_dir() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os(DATA_ENV) {
        return Some(PathBuf::from(p));
    }
    let from_repo = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data"));
    [PathBuf::from("../shared/data"), from_repo]
        .into_iter()
        .find(|p| p.is_dir())
}

/// A file or folder inside the shared data, if the data folder is found and holds it.
pub fn shared_data_path(relative: &str) -> Option<PathBuf> {
    let p = shared_data_dir()?.join(relative);
    p.exists().then_some(p)
}
