//! Names read from a command line or a file that must be one of a known list.

/// A name that is none of the known ones; the message lists them.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("unknown {what} {name:?}: {}", known.join(", "))]
pub struct UnknownName {
    /// What was named (`"preset"`, `"split"`).
    pub what: &'static str,
    pub name: String,
    pub known: Vec<&'static str>,
}

impl UnknownName {
    pub fn new(what: &'static str, name: &str, known: impl IntoIterator<Item = &'static str>) -> Self {
        UnknownName { what, name: name.to_string(), known: known.into_iter().collect() }
    }
}

/// The value of `all` whose `name` is `text`, or the error listing them.
pub fn find_by_name<T: Copy>(
    what: &'static str,
    text: &str,
    all: &[T],
    name: impl Fn(T) -> &'static str,
) -> Result<T, UnknownName> {
    all.iter()
        .copied()
        .find(|&v| name(v) == text)
        .ok_or_else(|| UnknownName::new(what, text, all.iter().map(|&v| name(v))))
}
