//! The project's one error type, with categories, and its `Result` alias.

use std::path::{Path, PathBuf};

/// Every fallible function of the crate returns this error.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A configuration or argument is invalid; `field` names what is wrong.
    #[error("invalid configuration `{field}`: {message}")]
    Config { field: String, message: String },

    /// The operating system refused a file operation.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// An input file exists but its content is unusable (truncated PNG, NaN pose, ...).
    #[error("{}: {message}", path.display())]
    InputData { path: PathBuf, message: String },

    /// A value handed to a library function is out of its domain (not user input).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),

    /// An object store (S3, GCS, Azure) refused or failed a request; `url` names the dataset or object.
    #[error("{url}: {message}")]
    Store { url: String, message: String },

    /// libtorch reported an error.
    #[error("torch: {0}")]
    Torch(String),

    /// Arrow or Parquet reported an error.
    #[error("parquet/arrow: {0}")]
    Parquet(String),

    /// A fatal error while a stage processed one work unit.
    #[error("{stage} failed on {unit}: {source}")]
    Unit {
        stage: String,
        unit: String,
        #[source]
        source: Box<Error>,
    },

    /// The run was interrupted (Ctrl-C, SIGTERM); everything committed is kept.
    #[error("interrupted: committed shards are kept; run the same command again to resume")]
    Interrupted,

    /// A bug: an invariant of the program does not hold.
    #[error("internal error: {0}")]
    Internal(String),
}

/// `Result` with the project's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io { path: path.as_ref().to_path_buf(), source }
    }

    /// Bad content in the file at `path`.
    pub fn input(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Error::InputData { path: path.as_ref().to_path_buf(), message: message.into() }
    }

    /// An invalid configuration field.
    pub fn config(field: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Config { field: field.into(), message: message.into() }
    }
}

impl From<tch::TchError> for Error {
    fn from(e: tch::TchError) -> Self {
        Error::Torch(e.to_string())
    }
}
