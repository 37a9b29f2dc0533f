//! The `plausible` command-line tool.

mod cli;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "plausible",
    version,
    about = "How plausible is an object pose? Visual and physical plausibility of 6D pose hypotheses, batched on any GPU."
)]
struct Cli {
    /// More output: -v prints the adapter and backend, -vv debug logs.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// Write a Chrome trace of the run to this file (JSON Trace Event
    /// Format; open it in https://ui.perfetto.dev or chrome://tracing): one
    /// span for the command and one per stage (for `score`: load, setup,
    /// scoring with upload / dispatch / readback, ranking, write), with the
    /// GPU time of score passes where the adapter has timestamp queries.
    /// Without it the spans are off and cost nothing.
    #[arg(long, global = true, value_name = "TRACE.json")]
    trace: Option<std::path::PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Rank pose hypotheses by their visual-alignment score (eq. 3-5), and
    /// with --plane --physics by physical plausibility first.
    Score(cli::score::ScoreArgs),
    /// Fit the support plane to a depth frame (RANSAC outside the object's mask).
    Plane(cli::plane::PlaneArgs),
    /// Pose hypotheses of an object on the support plane: stable poses x yaw x position from the depth.
    Hypotheses(cli::hypotheses::HypothesesArgs),
    /// Run the scorer end to end on shipped data (no arguments needed).
    Demo(cli::demo::DemoArgs),
    /// Measure throughput, GPU side by side with the CPU twin.
    Bench(cli::bench::BenchArgs),
    /// Stable resting poses: drop tests, clustering, analytic cross-check, SQLite database.
    StablePoses(cli::stable::StableArgs),
    /// Physical plausibility of a scene: intersecting, floating, unstable (eq. 6-13).
    Check(cli::check::CheckArgs),
    /// Evaluate a BOP results file: AR from VSD, MSSD, MSPD (and ADD/ADI), as the BOP toolkit does, on any GPU.
    Eval(cli::eval::EvalArgs),
    /// Estimate the poses of a BOP dataset's target objects from stable-pose hypotheses on the fitted plane, scored and refined.
    Estimate(cli::estimate::EstimateArgs),
    /// Refine another method's BOP results against the depth (ICP; SIR, RIR verified by the visual score), resumable.
    Refine(cli::refine::RefineArgs),
    /// One self-contained HTML report from the JSON outputs of score, check, stable-poses export and eval, with their pictures.
    Report(cli::report::ReportArgs),
}

/// The command line, where `--inlier-mm -5` passes -5 to the flag (clap
/// reads a value starting with '-' as the next flag by default), so a
/// negative number gets the flag's own range error instead of "unexpected
/// argument".
fn parse_args() -> Cli {
    use clap::{CommandFactory, FromArgMatches};
    fn negatives(cmd: clap::Command) -> clap::Command {
        cmd.allow_negative_numbers(true).mut_subcommands(negatives)
    }
    let matches = negatives(Cli::command()).get_matches_from(join_non_finite(std::env::args_os()));
    Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit())
}

/// `--flag -inf` and `--flag -nan` as `--flag=-inf`: clap's negative-number
/// rule knows digits only, so these would read as short flags (-i, -n) and
/// fail with "unexpected argument" instead of the flag's own range error.
fn join_non_finite(args: impl IntoIterator<Item = std::ffi::OsString>) -> Vec<std::ffi::OsString> {
    let mut out: Vec<std::ffi::OsString> = Vec::new();
    let mut args = args.into_iter();
    while let Some(arg) = args.next() {
        // After `--` every argument is a value as it stands.
        if arg == "--" {
            out.push(arg);
            out.extend(args.by_ref());
            break;
        }
        let non_finite = arg.to_str().is_some_and(|a| {
            let a = a.to_ascii_lowercase();
            matches!(a.as_str(), "-inf" | "-infinity" | "-nan")
        });
        let after_long_flag = out.last().and_then(|p| p.to_str()).is_some_and(|p| p.starts_with("--") && p.len() > 2 && !p.contains('='));
        match out.last_mut() {
            Some(flag) if non_finite && after_long_flag => {
                flag.push("=");
                flag.push(&arg);
            }
            _ => out.push(arg),
        }
    }
    out
}

fn main() {
    // Rust ignores SIGPIPE, so `plausible score ... | head` would panic on
    // the first print after `head` exits. Die quietly like other Unix tools.
    #[cfg(unix)]
    // SAFETY: called first thing in main, before any other thread exists;
    // SIG_DFL is a valid action for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // println! panics when standard output cannot be written (a full disk,
    // /dev/full): report it as an error and exit 1 instead of a panic (101).
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let msg = info.payload().downcast_ref::<String>().map(String::as_str).or_else(|| info.payload().downcast_ref::<&str>().copied());
        if let Some(m) = msg.filter(|m| m.starts_with("failed printing to stdout")) {
            eprintln!("error: cannot write the output: {}", m.trim_start_matches("failed printing to stdout: "));
            cli::trace::finish().ok();
            std::process::exit(1);
        }
        default_hook(info);
    }));
    // On a headless server Mesa's device-select Vulkan layer tries to reach
    // a Wayland display and prints "XDG_RUNTIME_DIR is invalid" on every
    // start; without a display session it has nothing to select by. Set
    // here, before any thread exists (the library never touches the
    // process environment).
    if std::env::var_os("XDG_RUNTIME_DIR").is_none()
        && std::env::var_os("NODEVICE_SELECT").is_none()
        && std::env::var_os("MESA_VK_DEVICE_SELECT").is_none()
    {
        // SAFETY: first thing in main, no other thread exists yet.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
    let cli = parse_args();
    if let Err(e) = cli::trace::init(cli.verbose, cli.trace.as_deref()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
    let result = match cli.command {
        Command::Score(a) => cli::score::run(a, cli.verbose),
        Command::Plane(a) => cli::plane::run(a),
        Command::Hypotheses(a) => cli::hypotheses::run(a),
        Command::Demo(a) => cli::demo::run(a, cli.verbose),
        Command::Bench(a) => cli::bench::run(a, cli.verbose),
        Command::StablePoses(a) => cli::stable::stable_poses(a),
        Command::Check(a) => cli::check::run(a),
        Command::Eval(a) => cli::eval::run(a, cli.verbose),
        Command::Estimate(a) => cli::estimate::run(a, cli.verbose),
        Command::Refine(a) => cli::refine::run(a, cli.verbose),
        Command::Report(a) => cli::report::run(a),
    };
    // The trace is finished (its file completed) on the error path too.
    if let Err(e) = result.and(cli::trace::finish()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

#[cfg(test)]
mod tests {
    use super::join_non_finite;

    fn joined(args: &[&str]) -> Vec<String> {
        join_non_finite(args.iter().map(std::ffi::OsString::from)).into_iter().map(|a| a.into_string().unwrap()).collect()
    }

    /// `--flag -inf` reaches the flag; after `--` nothing is rewritten.
    #[test]
    fn non_finite_values_join_their_flag() {
        assert_eq!(joined(&["p", "plane", "--inlier-mm", "-inf"]), ["p", "plane", "--inlier-mm=-inf"]);
        assert_eq!(joined(&["p", "--a", "-NaN", "-x", "-inf"]), ["p", "--a=-NaN", "-x", "-inf"]);
        assert_eq!(joined(&["p", "s", "--", "--a.obj", "-inf"]), ["p", "s", "--", "--a.obj", "-inf"]);
        assert_eq!(joined(&["p", "--a=1", "-inf"]), ["p", "--a=1", "-inf"]);
    }
}
