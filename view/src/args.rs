//! The command-line options that open a view, shared by `infer stream` and `train fit`; they
//! exist in every build, so that a build without the viewer says so instead of not knowing them.

use std::path::PathBuf;

/// Where a view's data goes.
#[derive(Clone, Debug, PartialEq)]
pub enum Target {
    /// A Rerun viewer: one already listening on Rerun's default port, else one started from the
    /// `rerun` executable on `PATH` (`pip install rerun-sdk==0.36.*` or `cargo install rerun-cli
    /// --version 0.36.*` puts it there).
    Spawn,
    /// A viewer (or `rerun --serve-grpc`) at this URL, as `rerun+http://HOST:9876/proxy`.
    Connect(String),
    /// Recorded to this `.rrd` file for the viewer to open later. It is written beside itself
    /// (`FILE.rrd.partial`) and renamed when the view finishes: the name holds a whole recording
    /// or none.
    Save(PathBuf),
}

impl Target {
    /// The target in words, for the recorder's errors.
    #[cfg(feature = "rerun")]
    pub(crate) fn describe(&self) -> String {
        match self {
            Target::Spawn => "a Rerun viewer".into(),
            Target::Connect(url) => format!("the Rerun viewer at {url}"),
            Target::Save(path) => path.display().to_string(),
        }
    }
}

/// `--view`, `--view-connect URL`, `--view-save FILE.rrd`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ViewArgs {
    /// Show it live in a Rerun viewer (a build with `--features view`): one already running,
    /// else `rerun` started from PATH (`pip install rerun-sdk==0.36.*`).
    #[arg(long)]
    pub view: bool,
    /// Send the view to the Rerun viewer at this URL (rerun+http://HOST:9876/proxy).
    #[arg(long, value_name = "URL", conflicts_with = "view_save")]
    pub view_connect: Option<String>,
    /// Record the view to this .rrd file instead (written whole at the end; `rerun FILE.rrd`
    /// opens it).
    #[arg(long, value_name = "FILE.rrd", conflicts_with = "view")]
    pub view_save: Option<PathBuf>,
}

impl ViewArgs {
    /// Where the view goes, if one was asked for; an error where this build has no viewer.
    pub fn target(&self) -> Result<Option<Target>, String> {
        let target = match (&self.view_save, &self.view_connect, self.view) {
            (Some(path), _, _) => Target::Save(path.clone()),
            (None, Some(url), _) => Target::Connect(url.clone()),
            (None, None, true) => Target::Spawn,
            (None, None, false) => return Ok(None),
        };
        if cfg!(feature = "rerun") {
            Ok(Some(target))
        } else {
            Err("--view, --view-connect, --view-save: this build has no live view; build it with `--features view`"
                .into())
        }
    }
}
