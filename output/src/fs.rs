//! Writing files and folders so that a reader never sees a half-written one.

use std::io::Write;
use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` atomically: into a temporary file in the same directory, then
/// renamed over `path`. On error the temporary file is removed and `path` is untouched.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = temp_path_for(path);
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// The temporary sibling of `path` used by [`write_atomic`]: `.<name>.tmp-<pid>`.
pub fn temp_path_for(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "output".to_owned());
    let tmp_name = format!(".{name}.tmp-{}", std::process::id());
    match path.parent() {
        Some(dir) => dir.join(tmp_name),
        None => PathBuf::from(tmp_name),
    }
}

/// An output folder written in a hidden staging sibling (`.<name>.partial-<pid>`) and
/// published in one step, so that a run killed at any moment leaves either the previous
/// folder or the complete new one, never a mix. Dropped unpublished, the staging folder is
/// removed.
#[derive(Debug)]
pub struct StagedDir {
    stage: PathBuf,
    target: PathBuf,
    published: bool,
}

impl StagedDir {
    /// Creates the staging folder for `target` (and `target`'s parent, when missing).
    /// Staging folders that killed runs left for this target are removed first.
    pub fn new(target: &Path) -> std::io::Result<Self> {
        let name = target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "output".to_owned());
        let parent = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        std::fs::create_dir_all(&parent)?;
        let prefix = format!(".{name}.partial-");
        for entry in std::fs::read_dir(&parent)?.flatten() {
            if entry.file_name().to_string_lossy().starts_with(&prefix) {
                let _ = std::fs::remove_dir_all(entry.path());
            }
        }
        let stage = parent.join(format!("{prefix}{}", std::process::id()));
        std::fs::create_dir(&stage)?;
        Ok(Self {
            stage,
            target: target.to_path_buf(),
            published: false,
        })
    }

    /// The folder to write into.
    pub fn path(&self) -> &Path {
        &self.stage
    }

    /// Puts the staged folder in the target's place: a rename when there is none, else an
    /// atomic exchange of the two (Linux `renameat2(RENAME_EXCHANGE)`) and the removal of the
    /// old one. Where the exchange is unsupported, the old folder is moved aside first (a
    /// window of two renames).
    pub fn publish(mut self) -> std::io::Result<()> {
        if !self.target.exists() {
            std::fs::rename(&self.stage, &self.target)?;
        } else {
            let exchanged = rustix::fs::renameat_with(
                rustix::fs::CWD,
                &self.stage,
                rustix::fs::CWD,
                &self.target,
                rustix::fs::RenameFlags::EXCHANGE,
            );
            if exchanged.is_err() {
                let aside = self.stage.with_extension("old");
                std::fs::rename(&self.target, &aside)?;
                std::fs::rename(&self.stage, &self.target)?;
                std::fs::rename(&aside, &self.stage)?;
            }
            // The stage path now holds the previous output.
            std::fs::remove_dir_all(&self.stage)?;
        }
        self.published = true;
        Ok(())
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.published {
            let _ = std::fs::remove_dir_all(&self.stage);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_and_replaces_without_leaving_temporaries() {
        let dir = std::env::temp_dir().join(format!("stride-output-fs-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.txt");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        // A missing directory fails cleanly.
        assert!(write_atomic(&dir.join("missing/b.txt"), b"x").is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_staged_folder_replaces_the_old_one_whole_or_not_at_all() {
        let root = std::env::temp_dir().join(format!("stride-staged-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let out = root.join("out");
        // First publication: no previous folder.
        let s = StagedDir::new(&out).unwrap();
        std::fs::write(s.path().join("a.txt"), "one").unwrap();
        assert!(!out.exists(), "nothing visible before publishing");
        s.publish().unwrap();
        assert_eq!(std::fs::read_to_string(out.join("a.txt")).unwrap(), "one");
        // Dropped unpublished (a failed run): the old folder stays, the stage goes.
        let s = StagedDir::new(&out).unwrap();
        std::fs::write(s.path().join("a.txt"), "half").unwrap();
        drop(s);
        assert_eq!(std::fs::read_to_string(out.join("a.txt")).unwrap(), "one");
        // Replacing: the new folder whole, nothing of the old one, no leftovers.
        let s = StagedDir::new(&out).unwrap();
        std::fs::write(s.path().join("b.txt"), "two").unwrap();
        s.publish().unwrap();
        assert!(!out.join("a.txt").exists());
        assert_eq!(std::fs::read_to_string(out.join("b.txt")).unwrap(), "two");
        assert_eq!(std::fs::read_dir(&root).unwrap().count(), 1);
        std::fs::remove_dir_all(&root).unwrap();
    }
}
