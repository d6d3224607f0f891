//! `stride config`: the configuration file of every stage: its documented defaults, and a
//! check of a file.

use anyhow::Result;
use clap::Args;
use std::path::PathBuf;
use stride::config::{Config, DEFAULTS_TOML};

#[derive(Debug, Args)]
#[command(group = clap::ArgGroup::new("what").required(true))]
pub struct ConfigArgs {
    /// Print every parameter of every stage with its default and what it means (TOML, the
    /// format `--config` reads).
    #[arg(long, group = "what")]
    pub print_defaults: bool,
    /// Check a configuration file (unknown keys, types, ranges) and print the values it
    /// gives every parameter.
    #[arg(long, value_name = "FILE.toml", group = "what")]
    pub check: Option<PathBuf>,
}

pub fn run(a: ConfigArgs) -> Result<()> {
    if a.print_defaults {
        crate::outln!("{}", DEFAULTS_TOML.trim_end())?;
    }
    if let Some(path) = &a.check {
        let config = Config::load(path)?;
        crate::outln!("{}", config.to_toml()?.trim_end())?;
        tracing::info!("{} is valid", path.display());
    }
    Ok(())
}
