//! What the project's command lines share in their tests.

/// Every argument of `cmd` and its subcommands, as `command --flag`, that has no help text
/// (clap's help and version flags aside): each flag a user may type says what it does.
pub fn undocumented_flags(cmd: &clap::Command) -> Vec<String> {
    let mut missing = Vec::new();
    collect(cmd, cmd.get_name(), &mut missing);
    missing
}

/// Panics, listing them, if any flag of `cmd` has no help text (a test of each command line).
pub fn assert_documented(cmd: &clap::Command) {
    let missing = undocumented_flags(cmd);
    assert!(missing.is_empty(), "flags without help: {missing:?}");
}

fn collect(cmd: &clap::Command, path: &str, missing: &mut Vec<String>) {
    for arg in cmd.get_arguments() {
        let id = arg.get_id().as_str();
        if arg.is_hide_set() || id == "help" || id == "version" {
            continue;
        }
        if arg.get_help().is_none() && arg.get_long_help().is_none() {
            missing.push(format!("{path} --{}", arg.get_long().unwrap_or(id)));
        }
    }
    for sub in cmd.get_subcommands() {
        collect(sub, &format!("{path} {}", sub.get_name()), missing);
    }
}
