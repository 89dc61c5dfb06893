//! (stage identify: to be written)
