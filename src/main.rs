//! `g1viz` command line.
fn main() {}
