//! (stage robot: to be written)
