//! `stride`: RGB-D SLAM and 2.5-D elevation mapping for walking robots.
//!
//! The binary wires the library crates together; see `stride --help`.

mod cli;

use clap::Parser;

/// The error and its causes, each cause once: library errors that name their cause in
/// their own message are not followed by it again.
fn report(e: &anyhow::Error) -> String {
    let mut message = e.to_string();
    for cause in e.chain().skip(1) {
        let cause = cause.to_string();
        if !message.contains(&cause) {
            message.push_str(": ");
            message.push_str(&cause);
        }
    }
    message
}

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    cli::init_logging(args.verbose, args.quiet);
    // The parallel stages started from this thread (the odometry, maps on known poses, the
    // benchmarks) run on a pool it belongs to: handed to rayon's global pool from a thread
    // that waits for them, they lose a worker now and then (`stride_core::parallel`; the
    // back end's and the map's threads have pools of their own).
    // A pool that cannot start is reported as any other error; the pool lives for the run.
    let result = stride_core::parallel::join_own_pool("stride-main")
        .map_err(anyhow::Error::from)
        .and_then(|_pool| cli::run(args));
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // A closed stdout (e.g. `stride ... | head`) is not an error worth reporting.
            if e.chain().any(|c| {
                c.downcast_ref::<std::io::Error>()
                    .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
            }) {
                return std::process::ExitCode::SUCCESS;
            }
            // Exit codes: 1 a limit exceeded (`stride eval --max-*`), 2 any other error.
            if let Some(limit) = e.downcast_ref::<cli::gates::LimitExceeded>() {
                eprintln!("{limit}");
                return std::process::ExitCode::from(1);
            }
            eprintln!("error: {}", report(&e));
            std::process::ExitCode::from(2)
        }
    }
}
