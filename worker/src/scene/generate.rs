//! Procedural rooms.
