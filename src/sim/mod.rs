//! (stage sim: to be written)
