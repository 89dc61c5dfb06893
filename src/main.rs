//! `g1viz` command line: replay, identify, validate, simulate and diagnose G1 arm sessions.
//! This file only dispatches; each command is a module of `cli`, the work is library code.

mod cli;

use clap::Parser;

fn main() {
    // Rust ignores SIGPIPE, so printing into a closed pipe (`g1viz info … | head`) would panic;
    // a command-line tool should just stop, as `cat` does.
    #[cfg(unix)]
    // SAFETY: called first thing in main, before any thread exists; SIG_DFL is a valid handler.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // Ctrl-C / SIGTERM / SIGHUP remove the temporary outputs in flight before the process ends.
    g1viz::util::temp::cleanup_on_termination_signals();
    if let Err(err) = cli::run(cli::Cli::parse()) {
        eprintln!("error: {err:#}");
        std::process::exit(1);
    }
}
