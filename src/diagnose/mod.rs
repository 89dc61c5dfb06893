//! (stage diagnose: to be written)
