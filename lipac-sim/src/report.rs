//! Report writing.
