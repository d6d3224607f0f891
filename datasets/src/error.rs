//! The error type of this crate: every variant names the file (and line, where there is one).

use std::path::PathBuf;

/// An error reading or writing a dataset file.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// The operating system refused to read or write a file. The message already holds
    /// the OS error, so it is not also exposed as the error's source (which would print it
    /// twice in a chain).
    #[error("{}: {error}", path.display())]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        error: std::io::Error,
    },
    /// A line of a text file could not be understood.
    #[error("{}:{line}: {message}", path.display())]
    Parse {
        /// The file concerned.
        path: PathBuf,
        /// One-based line number.
        line: usize,
        /// What is wrong with the line.
        message: String,
    },
    /// A file is readable but its content is unusable as a whole.
    #[error("{}: {message}", path.display())]
    Invalid {
        /// The file or folder concerned.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A PNG image could not be decoded or has an unexpected format.
    #[error("{}: {message}", path.display())]
    Image {
        /// The image file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A message of an MCAP log cannot be used (an odd encoding, a truncated message, an
    /// image of the wrong size).
    #[error("{}: topic {topic}, message {index}: {message}", path.display())]
    Message {
        /// The MCAP file.
        path: PathBuf,
        /// The message's topic.
        topic: String,
        /// Zero-based index of the message among its topic's messages.
        index: usize,
        /// What is wrong with it.
        message: String,
    },
}

impl DatasetError {
    /// Wraps an I/O error with the path it concerns.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            error: source,
        }
    }

    /// A parse error at a one-based line of a file.
    pub fn parse(path: impl Into<PathBuf>, line: usize, message: impl Into<String>) -> Self {
        Self::Parse {
            path: path.into(),
            line,
            message: message.into(),
        }
    }

    /// An error about message `index` of `topic` in the MCAP file `path`.
    pub fn message(
        path: impl Into<PathBuf>,
        topic: &str,
        index: usize,
        message: impl Into<String>,
    ) -> Self {
        Self::Message {
            path: path.into(),
            topic: topic.to_owned(),
            index,
            message: message.into(),
        }
    }

    /// What went wrong, without the file it concerns (for errors re-worded elsewhere).
    pub fn detail(&self) -> String {
        match self {
            Self::Io { error, .. } => error.to_string(),
            Self::Parse { line, message, .. } => format!("line {line}: {message}"),
            Self::Invalid { message, .. }
            | Self::Image { message, .. }
            | Self::Message { message, .. } => message.clone(),
        }
    }

    /// An error about a file or folder as a whole.
    pub fn invalid(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Invalid {
            path: path.into(),
            message: message.into(),
        }
    }
}
