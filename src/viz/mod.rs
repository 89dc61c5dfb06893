//! (stage viz: to be written)
