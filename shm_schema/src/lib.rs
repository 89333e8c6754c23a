pub mod placeholder_types {}
