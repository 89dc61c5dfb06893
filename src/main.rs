//! `g1viz` command line (being wired).
fn main() {}
